//! `b2tf serve`: the HTTP service on the embedded defaults. Every flag can also come from
//! the environment (`B2TF_*`), which is how docker-compose deployments set them.

use crate::service::http::{router, AppState};
use crate::service::{Core, CoreConfig};
use anyhow::{Context, Result};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// HTTP listen address (port 0: any free port; the chosen one is printed).
    #[arg(long, env = "B2TF_HTTP_ADDR", default_value = "127.0.0.1:8080")]
    pub http: String,
    /// Object store URL (default: sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long, env = "B2TF_STORE")]
    pub store: Option<String>,
    /// Render contexts.
    #[arg(long, env = "B2TF_RENDER_POOL", default_value_t = crate::render::RenderPool::DEFAULT_SIZE)]
    pub render_pool: usize,
    /// Estimates running at once; more get 429 at once.
    #[arg(long, env = "B2TF_MAX_ESTIMATES", default_value_t = 2)]
    pub max_estimates: usize,
    /// Onboardings running at once; more get 429.
    #[arg(long, env = "B2TF_MAX_ONBOARDINGS", default_value_t = 1)]
    pub max_onboardings: usize,
    /// Largest request body, MB; larger ones get 413.
    #[arg(long, env = "B2TF_MAX_BODY_MB", default_value_t = 64)]
    pub max_body_mb: usize,
    /// Memory for loaded objects, MB.
    #[arg(long, env = "B2TF_CACHE_MB", default_value_t = 4000)]
    pub cache_mb: u64,
    /// File of API keys (one per line); with keys, only /healthz and /readyz are open.
    #[arg(long, env = "B2TF_API_KEYS_FILE")]
    pub api_keys_file: Option<std::path::PathBuf>,
    /// API keys, comma-separated (prefer the file: command lines are visible to other users).
    #[arg(long, env = "B2TF_API_KEYS", hide_env_values = true)]
    pub api_keys: Option<String>,
}

pub fn run(a: ServeArgs) -> Result<()> {
    let config = CoreConfig {
        store_url: a.store.clone().unwrap_or_else(crate::store::default_url),
        render_pool: a.render_pool,
        cache_bytes: a.cache_mb * 1_000_000,
        max_estimates: a.max_estimates.max(1),
        max_onboardings: a.max_onboardings.max(1),
    };
    let keys = crate::service::auth::ApiKeys::load(a.api_keys_file.as_deref(), a.api_keys.as_deref()).map_err(anyhow::Error::msg)?;
    let core = Arc::new(Core::new(config).context("starting the service core")?);
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&a.http).await.with_context(|| format!("cannot listen on {}", a.http))?;
        let addr = listener.local_addr()?;
        println!("listening on http://{addr} (store {}; {})", core.store_url(), if keys.enabled() { format!("{} API key(s) required", keys.len()) } else { "no API keys".into() });
        std::io::stdout().flush()?;
        let ready = Arc::new(AtomicBool::new(false));
        {
            let (core, ready) = (core.clone(), ready.clone());
            tokio::task::spawn_blocking(move || match core.warm_up() {
                Ok(()) => ready.store(true, Ordering::Release),
                Err(e) => eprintln!("warm-up failed, staying not ready: {e}"),
            });
        }
        let metrics = Arc::new(crate::service::metrics::Metrics::default());
        let app = router(AppState { core, ready, metrics, keys }, a.max_body_mb * 1_000_000);
        axum::serve(listener, app).with_graceful_shutdown(shutdown_signal()).await?;
        // The reader of stdout may be gone by now (a supervisor that only wanted the address).
        let _ = writeln!(std::io::stdout(), "stopped");
        Ok(())
    })
}

/// SIGTERM or Ctrl-C: stop accepting, let in-flight requests finish.
async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}
