//! `b2tf serve`: the HTTP/JSON and gRPC service on the embedded defaults. Settings come
//! from flags, `B2TF_*` environment variables and an optional TOML file (serve_config.rs).

use super::serve_config::{Resolved, ServeSettings};
use crate::service::server::{Bound, ServerOptions};
use crate::service::{Api, Core, CoreConfig};
use anyhow::{Context, Result};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// TOML file of settings (flags and B2TF_* variables override it).
    #[arg(long, env = "B2TF_CONFIG")]
    pub config: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub settings: ServeSettings,
}

/// Threads for the requests' blocking work (store reads, decoding, estimates, track
/// frames). Estimates and onboardings are bounded by their slots, but a burst of other
/// requests took one thread each (254 in docs/reliability.md's burst, tokio's ceiling
/// being 512); beyond this many they wait in tokio's queue instead. No blocking task waits
/// on another, so a queue cannot deadlock.
const MAX_BLOCKING_THREADS: usize = 128;

pub fn run(a: ServeArgs) -> Result<()> {
    let file = match &a.config {
        Some(path) => ServeSettings::from_file(path)?,
        None => ServeSettings::default(),
    };
    let s: Resolved = a.settings.resolve(file)?;
    let keys = crate::service::auth::ApiKeys::load(s.api_keys_file.as_deref(), s.api_keys.as_deref()).map_err(anyhow::Error::msg)?;
    let tls = match &s.tls {
        Some((cert, key)) => Some(crate::service::tls::TlsIdentity::load(cert, key, s.tls_client_ca.as_deref()).map_err(anyhow::Error::msg)?),
        None => None,
    };
    let config = CoreConfig {
        store_url: s.store.clone(),
        render_pool: s.render_pool,
        render_meshes: s.render_meshes,
        cache_bytes: s.cache_bytes,
        max_estimates: s.max_estimates,
        instance_threads: s.instance_threads,
        queue_depth: s.queue_depth,
        queue_timeout: s.queue_timeout,
        max_onboardings: s.max_onboardings,
        backbone: s.backbone.clone(),
        device: s.device.clone(),
        backbone_batch: s.backbone_batch,
        backbone_max_wait: s.backbone_max_wait,
        read_only: s.read_only,
        max_track_sessions: s.max_track_sessions,
        track_idle_timeout: s.track_idle_timeout,
    };
    let core = Arc::new(Core::new(config).context("starting the service core")?);
    let runtime = tokio::runtime::Builder::new_multi_thread().max_blocking_threads(MAX_BLOCKING_THREADS).enable_all().build()?;
    let api = Api {
        core: core.clone(),
        ready: Arc::new(AtomicBool::new(false)),
        metrics: Default::default(),
        keys: keys.clone(),
        rate: s.rate_limit.map(|r| Arc::new(crate::service::rate_limit::RateLimiter::new(r))),
        request_timeout: s.request_timeout,
    };
    let scheme = if tls.is_some() { ("https", "grpcs") } else { ("http", "grpc") };
    let mtls = tls.as_ref().is_some_and(|t| t.client_ca_pem.is_some());
    let rate = s.rate_limit;
    let options = ServerOptions { http: s.http.clone(), grpc: s.grpc.clone(), max_body_bytes: s.max_body_bytes, tls, console: s.console };
    let store_url = if s.read_only { format!("{}, read-only", core.store_url()) } else { core.store_url() };
    let console = s.console;
    let on_bound = move |b: Bound| {
        let mut line = String::from("listening on");
        if let Some(h) = b.http {
            line += &format!(" {}://{h}", scheme.0);
        }
        if let Some(g) = b.grpc {
            line += &format!(" {}://{g}", scheme.1);
        }
        let mut auth = if keys.enabled() { format!("{} API key(s) required", keys.len()) } else { "no API keys".into() };
        if mtls {
            auth += ", client certificates required";
        }
        if let Some(r) = rate {
            auth += &format!(", rate limit {} requests/s burst {} per {}", r.rate, r.burst, if keys.enabled() { "key" } else { "client address" });
        }
        // Stdout's line is the one scripts wait for (as JSON with --log-format json); the
        // log line is for log collectors.
        let mut fields = serde_json::Map::new();
        fields.extend(b.http.map(|h| ("http".to_string(), format!("{}://{h}", scheme.0).into())));
        fields.extend(b.grpc.map(|g| ("grpc".to_string(), format!("{}://{g}", scheme.1).into())));
        fields.insert("store".into(), store_url.clone().into());
        fields.insert("auth".into(), auth.clone().into());
        // Where people open the console (after the addresses: scripts take the first URL).
        let page = b.http.filter(|_| console).map(|h| format!("{}://{h}/console/", scheme.0));
        let page_note = page.as_ref().map_or_else(String::new, |p| format!("; web console {p}"));
        fields.extend(page.map(|p| ("console".to_string(), p.into())));
        println!("{}", crate::telemetry::own_line(tracing::Level::INFO, "b2tf::serve", &format!("{line} (store {store_url}; {auth}{page_note})"), "listening", fields));
        tracing::info!(http = b.http.map(tracing::field::display), grpc = b.grpc.map(tracing::field::display), tls = scheme.0 == "https", store = %store_url, api_keys = keys.len(), "listening");
        let _ = std::io::stdout().flush();
    };
    runtime.block_on(async move {
        {
            let (core, ready) = (core.clone(), api.ready.clone());
            tokio::task::spawn_blocking(move || match core.warm_up() {
                Ok(()) => ready.store(true, Ordering::Release),
                Err(e) => tracing::error!("warm-up failed, staying not ready: {e}"),
            });
        }
        if let Some(every) = s.revalidate {
            tokio::spawn(revalidate_every(core.clone(), every));
        }
        crate::service::server::run(api, options, on_bound, shutdown_signal()).await?;
        tracing::info!("stopped accepting; in-flight requests finished");
        let stopping = core.clone();
        let cancelled = tokio::task::spawn_blocking(move || stopping.stop_onboardings(std::time::Duration::from_secs(30))).await?;
        if cancelled > 0 {
            tracing::warn!("shutdown: cancelled {cancelled} running onboarding(s); nothing of them was stored");
        }
        // The reader of stdout may be gone by now (a supervisor that only wanted the address).
        let _ = writeln!(std::io::stdout(), "{}", crate::telemetry::own_line(tracing::Level::INFO, "b2tf::serve", "stopped", "stopped", Default::default()));
        Ok(())
    })
}

/// Checks the objects held in memory against the store every `every`, so that a replica
/// serves what another process replaced or deleted without a restart (docs/store.md).
async fn revalidate_every(core: Arc<Core>, every: std::time::Duration) {
    let mut tick = tokio::time::interval(every);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await; // the first tick is immediate: nothing is held yet
    loop {
        tick.tick().await;
        let core = core.clone();
        if let Err(e) = tokio::task::spawn_blocking(move || core.revalidate_cache()).await {
            tracing::warn!("revalidating the cached objects failed: {e}");
        }
    }
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
