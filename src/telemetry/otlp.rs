//! OTLP/gRPC export of this crate's spans (service.name "b2tfpose"): a batch exporter, so
//! a request only hands its finished spans to a queue; a slow or absent collector loses
//! spans (the queue is bounded), never delays a request. Dropping `Otlp` flushes what is
//! queued, waiting at most `FLUSH_WAIT`.

use opentelemetry::trace::TracerProvider as _;
use opentelemetry_otlp::WithExportConfig;
use opentelemetry_sdk::trace::SdkTracerProvider;
use std::time::Duration;
use tracing_subscriber::filter::Targets;
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::Layer;

/// One export attempt (retries included) at most.
const EXPORT_TIMEOUT: Duration = Duration::from_secs(3);
/// The flush at exit at most.
const FLUSH_WAIT: Duration = Duration::from_secs(5);

pub struct Otlp {
    provider: SdkTracerProvider,
    /// The exporter's channel lives on this runtime (tonic needs one), apart from the
    /// server's, so exporting works the same for every command and outlives the server.
    runtime: Option<tokio::runtime::Runtime>,
}

/// Checks what tonic would accept later, with a message that says what is expected.
fn check_endpoint(url: &str) -> anyhow::Result<()> {
    let uri: http::Uri = url.parse().map_err(|e| anyhow::anyhow!("--otlp-endpoint {url:?} is not a URL ({e}); expected e.g. http://localhost:4317"))?;
    match (uri.scheme_str(), uri.host()) {
        (Some("http"), Some(_)) => Ok(()),
        (Some("https"), Some(_)) => anyhow::bail!("--otlp-endpoint {url:?}: only plain http:// collectors are supported (this build exports without TLS); put a local collector or sidecar in front"),
        _ => anyhow::bail!("--otlp-endpoint {url:?} needs an http:// scheme and a host, e.g. http://localhost:4317"),
    }
}

impl Otlp {
    pub fn start(endpoint: &str) -> anyhow::Result<Self> {
        check_endpoint(endpoint)?;
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).thread_name("otlp-export").enable_all().build()?;
        let exporter = runtime.block_on(async { opentelemetry_otlp::SpanExporter::builder().with_tonic().with_endpoint(endpoint).with_timeout(EXPORT_TIMEOUT).build() });
        let exporter = exporter.map_err(|e| anyhow::anyhow!("--otlp-endpoint {endpoint}: {e}"))?;
        let resource = opentelemetry_sdk::Resource::builder().with_service_name("b2tfpose").build();
        let provider = SdkTracerProvider::builder().with_batch_exporter(exporter).with_resource(resource).build();
        Ok(Self { provider, runtime: Some(runtime) })
    }

    /// The layer that turns this crate's spans into OTLP spans; other crates' spans (the
    /// transport's own, the exporter's) stay out, so exporting never traces itself.
    pub fn layer<S>(&self) -> impl Layer<S> + Send + Sync
    where
        S: tracing::Subscriber + for<'a> LookupSpan<'a> + Send + Sync,
    {
        let targets = Targets::new().with_target("b2tfpose", tracing::Level::INFO);
        tracing_opentelemetry::layer().with_tracer(self.provider.tracer("b2tfpose")).with_filter(targets)
    }
}

impl Drop for Otlp {
    fn drop(&mut self) {
        if let Err(e) = self.provider.shutdown_with_timeout(FLUSH_WAIT) {
            eprintln!("OTLP export: spans not flushed at exit: {e}");
        }
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_timeout(Duration::from_secs(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_checked_with_a_clear_message() {
        assert!(check_endpoint("http://localhost:4317").is_ok());
        assert!(check_endpoint("http://127.0.0.1:4317/").is_ok());
        for (bad, says) in [("localhost:4317", "http://"), ("https://collector:4317", "plain http"), ("ftp://x", "http://"), ("http://", "not a URL"), ("not a url", "not a URL")] {
            let e = check_endpoint(bad).unwrap_err().to_string();
            assert!(e.contains(says) && e.contains(bad), "{bad}: {e}");
        }
    }
}
