//! Logs and traces for every command: `tracing` events and spans to stderr (human-readable
//! or JSON lines), `log` records of dependencies bridged into them, and, optionally, the
//! spans exported over OTLP. Stdout stays the commands' own output (results, the server's
//! "listening on" line), so scripts that parse it are not disturbed by logs.

pub mod error_text;
pub mod json_lines;
pub mod logging;
#[cfg(feature = "otlp")]
pub mod otlp;
pub mod request_id;

pub use error_text::error_text;
pub use logging::LogFormat;
pub use request_id::RequestId;

/// The flags every command takes (`global`: before or after the subcommand).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct TelemetryArgs {
    /// Log lines on stderr: "human" or "json" (one JSON object per line). Levels come from
    /// B2TF_LOG or RUST_LOG (e.g. "debug", "warn,b2tfpose=debug") [default: human]
    #[arg(long, global = true, env = "B2TF_LOG_FORMAT", value_enum)]
    pub log_format: Option<LogFormat>,
    /// Export the spans (one per request, with its stages) over OTLP/gRPC to this collector,
    /// e.g. http://localhost:4317
    #[arg(long, global = true, env = "OTEL_EXPORTER_OTLP_ENDPOINT")]
    pub otlp_endpoint: Option<String>,
}

/// Keeps the exporter alive; dropping it flushes the spans still queued (bounded in time).
pub struct Guard {
    #[cfg(feature = "otlp")]
    _otlp: Option<otlp::Otlp>,
}

impl Guard {
    /// Flushes the spans still queued, as dropping the guard does: for a caller about to
    /// `std::process::exit`, which runs no destructors.
    pub fn flush(self) {}
}

/// Milliseconds since `t`: the unit every stage time the commands and the service report is in.
pub fn ms_since(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

static FORMAT: std::sync::OnceLock<LogFormat> = std::sync::OnceLock::new();

/// The format `init` set up (human before it ran): what a command's own lines outside the
/// log (the server's banner, a fatal error) follow.
pub fn format() -> LogFormat {
    FORMAT.get().copied().unwrap_or_default()
}

/// A line a command writes itself, outside the log (the server's banner, a fatal error), in
/// the log's format: `human` as it is, or a JSON line of `message` and `fields`.
pub fn own_line(level: tracing::Level, target: &str, human: &str, message: &str, fields: serde_json::Map<String, serde_json::Value>) -> String {
    match format() {
        LogFormat::Human => human.to_string(),
        LogFormat::Json => json_lines::line(level, target, message, fields),
    }
}

/// A command's fatal error, on stderr in the log's format.
pub fn fatal(message: &str) {
    eprintln!("{}", own_line(tracing::Level::ERROR, "b2tf", &format!("error: {message}"), message, Default::default()));
}

/// Installs the global subscriber. `default_filter` applies when neither B2TF_LOG nor
/// RUST_LOG is set. Fails on a bad filter or endpoint, naming it. With JSON logs, panics
/// are logged as JSON lines too (message, location, thread) instead of the default text.
pub fn init(args: &TelemetryArgs, default_filter: &str) -> anyhow::Result<Guard> {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::Layer;
    let format = args.log_format.unwrap_or_default();
    let _ = FORMAT.set(format);
    if format == LogFormat::Json {
        std::panic::set_hook(Box::new(json_panic));
    }
    let filter = logging::filter(default_filter)?;
    let logs = logging::layer(format).with_filter(filter);
    let endpoint = args.otlp_endpoint.as_deref().map(str::trim).filter(|e| !e.is_empty());
    #[cfg(feature = "otlp")]
    {
        let otlp = endpoint.map(otlp::Otlp::start).transpose()?;
        let layer = otlp.as_ref().map(|o| o.layer());
        tracing_subscriber::registry().with(logs).with(layer).try_init()?;
        Ok(Guard { _otlp: otlp })
    }
    #[cfg(not(feature = "otlp"))]
    {
        if let Some(e) = endpoint {
            anyhow::bail!("--otlp-endpoint {e}: this build has no OTLP export (cargo feature \"otlp\")");
        }
        tracing_subscriber::registry().with(logs).try_init()?;
        Ok(Guard {})
    }
}

/// A panic as one JSON line on stderr (not through `tracing`: the filter could hide it).
fn json_panic(info: &std::panic::PanicHookInfo<'_>) {
    let location = info.location().map(|l| format!("{}:{}:{}", l.file(), l.line(), l.column()));
    let backtrace = std::env::var_os("RUST_BACKTRACE").is_some_and(|v| v != "0").then(|| std::backtrace::Backtrace::force_capture().to_string());
    eprintln!("{}", panic_line(info.payload(), location, std::thread::current().name(), backtrace));
}

/// The JSON line of a panic with `payload` (what `panic!` was given: a `&str`, a `String`
/// when it formatted, anything else otherwise).
fn panic_line(payload: &(dyn std::any::Any + Send), location: Option<String>, thread: Option<&str>, backtrace: Option<String>) -> String {
    let message = payload.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| payload.downcast_ref::<String>().cloned()).unwrap_or_else(|| "(a panic without a message)".into());
    let mut fields = serde_json::Map::new();
    if let Some(l) = location {
        fields.insert("location".into(), l.into());
    }
    fields.insert("thread".into(), thread.unwrap_or("unnamed").into());
    if let Some(b) = backtrace {
        fields.insert("backtrace".into(), b.into());
    }
    json_lines::line(tracing::Level::ERROR, "panic", &format!("panicked: {message}"), fields)
}

#[cfg(test)]
mod tests {
    use super::panic_line;
    use serde_json::Value;

    #[test]
    fn a_panic_becomes_one_json_line_with_its_message_location_and_thread() {
        // The payloads `panic!` makes: a String when it formatted, a &str when it did not;
        // `panic_any` can carry anything. Built directly, so that the test does not swap
        // the process-wide panic hook under the other tests.
        type Payload = Box<dyn std::any::Any + Send>;
        let formatted: Payload = Box::new(format!("bad crop {}", 7));
        let literal: Payload = Box::new("no mask");
        let other: Payload = Box::new(42u8);
        let line = panic_line(&*formatted, Some("src/x.rs:1:2".into()), Some("worker-3"), None);
        assert!(!line.contains('\n'), "one line: {line}");
        let v: Value = serde_json::from_str(&line).unwrap();
        assert_eq!((v["level"].as_str(), v["target"].as_str(), v["message"].as_str()), (Some("ERROR"), Some("panic"), Some("panicked: bad crop 7")));
        assert_eq!((v["location"].as_str(), v["thread"].as_str()), (Some("src/x.rs:1:2"), Some("worker-3")));
        assert!(v.get("backtrace").is_none());
        let v: Value = serde_json::from_str(&panic_line(&*literal, None, None, Some("frames".into()))).unwrap();
        assert_eq!((v["message"].as_str(), v["thread"].as_str(), v["backtrace"].as_str()), (Some("panicked: no mask"), Some("unnamed"), Some("frames")));
        assert!(v.get("location").is_none());
        let v: Value = serde_json::from_str(&panic_line(&*other, None, None, None)).unwrap();
        assert_eq!(v["message"].as_str(), Some("panicked: (a panic without a message)"));
    }
}
