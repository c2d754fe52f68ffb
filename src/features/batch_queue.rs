//! A single-owner batching queue in front of a backbone: requests from many threads (one
//! estimate's query and RRC crops, an onboarding's view batches) go through one channel
//! to one worker, which runs whatever has queued up as one forward pass. An accelerator
//! then sees large batches under load. By default no request waits for a batch to fill;
//! `max_wait` lets the worker hold a pass that long after its first request to collect
//! more (worth it where a pass costs about the same for 1 crop as for 32, on a GPU), the
//! layout of text-embeddings-inference's router → queue → backend.

use super::backbone::{Backbone, BackboneIdentity, FeatureError, FeatureMap};
use super::crop::CropInput;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Upper bounds of the batch-size histogram (crops per forward pass).
pub const BATCH_BUCKETS: [usize; 8] = [1, 2, 4, 8, 16, 32, 64, 128];

struct Job {
    crops: Vec<CropInput>,
    queued_at: Instant,
    reply: SyncSender<Result<Vec<FeatureMap>, FeatureError>>,
}

#[derive(Default)]
struct Counters {
    /// Crops waiting for the worker.
    queued: AtomicUsize,
    passes: AtomicU64,
    crops: AtomicU64,
    /// Requests served, their summed wait before their pass started, and the passes'
    /// summed run time, microseconds.
    jobs: AtomicU64,
    wait_us: AtomicU64,
    pass_us: AtomicU64,
    /// Passes per `BATCH_BUCKETS` bound (cumulative like Prometheus' `le`), then +Inf.
    buckets: [AtomicU64; BATCH_BUCKETS.len()],
}

/// What the queue has done, for metrics.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct QueueStats {
    pub queued_crops: usize,
    pub passes: u64,
    pub crops: u64,
    /// Cumulative counts per `BATCH_BUCKETS` bound.
    pub batch_buckets: Vec<u64>,
    /// Requests served; their total wait in the queue and the passes' total time, seconds.
    pub jobs: u64,
    pub wait_seconds: f64,
    pub pass_seconds: f64,
}

pub struct BatchingBackbone {
    identity: BackboneIdentity,
    /// The inner backbone's `reduced_input_size`, answered here without the queue.
    reduced_input_size: Option<u32>,
    /// `None` only while dropping.
    jobs: Option<Sender<Job>>,
    counters: Arc<Counters>,
    worker: Option<std::thread::JoinHandle<()>>,
}

impl BatchingBackbone {
    /// Starts the worker. A pass takes whole requests in arrival order up to `max_batch`
    /// crops (a larger single request runs alone, whole), without waiting for more.
    pub fn new(inner: Arc<dyn Backbone>, max_batch: usize) -> Self {
        Self::with_max_wait(inner, max_batch, Duration::ZERO)
    }

    /// As `new`, but a pass waits up to `max_wait` after its first request for more
    /// requests, until it holds `max_batch` crops.
    pub fn with_max_wait(inner: Arc<dyn Backbone>, max_batch: usize, max_wait: Duration) -> Self {
        let (tx, rx) = channel::<Job>();
        let counters = Arc::new(Counters::default());
        let identity = inner.identity();
        let reduced_input_size = inner.reduced_input_size();
        let worker_counters = counters.clone();
        let worker =
            std::thread::Builder::new().name("backbone-queue".into()).spawn(move || worker(inner, rx, max_batch.max(1), max_wait, worker_counters)).expect("spawning the backbone queue thread");
        Self { identity, reduced_input_size, jobs: Some(tx), counters, worker: Some(worker) }
    }

    pub fn stats(&self) -> QueueStats {
        let c = &self.counters;
        QueueStats {
            queued_crops: c.queued.load(Ordering::Relaxed),
            passes: c.passes.load(Ordering::Relaxed),
            crops: c.crops.load(Ordering::Relaxed),
            batch_buckets: c.buckets.iter().map(|b| b.load(Ordering::Relaxed)).collect(),
            jobs: c.jobs.load(Ordering::Relaxed),
            wait_seconds: c.wait_us.load(Ordering::Relaxed) as f64 * 1e-6,
            pass_seconds: c.pass_us.load(Ordering::Relaxed) as f64 * 1e-6,
        }
    }
}

/// Dropping the queue waits for its worker to drop the backbone. A process that returns
/// from `main` while the worker is still releasing a GPU session crashes in its exit: ONNX
/// Runtime's CUDA allocator frees pinned memory after the CUDA driver has shut down and
/// aborts ("CUDA failure 4: driver shutting down", seen when `b2tf serve` on `cuda:0`
/// stopped).
impl Drop for BatchingBackbone {
    fn drop(&mut self) {
        drop(self.jobs.take()); // the worker's `recv` fails once the pass in hand is done
        if let Some(worker) = self.worker.take() {
            if worker.join().is_err() {
                tracing::warn!("the backbone queue worker panicked while stopping");
            }
        }
    }
}

fn worker(inner: Arc<dyn Backbone>, rx: Receiver<Job>, max_batch: usize, max_wait: Duration, counters: Arc<Counters>) {
    // The backbone runs on a thread pool of its own: callers may be rayon tasks of the
    // global pool (onboarding runs views in parallel) blocked on their replies, and a
    // backbone parallelising on that same pool would wait for them forever.
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let pool = match rayon::ThreadPoolBuilder::new().num_threads(threads).thread_name(|i| format!("backbone-{i}")).build() {
        Ok(p) => p,
        Err(e) => {
            tracing::error!("backbone queue: cannot start its thread pool: {e}");
            return; // callers then get "the backbone queue worker stopped"
        }
    };
    let mut carry: Option<Job> = None;
    loop {
        // Block for the first request only; then take what is already waiting.
        let first = match carry.take() {
            Some(j) => j,
            None => match rx.recv() {
                Ok(j) => j,
                Err(_) => return, // every sender dropped: the backbone is gone
            },
        };
        let mut batch = vec![first];
        let mut size = batch[0].crops.len();
        let deadline = Instant::now() + max_wait;
        while size < max_batch {
            // Without a wait (or past it) only what is already queued joins the pass.
            let left = deadline.saturating_duration_since(Instant::now());
            let next = if left.is_zero() { rx.try_recv().ok() } else { rx.recv_timeout(left).ok() };
            match next {
                Some(j) if size + j.crops.len() <= max_batch => {
                    size += j.crops.len();
                    batch.push(j);
                }
                Some(j) => {
                    carry = Some(j);
                    break;
                }
                None => break,
            }
        }
        let started = Instant::now();
        let waited: u64 = batch.iter().map(|j| started.duration_since(j.queued_at).as_micros() as u64).sum();
        counters.queued.fetch_sub(size, Ordering::Relaxed);
        let lens: Vec<usize> = batch.iter().map(|j| j.crops.len()).collect();
        let crops: Vec<CropInput> = batch.iter_mut().flat_map(|j| std::mem::take(&mut j.crops)).collect();
        // A panicking backend fails this pass's requests, not the queue.
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| pool.install(|| inner.extract(&crops)))).unwrap_or_else(|_| Err(FeatureError::Backend("the backbone panicked".into())));
        counters.passes.fetch_add(1, Ordering::Relaxed);
        counters.jobs.fetch_add(batch.len() as u64, Ordering::Relaxed);
        counters.wait_us.fetch_add(waited, Ordering::Relaxed);
        counters.pass_us.fetch_add(started.elapsed().as_micros() as u64, Ordering::Relaxed);
        counters.crops.fetch_add(size as u64, Ordering::Relaxed);
        for (bound, count) in BATCH_BUCKETS.iter().zip(&counters.buckets) {
            if size <= *bound {
                count.fetch_add(1, Ordering::Relaxed);
            }
        }
        match result {
            Ok(mut maps) => {
                // Hand each request its own maps, in order.
                for (job, n) in batch.into_iter().zip(lens).rev() {
                    let Some(start) = maps.len().checked_sub(n) else {
                        let _ = job.reply.send(Err(FeatureError::Backend("the backbone returned too few feature maps".into())));
                        continue;
                    };
                    let mine = maps.split_off(start);
                    let _ = job.reply.send(Ok(mine));
                }
            }
            Err(e) => {
                let message = e.to_string();
                for job in batch {
                    let _ = job.reply.send(Err(FeatureError::Backend(message.clone())));
                }
            }
        }
    }
}

impl Backbone for BatchingBackbone {
    fn identity(&self) -> BackboneIdentity {
        self.identity.clone()
    }

    fn reduced_input_size(&self) -> Option<u32> {
        self.reduced_input_size
    }

    fn extract(&self, crops: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError> {
        if crops.is_empty() {
            return Ok(Vec::new());
        }
        super::backbone::check_sizes(crops, self.identity.input_size, self.reduced_input_size)?;
        let (reply, answer) = sync_channel(1);
        self.counters.queued.fetch_add(crops.len(), Ordering::Relaxed);
        let sent = self.jobs.as_ref().map(|jobs| jobs.send(Job { crops: crops.to_vec(), queued_at: Instant::now(), reply }));
        if !matches!(sent, Some(Ok(()))) {
            self.counters.queued.fetch_sub(crops.len(), Ordering::Relaxed);
            return Err(FeatureError::Backend("the backbone queue has stopped".into()));
        }
        answer.recv().map_err(|_| FeatureError::Backend("the backbone queue worker stopped".into()))?
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::{EmbeddedBackbone, EmbeddedConfig};

    fn crops(n: usize, seed: u8) -> Vec<CropInput> {
        (0..n)
            .map(|i| {
                let v = seed.wrapping_mul(31).wrapping_add(i as u8 * 17);
                let rgb = image::RgbImage::from_fn(512, 512, |x, y| image::Rgb([((x / 8) as u8).wrapping_add(v), ((y / 8) as u8) ^ v, v]));
                let mask = image::GrayImage::from_fn(512, 512, |x, y| image::Luma([if (100..400).contains(&x) && (50..450).contains(&y) { 255 } else { 0 }]));
                CropInput { rgb, mask }
            })
            .collect()
    }

    #[test]
    fn concurrent_requests_get_their_own_features_in_shared_passes() {
        let inner: Arc<dyn Backbone> = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap());
        let queue = Arc::new(BatchingBackbone::new(inner.clone(), 8));
        assert_eq!(queue.identity(), inner.identity());
        let requests: Vec<Vec<CropInput>> = (0..6).map(|r| crops(1 + r % 3, r as u8)).collect();
        let direct: Vec<Vec<FeatureMap>> = requests.iter().map(|c| inner.extract(c).unwrap()).collect();
        let queued: Vec<Vec<FeatureMap>> = std::thread::scope(|s| {
            let hs: Vec<_> = requests.iter().map(|c| s.spawn(|| queue.extract(c).unwrap())).collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for (d, q) in direct.iter().zip(&queued) {
            assert_eq!(d.len(), q.len());
            for (a, b) in d.iter().zip(q) {
                assert_eq!(a.local, b.local);
                assert_eq!(a.global, b.global);
            }
        }
        let st = queue.stats();
        let total: usize = requests.iter().map(Vec::len).sum();
        assert_eq!((st.crops, st.queued_crops), (total as u64, 0));
        assert!(st.passes >= 2 && st.passes <= requests.len() as u64, "{st:?}");
        assert_eq!(*st.batch_buckets.last().unwrap(), st.passes);
        // Bad input is refused before queueing, naming the crop.
        let mut bad = crops(2, 9);
        bad[1].rgb = image::RgbImage::new(64, 64);
        assert!(matches!(queue.extract(&bad), Err(FeatureError::WrongSize { index: 1, .. })));
        assert!(queue.extract(&[]).unwrap().is_empty());
        // The inner backbone's reduced crops pass the queue too, in a batch with full ones.
        assert_eq!(queue.reduced_input_size(), inner.reduced_input_size());
        let half = inner.reduced_input_size().unwrap();
        let mut mixed = crops(2, 5);
        mixed[1] = CropInput { rgb: image::imageops::thumbnail(&mixed[1].rgb, half, half), mask: image::imageops::thumbnail(&mixed[1].mask, half, half) };
        let (d, q) = (inner.extract(&mixed).unwrap(), queue.extract(&mixed).unwrap());
        assert_eq!((q[1].grid, &q[1].local), (d[1].grid, &d[1].local));
        assert_eq!(q[1].grid.n, q[0].grid.n);
    }

    #[test]
    fn a_pass_waits_for_more_requests_up_to_max_wait() {
        let inner: Arc<dyn Backbone> = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap());
        // Two requests 50 ms apart: a 5 s wait puts them in one pass (the wait ends as soon
        // as the batch is full, so the test does not take 5 s).
        let queue = Arc::new(BatchingBackbone::with_max_wait(inner, 2, Duration::from_secs(5)));
        let t = Instant::now();
        std::thread::scope(|s| {
            let a = s.spawn(|| queue.extract(&crops(1, 1)).unwrap());
            std::thread::sleep(Duration::from_millis(50));
            let b = s.spawn(|| queue.extract(&crops(1, 2)).unwrap());
            a.join().unwrap();
            b.join().unwrap();
        });
        let st = queue.stats();
        assert_eq!((st.passes, st.crops, st.jobs), (1, 2, 2), "{st:?}");
        assert!(t.elapsed() < Duration::from_secs(4), "the full batch still waited {:?}", t.elapsed());
        // The first request waited for the second: at least the 50 ms between them.
        assert!(st.wait_seconds >= 0.04 && st.pass_seconds > 0.0, "{st:?}");
    }

    #[test]
    fn callers_on_the_global_rayon_pool_do_not_deadlock() {
        // Onboarding calls the backbone from rayon tasks; the queue's backbone parallelises
        // too. Run in a thread with a time limit so a regression fails instead of hanging.
        use rayon::prelude::*;
        let inner: Arc<dyn Backbone> = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap());
        let queue = Arc::new(BatchingBackbone::new(inner, 4));
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let n: usize = (0..8u8).into_par_iter().map(|i| queue.extract(&crops(2, i)).map(|m| m.len()).unwrap_or(0)).sum();
            let _ = tx.send(n);
        });
        assert_eq!(rx.recv_timeout(std::time::Duration::from_secs(120)).expect("deadlock: no answer within 120 s"), 16);
    }

    struct Panics;
    impl Backbone for Panics {
        fn identity(&self) -> BackboneIdentity {
            BackboneIdentity { name: "panics".into(), weights_hash: String::new(), layers: String::new(), input_size: 512, patch_size: 16, local_dim: 1, global_dim: 1 }
        }
        fn extract(&self, _: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError> {
            panic!("backend bug")
        }
    }

    /// Releases slowly, as a GPU session does, and says when it is gone.
    struct SlowToRelease(Arc<std::sync::atomic::AtomicBool>);
    impl Backbone for SlowToRelease {
        fn identity(&self) -> BackboneIdentity {
            Panics.identity()
        }
        fn extract(&self, _: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError> {
            Ok(Vec::new())
        }
    }
    impl Drop for SlowToRelease {
        fn drop(&mut self) {
            std::thread::sleep(Duration::from_millis(200));
            self.0.store(true, Ordering::SeqCst);
        }
    }

    #[test]
    fn dropping_the_queue_waits_until_its_backbone_is_released() {
        let released = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let queue = BatchingBackbone::new(Arc::new(SlowToRelease(released.clone())), 4);
        let _ = queue.extract(&crops(1, 0)); // one pass, answered (as "too few maps") before the drop
        drop(queue);
        assert!(released.load(Ordering::SeqCst), "the queue returned before its worker released the backbone");
    }

    #[test]
    fn a_panicking_backend_fails_the_request_not_the_queue() {
        let queue = BatchingBackbone::new(Arc::new(Panics), 4);
        for _ in 0..2 {
            let e = queue.extract(&crops(1, 0)).unwrap_err();
            assert!(e.to_string().contains("panicked"), "{e}");
        }
    }
}
