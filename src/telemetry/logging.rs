//! The stderr log layer: its format and its level filter.

use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::{EnvFilter, Layer};

#[derive(clap::ValueEnum, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LogFormat {
    /// `2026-11-24T06:00:00.123Z  INFO request{request_id=… method=POST …}: b2tfpose…: message`
    #[default]
    Human,
    /// One JSON object per line, the request's span fields (request_id, …) at the top level.
    Json,
}

/// Dependencies that log a lot at info and below; kept to warnings unless a directive names
/// them (e.g. B2TF_LOG=wgpu_hal=info).
const QUIET: &[&str] = &["wgpu_core", "wgpu_hal", "naga", "h2", "hyper", "hyper_util", "tower", "tonic", "rustls", "ort"];

/// The filter: B2TF_LOG, else RUST_LOG, else `default`; chatty dependencies stay at warn
/// unless the directives name them.
pub fn filter(default: &str) -> anyhow::Result<EnvFilter> {
    let (source, directives) = match (std::env::var("B2TF_LOG"), std::env::var("RUST_LOG")) {
        (Ok(v), _) if !v.trim().is_empty() => ("B2TF_LOG", v),
        (_, Ok(v)) if !v.trim().is_empty() => ("RUST_LOG", v),
        _ => ("the default", default.to_string()),
    };
    parse(&directives).map_err(|e| anyhow::anyhow!("log filter {directives:?} from {source}: {e}"))
}

fn parse(directives: &str) -> Result<EnvFilter, String> {
    let mut all: Vec<String> = QUIET.iter().filter(|t| !directives.contains(*t)).map(|t| format!("{t}=warn")).collect();
    // A bare level ("debug") would lift the quiet ones too if it came after them.
    all.insert(0, directives.to_string());
    let joined = all.join(",");
    EnvFilter::builder().with_regex(false).parse(&joined).map_err(|e| e.to_string())
}

/// The stderr layer in `format`; colours only on a terminal.
pub fn layer<S>(format: LogFormat) -> Box<dyn Layer<S> + Send + Sync>
where
    S: tracing::Subscriber + for<'a> LookupSpan<'a>,
{
    use std::io::IsTerminal;
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr);
    match format {
        LogFormat::Human => fmt.with_ansi(std::io::stderr().is_terminal()).boxed(),
        LogFormat::Json => fmt.with_ansi(false).fmt_fields(tracing_subscriber::fmt::format::JsonFields::new()).event_format(super::json_lines::JsonLines).boxed(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directives_parse_and_bad_ones_are_refused() {
        assert!(parse("info").is_ok());
        assert!(parse("warn,b2tfpose=debug").is_ok());
        assert!(parse("b2tfpose=loud").is_err());
        // A named dependency keeps the level asked for.
        let f = parse("wgpu_hal=info").unwrap().to_string();
        assert!(f.contains("wgpu_hal=info") && !f.contains("wgpu_hal=warn"), "{f}");
        assert!(parse("debug").unwrap().to_string().contains("naga=warn"));
    }
}
