//! Logs and traces for every command: `tracing` events and spans to stderr (human-readable
//! or JSON lines), `log` records of dependencies bridged into them, and, optionally, the
//! spans exported over OTLP. Stdout stays the commands' own output (results, the server's
//! "listening on" line), so scripts that parse it are not disturbed by logs.

pub mod json_lines;
pub mod logging;
#[cfg(feature = "otlp")]
pub mod otlp;
pub mod request_id;

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

/// Installs the global subscriber. `default_filter` applies when neither B2TF_LOG nor
/// RUST_LOG is set. Fails on a bad filter or endpoint, naming it.
pub fn init(args: &TelemetryArgs, default_filter: &str) -> anyhow::Result<Guard> {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::Layer;
    let filter = logging::filter(default_filter)?;
    let logs = logging::layer(args.log_format.unwrap_or_default()).with_filter(filter);
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
