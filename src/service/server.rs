//! Runs the two listeners (HTTP/JSON and gRPC) over one `Api` until a shutdown signal:
//! then both stop accepting, let in-flight requests finish, and return, after which the
//! caller drops the core (closing the store).

use super::api::Api;
use super::proto::pose_service_server::PoseServiceServer;
use super::tls::{TlsIdentity, TlsListener};
use anyhow::{Context, Result};
use std::net::SocketAddr;
use std::time::Duration;
use tokio::net::TcpListener;

pub struct ServerOptions {
    /// HTTP listen address; `None`: no HTTP listener.
    pub http: Option<String>,
    /// gRPC listen address; `None`: no gRPC listener.
    pub grpc: Option<String>,
    /// Largest HTTP body / gRPC message.
    pub max_body_bytes: usize,
    pub tls: Option<TlsIdentity>,
    /// Serve the web console (console.rs) on the HTTP listener.
    pub console: bool,
}

/// Where the listeners ended up (port 0 picks a free one).
#[derive(Clone, Copy, Debug)]
pub struct Bound {
    pub http: Option<SocketAddr>,
    pub grpc: Option<SocketAddr>,
}

async fn bind(addr: &Option<String>, what: &str) -> Result<Option<TcpListener>> {
    match addr {
        Some(a) => Ok(Some(TcpListener::bind(a).await.with_context(|| format!("cannot listen for {what} on {a}"))?)),
        None => Ok(None),
    }
}

/// Binds both listeners, reports their addresses through `on_bound`, serves until
/// `shutdown` completes, then drains.
pub async fn run(api: Api, opts: ServerOptions, on_bound: impl FnOnce(Bound), shutdown: impl std::future::Future<Output = ()> + Send + 'static) -> Result<()> {
    let http = bind(&opts.http, "HTTP").await?;
    let grpc = bind(&opts.grpc, "gRPC").await?;
    on_bound(Bound { http: http.as_ref().map(|l| l.local_addr()).transpose()?, grpc: grpc.as_ref().map(|l| l.local_addr()).transpose()? });
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    tokio::spawn(async move {
        shutdown.await;
        let _ = stop_tx.send(true);
    });
    let stopped = move || {
        let mut rx = stop_rx.clone();
        async move {
            let _ = rx.wait_for(|s| *s).await;
        }
    };
    // Idle tracking sessions are closed even when no request comes to notice them, and
    // idle clients' rate-limit buckets are forgotten.
    let sweeper = {
        let (core, rate) = (api.core.clone(), api.rate.clone());
        let every = (core.config.track_idle_timeout / 2).clamp(Duration::from_millis(50), Duration::from_secs(10));
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(every);
            loop {
                tick.tick().await;
                core.expire_tracks();
                if let Some(r) = &rate {
                    r.forget_idle(std::time::Instant::now());
                }
            }
        })
    };
    let mut tasks = tokio::task::JoinSet::new();
    if let Some(listener) = http {
        // The peer address reaches the handlers (the rate limit without keys uses it) and
        // the request's span.
        let app = super::http::router(api.clone(), opts.max_body_bytes, opts.console).into_make_service_with_connect_info::<super::http_observe::Peer>();
        let signal = stopped();
        match &opts.tls {
            Some(id) => {
                let config = id.server_config(&[b"h2", b"http/1.1"]).map_err(anyhow::Error::msg)?;
                let tls = TlsListener::new(listener, config)?;
                tasks.spawn(async move { axum::serve(tls, app).with_graceful_shutdown(signal).await.context("HTTP server") });
            }
            None => {
                tasks.spawn(async move { axum::serve(listener, app).with_graceful_shutdown(signal).await.context("HTTP server") });
            }
        }
    }
    if let Some(listener) = grpc {
        tasks.spawn(serve_grpc(api.clone(), listener, opts.max_body_bytes, opts.tls.clone(), stopped()));
    }
    let result = async {
        while let Some(done) = tasks.join_next().await {
            done.context("server task")??;
        }
        Ok(())
    }
    .await;
    sweeper.abort();
    result
}

async fn serve_grpc(api: Api, listener: TcpListener, max_message_bytes: usize, tls: Option<TlsIdentity>, stopped: impl std::future::Future<Output = ()> + Send + 'static) -> Result<()> {
    let (health, health_service) = tonic_health::server::health_reporter();
    type Pose = PoseServiceServer<super::grpc::GrpcService>;
    health.set_not_serving::<Pose>().await;
    health.set_service_status("", tonic_health::ServingStatus::NotServing).await;
    {
        // SERVING once warmed up, like /readyz.
        let (health, api) = (health.clone(), api.clone());
        tokio::spawn(async move {
            while !api.is_ready() {
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            health.set_serving::<Pose>().await;
            health.set_service_status("", tonic_health::ServingStatus::Serving).await;
        });
    }
    let reflection = || {
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(super::proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
    };
    let (reflection_v1, reflection_v1alpha) = (reflection().build_v1()?, reflection().build_v1alpha()?);
    let mut builder = tonic::transport::Server::builder();
    if let Some(id) = &tls {
        let mut config = tonic::transport::ServerTlsConfig::new().identity(tonic::transport::Identity::from_pem(&id.cert_pem, &id.key_pem));
        if let Some(ca) = &id.client_ca_pem {
            // Required, not optional: tonic's default, as on the HTTP port.
            config = config.client_ca_root(tonic::transport::Certificate::from_pem(ca));
        }
        builder = builder.tls_config(config)?;
    }
    let incoming = tokio_stream::wrappers::TcpListenerStream::new(listener);
    let shutdown = async move {
        stopped.await;
        health.set_service_status("", tonic_health::ServingStatus::NotServing).await;
    };
    builder
        .layer(super::grpc_observe::ObserveLayer)
        .layer(tower::util::MapResponseLayer::new(super::grpc_oversized::oversized_to_invalid_argument))
        .add_service(health_service)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(super::grpc::pose_service(api, max_message_bytes))
        .serve_with_incoming_shutdown(incoming, shutdown)
        .await
        .context("gRPC server")
}
