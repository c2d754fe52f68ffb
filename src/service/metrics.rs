//! Prometheus text-format metrics: requests by route and status, latency histograms per
//! route, estimate stage timings, and gauges read from the core at scrape time (running
//! estimates and onboardings, loaded objects, cache bytes). Hand-written: a few counters
//! do not need a metrics framework.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::Mutex;

/// Upper bounds of the latency buckets, seconds.
const BUCKETS: [f64; 12] = [0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0];

#[derive(Default, Clone)]
struct Histogram {
    counts: [u64; BUCKETS.len()],
    sum: f64,
    count: u64,
}

impl Histogram {
    fn observe(&mut self, v: f64) {
        for (b, c) in BUCKETS.iter().zip(self.counts.iter_mut()) {
            if v <= *b {
                *c += 1;
            }
        }
        self.sum += v;
        self.count += 1;
    }

    fn write(&self, out: &mut String, name: &str, labels: &str) {
        write_histogram(out, name, labels, BUCKETS.iter().map(|b| b.to_string()).zip(self.counts), self.count, self.sum);
    }
}

/// One Prometheus histogram: cumulative `(upper bound, count)` buckets, then +Inf, sum and
/// count. `labels` is empty or ends with a comma.
fn write_histogram(out: &mut String, name: &str, labels: &str, buckets: impl Iterator<Item = (String, u64)>, count: u64, sum: f64) {
    for (bound, c) in buckets {
        let _ = writeln!(out, "{name}_bucket{{{labels}le=\"{bound}\"}} {c}");
    }
    let _ = writeln!(out, "{name}_bucket{{{labels}le=\"+Inf\"}} {count}");
    let own = labels.trim_end_matches(',');
    let own = if own.is_empty() { String::new() } else { format!("{{{own}}}") };
    let _ = writeln!(out, "{name}_sum{own} {sum}");
    let _ = writeln!(out, "{name}_count{own} {count}");
}

/// Each `stage: ms` of a JSON object into its histogram, in seconds.
fn observe_stages(stages: &mut BTreeMap<String, Histogram>, prefix: &str, timings_ms: &BTreeMap<String, f64>) {
    for (stage, ms) in timings_ms {
        stages.entry(format!("{prefix}{stage}")).or_default().observe(ms / 1e3);
    }
}

#[derive(Default)]
struct Inner {
    requests: BTreeMap<(String, String, String), u64>,
    latency: BTreeMap<String, Histogram>,
    stages: BTreeMap<String, Histogram>,
    detections_per_estimate: Histogram,
    detections_per_detect: Histogram,
    track_objects: BTreeMap<String, u64>,
    /// By API key identity; both bounded by the number of keys.
    key_requests: BTreeMap<String, u64>,
    rate_limited: BTreeMap<String, u64>,
    /// How long estimates waited for a slot, those admitted at once included.
    queue_wait: Histogram,
    /// Estimates refused by the queue, by reason (full, deadline, timeout).
    queue_refused: BTreeMap<&'static str, u64>,
}

#[derive(Default)]
pub struct Metrics {
    inner: Mutex<Inner>,
}

/// Values read from the core when scraped.
pub struct Gauges {
    pub estimates_running: usize,
    pub estimates_waiting: usize,
    /// The service time the queue's Retry-After hints come from, once measured.
    pub estimate_service_seconds: Option<f64>,
    pub onboardings_running: usize,
    pub objects_loaded: usize,
    pub cache_bytes: u64,
    /// Cached objects dropped because the store's copy was replaced or deleted.
    pub cache_stale: u64,
    pub ready: bool,
    /// The backbone batching queue, when there is one.
    pub queue: Option<crate::features::batch_queue::QueueStats>,
    /// Tracking sessions open (HTTP sessions and gRPC streams).
    pub track_sessions: usize,
    /// Meshes uploaded to the render pool's renderers.
    pub render_mesh_uploads: u64,
    /// Object thumbnails drawn (not served from those kept).
    pub thumbnails_drawn: u64,
}

impl Metrics {
    /// One finished request. HTTP: method, route template, status code; gRPC: method
    /// "grpc", the full RPC path, the status code's name (e.g. "OK", "NOT_FOUND").
    pub fn request(&self, method: &str, route: &str, status: &str, seconds: f64) {
        let mut g = self.inner.lock().expect("metrics lock");
        *g.requests.entry((method.to_string(), route.to_string(), status.to_string())).or_default() += 1;
        g.latency.entry(format!("{method} {route}")).or_default().observe(seconds);
    }

    /// Stage times of one estimated instance (milliseconds, as the pipeline reports them).
    pub fn stages(&self, timings_ms: &BTreeMap<String, f64>, detections: usize) {
        let mut g = self.inner.lock().expect("metrics lock");
        observe_stages(&mut g.stages, "", timings_ms);
        g.detections_per_estimate.observe(detections as f64);
    }

    /// Stage times (milliseconds) of one Detect call, as stages named `detect_<stage>`,
    /// and how many objects it found.
    pub fn detected(&self, timings_ms: &BTreeMap<String, f64>, found: usize) {
        let mut g = self.inner.lock().expect("metrics lock");
        observe_stages(&mut g.stages, "detect_", timings_ms);
        g.detections_per_detect.observe(found as f64);
    }

    /// The objects of one tracked frame, by how each pose came about.
    pub fn track_frame<'a>(&self, modes: impl Iterator<Item = &'a str>) {
        let mut g = self.inner.lock().expect("metrics lock");
        for m in modes {
            *g.track_objects.entry(m.to_string()).or_default() += 1;
        }
    }

    /// A request admitted with the key of this identity (never the key itself).
    pub fn key_request(&self, identity: &str) {
        *self.inner.lock().expect("metrics lock").key_requests.entry(identity.to_string()).or_default() += 1;
    }

    /// A request refused by the rate limit: the key identity, or "address" when limited
    /// by client address (addresses themselves would make unbounded labels).
    pub fn rate_limited(&self, client: &str) {
        *self.inner.lock().expect("metrics lock").rate_limited.entry(client.to_string()).or_default() += 1;
    }

    /// An estimate or detection that got its slot after waiting this long.
    pub fn queue_wait(&self, seconds: f64) {
        self.inner.lock().expect("metrics lock").queue_wait.observe(seconds);
    }

    /// An estimate or detection the queue turned away (estimate_queue::Refusal's name).
    pub fn queue_refused(&self, reason: &'static str) {
        *self.inner.lock().expect("metrics lock").queue_refused.entry(reason).or_default() += 1;
    }

    pub fn render(&self, gauges: &Gauges) -> String {
        let g = self.inner.lock().expect("metrics lock");
        let mut out = String::new();
        out.push_str("# HELP b2tf_requests_total Requests by method, route and status.\n# TYPE b2tf_requests_total counter\n");
        for ((m, r, s), n) in &g.requests {
            let _ = writeln!(out, "b2tf_requests_total{{method=\"{m}\",route=\"{r}\",status=\"{s}\"}} {n}");
        }
        out.push_str("# HELP b2tf_request_seconds Request latency.\n# TYPE b2tf_request_seconds histogram\n");
        for (key, h) in &g.latency {
            let (m, r) = key.split_once(' ').unwrap_or((key, ""));
            h.write(&mut out, "b2tf_request_seconds", &format!("method=\"{m}\",route=\"{r}\","));
        }
        out.push_str("# HELP b2tf_stage_seconds Estimation stage time per instance; detect_* stages per detect request.\n# TYPE b2tf_stage_seconds histogram\n");
        for (stage, h) in &g.stages {
            h.write(&mut out, "b2tf_stage_seconds", &format!("stage=\"{stage}\","));
        }
        out.push_str("# HELP b2tf_detections_per_estimate Detections in one estimate request.\n# TYPE b2tf_detections_per_estimate histogram\n");
        g.detections_per_estimate.write(&mut out, "b2tf_detections_per_estimate", "");
        out.push_str("# HELP b2tf_detections_per_detect Objects found by one detect request.\n# TYPE b2tf_detections_per_detect histogram\n");
        g.detections_per_detect.write(&mut out, "b2tf_detections_per_detect", "");
        out.push_str("# HELP b2tf_track_objects_total Objects in tracked frames, by mode (tracked, reinitialised, lost, ...).\n# TYPE b2tf_track_objects_total counter\n");
        for (mode, n) in &g.track_objects {
            let _ = writeln!(out, "b2tf_track_objects_total{{mode=\"{mode}\"}} {n}");
        }
        out.push_str("# HELP b2tf_key_requests_total Requests admitted, by API key identity (its name= or key-<digest prefix>).\n# TYPE b2tf_key_requests_total counter\n");
        for (key, n) in &g.key_requests {
            let _ = writeln!(out, "b2tf_key_requests_total{{key=\"{key}\"}} {n}");
        }
        out.push_str("# HELP b2tf_rate_limited_total Requests refused by the rate limit, by API key identity (\"address\": limited by client address).\n# TYPE b2tf_rate_limited_total counter\n");
        for (client, n) in &g.rate_limited {
            let _ = writeln!(out, "b2tf_rate_limited_total{{client=\"{client}\"}} {n}");
        }
        out.push_str("# HELP b2tf_estimate_queue_wait_seconds Time estimates and detections waited for a slot (0 when one was free).\n# TYPE b2tf_estimate_queue_wait_seconds histogram\n");
        g.queue_wait.write(&mut out, "b2tf_estimate_queue_wait_seconds", "");
        out.push_str("# HELP b2tf_estimate_queue_refused_total Estimates and detections refused by the queue: full, deadline (the wait would pass it), timeout (--queue-timeout-ms).\n# TYPE b2tf_estimate_queue_refused_total counter\n");
        for (reason, n) in &g.queue_refused {
            let _ = writeln!(out, "b2tf_estimate_queue_refused_total{{reason=\"{reason}\"}} {n}");
        }
        let gauge = |out: &mut String, name: &str, help: &str, v: f64| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} gauge\n{name} {v}");
        };
        gauge(&mut out, "b2tf_estimates_running", "Estimates and detections in progress (at most --max-estimates).", gauges.estimates_running as f64);
        gauge(&mut out, "b2tf_estimate_queue_length", "Estimates and detections waiting for a slot (at most --queue-depth).", gauges.estimates_waiting as f64);
        if let Some(s) = gauges.estimate_service_seconds {
            gauge(&mut out, "b2tf_estimate_service_seconds", "Running mean of the time one estimate holds its slot (the base of Retry-After hints).", s);
        }
        gauge(&mut out, "b2tf_onboardings_running", "Onboardings in progress.", gauges.onboardings_running as f64);
        gauge(&mut out, "b2tf_objects_loaded", "Objects held in the model cache.", gauges.objects_loaded as f64);
        gauge(&mut out, "b2tf_cache_bytes", "Bytes held by the model cache.", gauges.cache_bytes as f64);
        let _ = writeln!(
            out,
            "# HELP b2tf_cache_stale_total Cached objects dropped because another process replaced or deleted them in the store.\n# TYPE b2tf_cache_stale_total counter\nb2tf_cache_stale_total {}",
            gauges.cache_stale
        );
        let _ = writeln!(out, "# HELP b2tf_render_mesh_uploads_total Meshes uploaded to the render pool's renderers: one per object and renderer when each holds what it renders; more means renderers evict meshes (over 8 objects in use at once) and upload them again.\n# TYPE b2tf_render_mesh_uploads_total counter\nb2tf_render_mesh_uploads_total {}", gauges.render_mesh_uploads);
        let _ = writeln!(out, "# HELP b2tf_thumbnails_drawn_total Object thumbnails drawn (the console's pictures); requests answered from those kept, or that waited for the same drawing, add nothing.\n# TYPE b2tf_thumbnails_drawn_total counter\nb2tf_thumbnails_drawn_total {}", gauges.thumbnails_drawn);
        gauge(&mut out, "b2tf_ready", "1 once warmed up.", if gauges.ready { 1.0 } else { 0.0 });
        gauge(&mut out, "b2tf_track_sessions_open", "Tracking sessions open (HTTP sessions and gRPC Track streams).", gauges.track_sessions as f64);
        if let Some(q) = &gauges.queue {
            gauge(&mut out, "b2tf_backbone_queue_depth", "Crops waiting for the backbone.", q.queued_crops as f64);
            out.push_str("# HELP b2tf_backbone_batch_crops Crops per backbone forward pass (requests batched together).\n# TYPE b2tf_backbone_batch_crops histogram\n");
            let buckets = crate::features::batch_queue::BATCH_BUCKETS.iter().map(|b| b.to_string()).zip(q.batch_buckets.iter().copied());
            write_histogram(&mut out, "b2tf_backbone_batch_crops", "", buckets, q.passes, q.crops as f64);
            let summary = |out: &mut String, name: &str, help: &str, count: u64, sum: f64| {
                let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} summary\n{name}_sum {sum}\n{name}_count {count}");
            };
            summary(&mut out, "b2tf_backbone_queue_wait_seconds", "Time requests waited for their backbone pass.", q.jobs, q.wait_seconds);
            summary(&mut out, "b2tf_backbone_pass_seconds", "Backbone forward pass time.", q.passes, q.pass_seconds);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_counters_histograms_and_gauges() {
        let m = Metrics::default();
        m.request("POST", "/v1/estimate", "200", 0.3);
        m.request("POST", "/v1/estimate", "200", 0.03);
        m.request("POST", "/v1/estimate", "429", 0.001);
        m.request("grpc", "/b2tfpose.v1.PoseService/Estimate", "NOT_FOUND", 0.001);
        m.stages(&BTreeMap::from([("pnp".to_string(), 4.0), ("total".to_string(), 150.0)]), 2);
        m.key_request("cell-7");
        m.rate_limited("cell-7");
        m.rate_limited("cell-7");
        m.queue_wait(0.0);
        m.queue_wait(0.7);
        m.queue_refused("full");
        let text = m.render(&Gauges {
            estimates_running: 1,
            estimates_waiting: 4,
            estimate_service_seconds: Some(0.6),
            onboardings_running: 0,
            objects_loaded: 3,
            cache_bytes: 42,
            cache_stale: 1,
            ready: true,
            queue: Some(crate::features::batch_queue::QueueStats {
                queued_crops: 3,
                passes: 2,
                crops: 11,
                batch_buckets: vec![0, 0, 0, 1, 2, 2, 2, 2],
                jobs: 5,
                wait_seconds: 0.25,
                pass_seconds: 0.5,
            }),
            track_sessions: 2,
            render_mesh_uploads: 7,
            thumbnails_drawn: 5,
        });
        assert!(text.contains("b2tf_requests_total{method=\"POST\",route=\"/v1/estimate\",status=\"200\"} 2"), "{text}");
        assert!(text.contains("b2tf_request_seconds_bucket{method=\"POST\",route=\"/v1/estimate\",le=\"0.05\"} 2"), "{text}");
        assert!(text.contains("b2tf_request_seconds_count{method=\"POST\",route=\"/v1/estimate\"} 3"), "{text}");
        assert!(text.contains("b2tf_requests_total{method=\"grpc\",route=\"/b2tfpose.v1.PoseService/Estimate\",status=\"NOT_FOUND\"} 1"), "{text}");
        assert!(text.contains("b2tf_stage_seconds_bucket{stage=\"pnp\",le=\"0.005\"} 1"), "{text}");
        assert!(text.contains("b2tf_backbone_queue_depth 3") && text.contains("b2tf_backbone_batch_crops_bucket{le=\"8\"} 1") && text.contains("b2tf_backbone_batch_crops_count 2"), "{text}");
        assert!(text.contains("b2tf_backbone_queue_wait_seconds_sum 0.25\nb2tf_backbone_queue_wait_seconds_count 5") && text.contains("b2tf_backbone_pass_seconds_count 2"), "{text}");
        assert!(text.contains("b2tf_key_requests_total{key=\"cell-7\"} 1") && text.contains("b2tf_rate_limited_total{client=\"cell-7\"} 2"), "{text}");
        assert!(text.contains("b2tf_estimate_queue_wait_seconds_bucket{le=\"0.5\"} 1") && text.contains("b2tf_estimate_queue_wait_seconds_count 2"), "{text}");
        assert!(text.contains("b2tf_estimate_queue_refused_total{reason=\"full\"} 1") && text.contains("b2tf_estimate_queue_length 4") && text.contains("b2tf_estimate_service_seconds 0.6"), "{text}");
        assert!(text.contains("b2tf_objects_loaded 3") && text.contains("b2tf_cache_bytes 42") && text.contains("b2tf_cache_stale_total 1") && text.contains("b2tf_ready 1"), "{text}");
        assert!(text.contains("b2tf_render_mesh_uploads_total 7\n") && text.contains("b2tf_thumbnails_drawn_total 5\n"), "{text}");
    }
}
