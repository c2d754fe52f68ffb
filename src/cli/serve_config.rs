//! `b2tf serve` settings from three places, strongest first: flags, the environment
//! (`B2TF_*`, how docker-compose sets them), and an optional TOML file (`--config`), then
//! the defaults. The file uses the flags' names with underscores:
//!
//! ```toml
//! http = "0.0.0.0:8080"          # "none" turns a listener off
//! grpc = "0.0.0.0:50051"
//! store = "sqlite:///var/lib/b2tf/objects.db"   # or dir:///PATH, s3://BUCKET/PREFIX?region=...
//! backbone = "embedded"         # or "onnx:/models/dinov3-vitl16.onnx" (its .json beside it)
//! device = "cpu"                 # for an ONNX backbone: "cuda:0", "tensorrt:0"
//! backbone_batch = 32            # crops per backbone pass of the batching queue; 0: none
//! backbone_max_wait_ms = 0       # how long a pass may wait for more requests (GPU: a few ms)
//! render_pool = 2
//! render_meshes = 8              # objects' meshes each render context keeps uploaded
//! max_estimates = 2
//! instance_threads = 2           # one request's instances estimated side by side [default: cores / max_estimates, at least 2]
//! queue_depth = 16               # estimates waiting for a slot [default: 8 x max_estimates]
//! queue_timeout_ms = 30000       # longest one waits before 429
//! max_onboardings = 1
//! max_body_mb = 64
//! cache_mb = 4000
//! request_timeout_s = 60
//! api_keys_file = "/run/secrets/b2tf_keys"
//! tls_cert = "/etc/b2tf/cert.pem"
//! tls_key = "/etc/b2tf/key.pem"
//! tls_client_ca = "/etc/b2tf/clients-ca.pem"  # mTLS: client certificates from these CAs
//! rate_limit = "20/s"            # per API key (per client address without keys); off if unset
//! rate_burst = 40                # requests at once after idling [default: the rate per second]
//! read_only = false              # true: a replica serving a store another process writes
//! revalidate_s = 5               # how often cached objects are checked against the store
//! max_track_sessions = 8         # tracking sessions / Track streams open at once
//! track_idle_timeout_s = 60      # a session with no frame for this long is closed
//! console = true                 # the web console at /console/ on the HTTP port
//! ```

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// Every setting, each optional: what one source says.
#[derive(clap::Args, serde::Deserialize, Debug, Default, Clone)]
#[serde(deny_unknown_fields)]
pub struct ServeSettings {
    /// HTTP listen address ("none": off; port 0: any free port, printed) [default: 127.0.0.1:8080]
    #[arg(long, env = "B2TF_HTTP_ADDR")]
    pub http: Option<String>,
    /// gRPC listen address ("none": off) [default: 127.0.0.1:50051]
    #[arg(long, env = "B2TF_GRPC_ADDR")]
    pub grpc: Option<String>,
    /// Object store URL: sqlite://PATH.db, dir://PATH or s3://BUCKET/PREFIX[?OPTIONS]
    /// [default: sqlite://~/.local/share/b2tfpose/objects.db]
    #[arg(long, env = "B2TF_STORE")]
    pub store: Option<String>,
    /// Backbone: "embedded" (weight-free, built in) or "onnx:PATH" (an ONNX export with
    /// its .json sidecar; ONNX Runtime from $B2TF_ORT_LIB) [default: embedded]
    #[arg(long, env = "B2TF_BACKBONE")]
    pub backbone: Option<String>,
    /// Where an ONNX backbone runs: cpu, cuda[:N], tensorrt[:N] [default: cpu]
    #[arg(long, env = "B2TF_DEVICE")]
    pub device: Option<String>,
    /// Most crops per backbone forward pass of the shared batching queue; 0: no queue
    /// [default: 32]
    #[arg(long, env = "B2TF_BACKBONE_BATCH")]
    pub backbone_batch: Option<usize>,
    /// Longest a backbone pass waits after its first request for more, ms; 0: runs at once
    /// with what is queued [default: 0]
    #[arg(long, env = "B2TF_BACKBONE_MAX_WAIT_MS")]
    pub backbone_max_wait_ms: Option<f64>,
    /// Render contexts [default: 2]
    #[arg(long, env = "B2TF_RENDER_POOL")]
    pub render_pool: Option<usize>,
    /// Objects' meshes each render context keeps uploaded (the least recently used one is
    /// replaced): at least the objects a cell estimates in turn, or each request uploads
    /// its object again (about 50-100 ms of a textured mesh) [default: 8]
    #[arg(long, env = "B2TF_RENDER_MESHES")]
    pub render_meshes: Option<usize>,
    /// Estimates (and detections) running at once; more wait in line [default: 2]
    #[arg(long, env = "B2TF_MAX_ESTIMATES")]
    pub max_estimates: Option<usize>,
    /// Threads one request's instances (the caller's detections, or with depth the
    /// detector's candidates object by object) are estimated on side by side; 1: in turn
    /// [default: the cores shared among max_estimates, at least 2]
    #[arg(long, env = "B2TF_INSTANCE_THREADS")]
    pub instance_threads: Option<usize>,
    /// Estimates waiting for a slot, in arrival order; beyond, or when the expected wait
    /// would pass a request's deadline, 429 / RESOURCE_EXHAUSTED with Retry-After; 0:
    /// refuse at once [default: 8 x max_estimates]
    #[arg(long, env = "B2TF_QUEUE_DEPTH")]
    pub queue_depth: Option<usize>,
    /// Longest an estimate waits in line before it is refused (429), ms [default: 30000]
    #[arg(long, env = "B2TF_QUEUE_TIMEOUT_MS")]
    pub queue_timeout_ms: Option<u64>,
    /// Onboardings running at once; more are refused [default: 1]
    #[arg(long, env = "B2TF_MAX_ONBOARDINGS")]
    pub max_onboardings: Option<usize>,
    /// Largest request body / gRPC message, MB (413 / INVALID_ARGUMENT beyond) [default: 64]
    #[arg(long, env = "B2TF_MAX_BODY_MB")]
    pub max_body_mb: Option<usize>,
    /// Memory for loaded objects, MB [default: 4000]
    #[arg(long, env = "B2TF_CACHE_MB")]
    pub cache_mb: Option<u64>,
    /// Longest an estimate may run on the server, seconds; 0: no limit (gRPC clients'
    /// shorter deadlines always apply) [default: 120]
    #[arg(long, env = "B2TF_REQUEST_TIMEOUT_S")]
    pub request_timeout_s: Option<f64>,
    /// File of API keys, one per line: `KEY [scopes=read,write,admin] [name=NAME]` (a bare
    /// key has every scope); with keys, only the health checks are open.
    #[arg(long, env = "B2TF_API_KEYS_FILE")]
    pub api_keys_file: Option<PathBuf>,
    /// API keys, comma-separated, each with every scope (prefer the file: command lines are
    /// visible to others).
    #[arg(long, env = "B2TF_API_KEYS", hide_env_values = true)]
    pub api_keys: Option<String>,
    /// PEM certificate chain: serve both ports over TLS (needs --tls-key).
    #[arg(long, env = "B2TF_TLS_CERT")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key for --tls-cert.
    #[arg(long, env = "B2TF_TLS_KEY")]
    pub tls_key: Option<PathBuf>,
    /// PEM of the CA certificate(s) client certificates must chain to: mTLS on both ports,
    /// a client without such a certificate fails the handshake (needs --tls-cert/--tls-key).
    #[arg(long, env = "B2TF_TLS_CLIENT_CA")]
    pub tls_client_ca: Option<PathBuf>,
    /// Requests per API key (per client address when there are no keys): RATE[/s|/m|/h];
    /// over it, 429 / RESOURCE_EXHAUSTED with Retry-After [default: no limit]
    #[arg(long, env = "B2TF_RATE_LIMIT")]
    pub rate_limit: Option<String>,
    /// Requests a client may make at once after idling, with --rate-limit [default: the
    /// per-second rate, rounded up]
    #[arg(long, env = "B2TF_RATE_BURST")]
    pub rate_burst: Option<u32>,
    /// Serve a store that another process writes (replicas sharing one store): open it
    /// read-only, never create or clean anything in it, refuse onboard and delete (403 /
    /// PERMISSION_DENIED) [default: false]
    #[arg(long, env = "B2TF_READ_ONLY", num_args = 0..=1, default_missing_value = "true", value_parser = clap::builder::BoolishValueParser::new())]
    pub read_only: Option<bool>,
    /// How often the objects held in memory are checked against the store, seconds: one
    /// replaced or deleted by another process (an onboarding job, another replica's
    /// writer) is dropped and loaded afresh on its next use; 0: never [default: 5]
    #[arg(long, env = "B2TF_REVALIDATE_S")]
    pub revalidate_s: Option<f64>,
    /// Tracking sessions (HTTP sessions and gRPC Track streams) open at once; more are
    /// refused (429 / RESOURCE_EXHAUSTED) [default: 8]
    #[arg(long, env = "B2TF_MAX_TRACK_SESSIONS")]
    pub max_track_sessions: Option<usize>,
    /// A tracking session with no frame for this long is closed, seconds [default: 60]
    #[arg(long, env = "B2TF_TRACK_IDLE_TIMEOUT_S")]
    pub track_idle_timeout_s: Option<f64>,
    /// Serve the web console at /console/ (and redirect / there) on the HTTP port; its
    /// calls go through the API with the user's key [default: true]
    #[arg(long, env = "B2TF_CONSOLE", num_args = 0..=1, default_missing_value = "true", value_parser = clap::builder::BoolishValueParser::new())]
    pub console: Option<bool>,
}

/// The settings in force.
#[derive(Debug, Clone)]
pub struct Resolved {
    pub http: Option<String>,
    pub grpc: Option<String>,
    pub store: String,
    pub render_pool: usize,
    pub render_meshes: usize,
    pub backbone: crate::features::BackboneChoice,
    pub device: crate::features::Device,
    pub backbone_batch: usize,
    pub backbone_max_wait: std::time::Duration,
    pub max_estimates: usize,
    pub instance_threads: usize,
    pub queue_depth: usize,
    pub queue_timeout: std::time::Duration,
    pub max_onboardings: usize,
    pub max_body_bytes: usize,
    pub cache_bytes: u64,
    pub request_timeout: Option<std::time::Duration>,
    pub api_keys_file: Option<PathBuf>,
    pub api_keys: Option<String>,
    pub tls: Option<(PathBuf, PathBuf)>,
    pub tls_client_ca: Option<PathBuf>,
    pub rate_limit: Option<crate::service::rate_limit::RateSpec>,
    pub read_only: bool,
    /// How often cached objects are checked against the store; None: never.
    pub revalidate: Option<std::time::Duration>,
    pub max_track_sessions: usize,
    pub track_idle_timeout: std::time::Duration,
    pub console: bool,
}

impl ServeSettings {
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("config file {}", path.display()))?;
        let mut s: Self = toml::from_str(&text).with_context(|| format!("config file {}", path.display()))?;
        // Relative paths in the file are relative to the file, not to the working folder.
        let base = path.parent().unwrap_or(Path::new("."));
        for p in [&mut s.api_keys_file, &mut s.tls_cert, &mut s.tls_key, &mut s.tls_client_ca].into_iter().flatten() {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        }
        Ok(s)
    }

    /// `self` wins over `file`, which wins over the defaults.
    pub fn resolve(self, file: ServeSettings) -> Result<Resolved> {
        macro_rules! pick {
            ($f:ident) => {
                self.$f.or(file.$f)
            };
        }
        let listen = |v: Option<String>, default: &str| -> Option<String> {
            match v.as_deref().map(str::trim) {
                Some("none" | "off" | "") => None,
                Some(a) => Some(a.to_string()),
                None => Some(default.to_string()),
            }
        };
        let http = listen(pick!(http), "127.0.0.1:8080");
        let grpc = listen(pick!(grpc), "127.0.0.1:50051");
        if http.is_none() && grpc.is_none() {
            bail!("both listeners are off: set --http or --grpc to an address");
        }
        let backbone: crate::features::BackboneChoice = pick!(backbone).as_deref().unwrap_or("embedded").parse().map_err(anyhow::Error::msg)?;
        let device: crate::features::Device = pick!(device).as_deref().unwrap_or("cpu").parse().map_err(anyhow::Error::msg)?;
        let positive = |name: &str, v: usize| -> Result<usize> {
            if v == 0 {
                bail!("{name} must be at least 1");
            }
            Ok(v)
        };
        let max_wait_ms = pick!(backbone_max_wait_ms).unwrap_or(0.0);
        if !max_wait_ms.is_finite() || !(0.0..=10_000.0).contains(&max_wait_ms) {
            bail!("backbone_max_wait_ms must be a number of milliseconds from 0 to 10000, not {max_wait_ms}");
        }
        let timeout = pick!(request_timeout_s).unwrap_or(120.0);
        if !timeout.is_finite() || timeout < 0.0 {
            bail!("request_timeout_s must be a number of seconds ≥ 0 (0: no limit), not {timeout}");
        }
        let max_estimates = positive("max_estimates", pick!(max_estimates).unwrap_or(2))?;
        let queue_depth = pick!(queue_depth).unwrap_or(8 * max_estimates);
        if queue_depth > 100_000 {
            bail!("queue_depth must be at most 100000, not {queue_depth}");
        }
        let queue_timeout_ms = pick!(queue_timeout_ms).unwrap_or(30_000);
        if !(1..=3_600_000).contains(&queue_timeout_ms) {
            bail!("queue_timeout_ms must be from 1 to 3600000 ms, not {queue_timeout_ms}");
        }
        let revalidate_s = pick!(revalidate_s).unwrap_or(5.0);
        if !revalidate_s.is_finite() || !(0.0..=86_400.0).contains(&revalidate_s) {
            bail!("revalidate_s must be a number of seconds from 0 (never) to 86400, not {revalidate_s}");
        }
        let idle = pick!(track_idle_timeout_s).unwrap_or(60.0);
        if !idle.is_finite() || !(0.1..=86_400.0).contains(&idle) {
            bail!("track_idle_timeout_s must be a number of seconds from 0.1 to 86400, not {idle}");
        }
        let tls = match (pick!(tls_cert), pick!(tls_key)) {
            (Some(c), Some(k)) => Some((c, k)),
            (None, None) => None,
            _ => bail!("TLS needs both tls_cert and tls_key"),
        };
        let tls_client_ca = pick!(tls_client_ca);
        if tls_client_ca.is_some() && tls.is_none() {
            bail!("tls_client_ca (mTLS) needs TLS: set tls_cert and tls_key too");
        }
        let rate_burst = pick!(rate_burst);
        let rate_limit = match pick!(rate_limit) {
            Some(r) => Some(crate::service::rate_limit::RateSpec::parse(&r, rate_burst).map_err(anyhow::Error::msg)?),
            None if rate_burst.is_some() => bail!("rate_burst needs rate_limit"),
            None => None,
        };
        Ok(Resolved {
            http,
            grpc,
            store: pick!(store).unwrap_or_else(crate::store::default_url),
            render_pool: positive("render_pool", pick!(render_pool).unwrap_or(crate::render::RenderPool::DEFAULT_SIZE))?,
            render_meshes: positive("render_meshes", pick!(render_meshes).unwrap_or(crate::render::RendererConfig::default().max_cached_meshes))?,
            backbone,
            device,
            backbone_batch: pick!(backbone_batch).unwrap_or(32),
            backbone_max_wait: std::time::Duration::from_secs_f64(max_wait_ms / 1e3),
            max_estimates,
            instance_threads: positive("instance_threads", pick!(instance_threads).unwrap_or_else(|| crate::parallel::instance_threads(max_estimates)))?,
            queue_depth,
            queue_timeout: std::time::Duration::from_millis(queue_timeout_ms),
            max_onboardings: positive("max_onboardings", pick!(max_onboardings).unwrap_or(1))?,
            max_body_bytes: positive("max_body_mb", pick!(max_body_mb).unwrap_or(64))? * 1_000_000,
            cache_bytes: pick!(cache_mb).unwrap_or(4000) * 1_000_000,
            request_timeout: (timeout > 0.0).then(|| std::time::Duration::from_secs_f64(timeout)),
            api_keys_file: pick!(api_keys_file),
            api_keys: pick!(api_keys),
            tls,
            tls_client_ca,
            rate_limit,
            read_only: pick!(read_only).unwrap_or(false),
            revalidate: (revalidate_s > 0.0).then(|| std::time::Duration::from_secs_f64(revalidate_s)),
            max_track_sessions: positive("max_track_sessions", pick!(max_track_sessions).unwrap_or(8))?,
            track_idle_timeout: std::time::Duration::from_secs_f64(idle),
            console: pick!(console).unwrap_or(true),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_win_over_the_file_and_the_file_over_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("b2tf.toml");
        std::fs::write(&f, "http = \"0.0.0.0:9000\"\ngrpc = \"none\"\nmax_estimates = 4\nrequest_timeout_s = 0\napi_keys_file = \"keys.txt\"\n").unwrap();
        let file = ServeSettings::from_file(&f).unwrap();
        let flags = ServeSettings { max_estimates: Some(8), ..Default::default() };
        let r = flags.resolve(file).unwrap();
        assert_eq!(r.http.as_deref(), Some("0.0.0.0:9000"));
        assert_eq!(r.grpc, None);
        assert_eq!(r.max_estimates, 8);
        assert_eq!(r.queue_depth, 64, "the queue follows the running count");
        assert_eq!(r.instance_threads, 2, "at least two whatever the cores");
        assert_eq!(r.request_timeout, None);
        assert_eq!(r.api_keys_file, Some(dir.path().join("keys.txt")));
        let d = ServeSettings::default().resolve(ServeSettings::default()).unwrap();
        assert_eq!((d.http.as_deref(), d.grpc.as_deref(), d.max_onboardings), (Some("127.0.0.1:8080"), Some("127.0.0.1:50051"), 1));
        assert_eq!(d.request_timeout, Some(std::time::Duration::from_secs(120)));
        assert_eq!((d.queue_depth, d.queue_timeout), (16, std::time::Duration::from_secs(30)));
        assert_eq!(d.revalidate, Some(std::time::Duration::from_secs(5)));
        assert_eq!(ServeSettings { revalidate_s: Some(0.0), ..Default::default() }.resolve(ServeSettings::default()).unwrap().revalidate, None);
        assert!(!d.read_only);
        std::fs::write(&f, "read_only = true\n").unwrap();
        assert!(ServeSettings::default().resolve(ServeSettings::from_file(&f).unwrap()).unwrap().read_only);
    }

    #[test]
    fn read_only_is_a_flag_or_a_boolish_variable() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            s: ServeSettings,
        }
        assert_eq!(Cli::try_parse_from(["b2tf", "--read-only"]).unwrap().s.read_only, Some(true));
        assert_eq!(Cli::try_parse_from(["b2tf", "--read-only", "false"]).unwrap().s.read_only, Some(false));
        assert!(Cli::try_parse_from(["b2tf", "--read-only", "maybe"]).is_err());
    }

    #[test]
    fn bad_settings_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("bad.toml");
        std::fs::write(&f, "max_estimatez = 3\n").unwrap();
        assert!(format!("{:#}", ServeSettings::from_file(&f).unwrap_err()).contains("max_estimatez"));
        std::fs::write(&f, "max_estimates = \"three\"\n").unwrap();
        assert!(format!("{:#}", ServeSettings::from_file(&f).unwrap_err()).contains("max_estimates"));
        let none = ServeSettings::default;
        let err = |s: ServeSettings| format!("{:#}", s.resolve(none()).unwrap_err());
        assert!(err(ServeSettings { max_estimates: Some(0), ..none() }).contains("max_estimates"));
        assert!(err(ServeSettings { instance_threads: Some(0), ..none() }).contains("instance_threads"));
        assert!(err(ServeSettings { render_meshes: Some(0), ..none() }).contains("render_meshes"));
        assert!(err(ServeSettings { backbone: Some("dinov3".into()), ..none() }).contains("dinov3"));
        assert!(err(ServeSettings { device: Some("gpu".into()), ..none() }).contains("gpu"));
        assert!(err(ServeSettings { backbone_max_wait_ms: Some(-1.0), ..none() }).contains("backbone_max_wait_ms"));
        assert!(err(ServeSettings { tls_cert: Some("c.pem".into()), ..none() }).contains("tls_key"));
        assert!(err(ServeSettings { http: Some("none".into()), grpc: Some("off".into()), ..none() }).contains("both listeners"));
        assert!(err(ServeSettings { request_timeout_s: Some(-1.0), ..none() }).contains("request_timeout_s"));
        assert!(err(ServeSettings { queue_timeout_ms: Some(0), ..none() }).contains("queue_timeout_ms"));
        assert!(err(ServeSettings { revalidate_s: Some(-1.0), ..none() }).contains("revalidate_s"));
        assert!(err(ServeSettings { queue_depth: Some(1_000_000), ..none() }).contains("queue_depth"));
        assert!(err(ServeSettings { tls_client_ca: Some("ca.pem".into()), ..none() }).contains("tls_client_ca (mTLS) needs TLS"));
        assert!(err(ServeSettings { rate_limit: Some("fast".into()), ..none() }).contains("\"fast\""));
        assert!(err(ServeSettings { rate_limit: Some("5/s".into()), rate_burst: Some(0), ..none() }).contains("rate_burst"));
        assert!(err(ServeSettings { rate_burst: Some(3), ..none() }).contains("rate_burst needs rate_limit"));
        let r = ServeSettings { rate_limit: Some("120/m".into()), ..none() }.resolve(none()).unwrap();
        assert_eq!(r.rate_limit, Some(crate::service::rate_limit::RateSpec { rate: 2.0, burst: 2 }));
    }
}
