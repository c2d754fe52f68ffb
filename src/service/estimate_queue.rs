//! The waiting line in front of the estimate slots, as inference servers keep one: up to
//! `running` estimates (and detections) run at once, up to `depth` more wait in arrival
//! order, each at most `timeout`. A request is refused (429 / RESOURCE_EXHAUSTED) only when
//! the line is full, when the wait it would have passes its deadline, or when it waited
//! its longest; each refusal says when to come back, from the measured service time.
//! A request whose client goes away leaves the line at once (its future is dropped).

use super::error::ServiceError;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QueueConfig {
    /// Estimates running at once.
    pub running: usize,
    /// Estimates waiting at most (0: refuse at once when all run).
    pub depth: usize,
    /// Longest one waits.
    pub timeout: Duration,
}

/// What the service time is taken to be before any estimate has finished.
const FIRST_GUESS: Duration = Duration::from_secs(1);
/// Weight of the newest estimate in the running mean of service times.
const SMOOTHING: f64 = 0.2;

/// Why a request was turned away (the `reason` label of the refusal counter).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// `depth` requests already wait.
    Full,
    /// The expected wait alone passes the request's deadline.
    Deadline,
    /// It waited `timeout` without a slot.
    Timeout,
}

impl Refusal {
    pub fn name(self) -> &'static str {
        match self {
            Refusal::Full => "full",
            Refusal::Deadline => "deadline",
            Refusal::Timeout => "timeout",
        }
    }
}

pub struct EstimateQueue {
    config: QueueConfig,
    slots: Arc<Semaphore>,
    waiting: AtomicUsize,
    /// Running mean of how long one estimate holds its slot, seconds; None before the first.
    service_s: Mutex<Option<f64>>,
}

/// A running estimate's slot: freed, and its time counted, when dropped (it travels to the
/// thread doing the work, so a request abandoned by its client frees it only once the
/// work stops).
pub struct Turn {
    _permit: OwnedSemaphorePermit,
    queue: Arc<EstimateQueue>,
    started: Instant,
    /// How long it waited for the slot.
    pub waited: Duration,
}

impl Drop for Turn {
    fn drop(&mut self) {
        self.queue.observe_service(self.started.elapsed());
    }
}

/// Leaves the count of waiting requests however the wait ends (slot, timeout, hang-up).
struct Waiting<'a>(&'a AtomicUsize);

impl Drop for Waiting<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl EstimateQueue {
    pub fn new(config: QueueConfig) -> Arc<Self> {
        Arc::new(Self { config, slots: Arc::new(Semaphore::new(config.running)), waiting: AtomicUsize::new(0), service_s: Mutex::new(None) })
    }

    /// Estimates running now.
    pub fn running(&self) -> usize {
        self.config.running - self.slots.available_permits().min(self.config.running)
    }

    /// Estimates waiting now.
    pub fn waiting(&self) -> usize {
        self.waiting.load(Ordering::Acquire)
    }

    /// The running mean of the service time, once an estimate has finished.
    pub fn service_time(&self) -> Option<Duration> {
        self.service_s.lock().expect("queue lock").map(Duration::from_secs_f64)
    }

    fn observe_service(&self, took: Duration) {
        let mut s = self.service_s.lock().expect("queue lock");
        let t = took.as_secs_f64();
        *s = Some(match *s {
            Some(mean) => mean + SMOOTHING * (t - mean),
            None => t,
        });
    }

    /// How long a request with `ahead` others waiting before it should expect to wait:
    /// the slots serve `running` at a time, so `ahead + 1` requests need that many service
    /// times divided among the slots.
    pub fn expected_wait(&self, ahead: usize) -> Duration {
        let service = self.service_time().unwrap_or(FIRST_GUESS);
        service.mul_f64((ahead + 1) as f64 / self.config.running as f64)
    }

    /// A slot, at once or after waiting in line; `budget`: the request's own time limit,
    /// which the wait counts against.
    pub async fn enter(self: &Arc<Self>, budget: Option<Duration>) -> Result<Turn, (Refusal, ServiceError)> {
        let arrived = Instant::now();
        let turn = |permit, queue: &Arc<Self>| Turn { _permit: permit, queue: queue.clone(), started: Instant::now(), waited: arrived.elapsed() };
        if let Ok(p) = self.slots.clone().try_acquire_owned() {
            return Ok(turn(p, self));
        }
        let depth = self.config.depth;
        let Ok(ahead) = self.waiting.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| (n < depth).then_some(n + 1)) else {
            let wait = self.expected_wait(depth);
            return Err((
                Refusal::Full,
                ServiceError::exhausted(
                    format!(
                        "{} estimates or detections are running and {depth} waiting (the server's limits, --max-estimates and --queue-depth); retry in {} ms",
                        self.config.running,
                        wait.as_millis()
                    ),
                    wait,
                ),
            ));
        };
        let _waiting = Waiting(&self.waiting);
        let expected = self.expected_wait(ahead);
        if let (Some(b), Some(_)) = (budget, self.service_time()) {
            if expected > b {
                return Err((
                    Refusal::Deadline,
                    ServiceError::exhausted(
                        format!(
                            "the wait for a free slot, about {} ms with {ahead} request(s) ahead, would pass this request's deadline of {} ms; retry later or allow more time",
                            expected.as_millis(),
                            b.as_millis()
                        ),
                        expected,
                    ),
                ));
            }
        }
        let limit = budget.map_or(self.config.timeout, |b| b.min(self.config.timeout));
        match tokio::time::timeout(limit, self.slots.clone().acquire_owned()).await {
            Ok(Ok(p)) => Ok(turn(p, self)),
            Ok(Err(_)) => Err((Refusal::Timeout, ServiceError::internal("the estimate queue was closed"))),
            Err(_) if budget.is_some_and(|b| b <= self.config.timeout) => Err((Refusal::Deadline, super::error::deadline_exceeded(budget.unwrap_or_default()))),
            Err(_) => {
                let wait = self.expected_wait(self.waiting());
                Err((
                    Refusal::Timeout,
                    ServiceError::exhausted(format!("waited {} ms for a free slot (the server's --queue-timeout-ms) without one; retry in {} ms", limit.as_millis(), wait.as_millis()), wait),
                ))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::error::ErrorKind;

    fn queue(running: usize, depth: usize, timeout_ms: u64) -> Arc<EstimateQueue> {
        EstimateQueue::new(QueueConfig { running, depth, timeout: Duration::from_millis(timeout_ms) })
    }

    #[tokio::test]
    async fn runs_up_to_the_limit_then_waits_in_order_then_refuses() {
        let q = queue(2, 2, 10_000);
        let a = q.enter(None).await.unwrap();
        let _b = q.enter(None).await.unwrap();
        assert_eq!((q.running(), q.waiting()), (2, 0));
        let order = Arc::new(Mutex::new(Vec::new()));
        let waiter = |name: &'static str| {
            let (q, order) = (q.clone(), order.clone());
            tokio::spawn(async move {
                let t = q.enter(None).await.unwrap();
                order.lock().unwrap().push(name);
                tokio::time::sleep(Duration::from_millis(10)).await;
                drop(t);
            })
        };
        let c = waiter("c");
        tokio::task::yield_now().await;
        let d = waiter("d");
        tokio::task::yield_now().await;
        assert_eq!(q.waiting(), 2);
        // The line is full: refused at once, with a wait to come back after.
        let (why, e) = q.enter(None).await.err().unwrap();
        assert_eq!(why, Refusal::Full);
        assert!(e.kind == ErrorKind::ResourceExhausted && e.message.contains("--queue-depth") && e.retry_after_ms.is_some(), "{e:?}");
        drop(a);
        c.await.unwrap();
        d.await.unwrap();
        assert_eq!(*order.lock().unwrap(), ["c", "d"], "first come, first served");
        assert_eq!(q.waiting(), 0);
    }

    #[tokio::test]
    async fn a_wait_past_the_queue_timeout_is_refused_with_a_hint() {
        let q = queue(1, 4, 200);
        let _a = q.enter(None).await.unwrap();
        let t0 = Instant::now();
        let (why, e) = q.enter(None).await.err().unwrap();
        assert_eq!(why, Refusal::Timeout);
        assert!(t0.elapsed() >= Duration::from_millis(200));
        assert!(e.kind == ErrorKind::ResourceExhausted && e.message.contains("--queue-timeout-ms") && e.retry_after_ms.is_some(), "{e:?}");
        assert_eq!(q.waiting(), 0);
    }

    #[tokio::test]
    async fn a_wait_past_the_deadline_is_refused_up_front_once_the_service_time_is_known() {
        let q = queue(1, 4, 60_000);
        // Before any estimate finished nothing is predicted: the request waits its budget.
        let a = q.enter(None).await.unwrap();
        let t0 = Instant::now();
        let (why, e) = q.enter(Some(Duration::from_millis(100))).await.err().unwrap();
        assert_eq!((why, e.kind), (Refusal::Deadline, ErrorKind::DeadlineExceeded));
        assert!(t0.elapsed() >= Duration::from_millis(100));
        q.observe_service(Duration::from_secs(20));
        let t0 = Instant::now();
        let (why, e) = q.enter(Some(Duration::from_secs(15))).await.err().unwrap();
        assert_eq!(why, Refusal::Deadline);
        assert!(t0.elapsed() < Duration::from_secs(15), "refused without waiting");
        assert!(e.kind == ErrorKind::ResourceExhausted && e.retry_after_ms == Some(20_000) && e.message.contains("deadline"), "{e:?}");
        // With time enough it waits and gets the slot.
        let q2 = q.clone();
        let waiter = tokio::spawn(async move { q2.enter(Some(Duration::from_secs(50))).await.map(|t| t.waited) });
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(q.waiting(), 1);
        drop(a);
        assert!(waiter.await.unwrap().unwrap() >= Duration::from_millis(100));
    }

    #[tokio::test]
    async fn a_client_that_hangs_up_leaves_the_line() {
        let q = queue(1, 1, 60_000);
        let a = q.enter(None).await.unwrap();
        let q2 = q.clone();
        let gone = tokio::spawn(async move { q2.enter(None).await.map(|_| ()) });
        tokio::task::yield_now().await;
        assert_eq!(q.waiting(), 1);
        gone.abort();
        let _ = gone.await;
        assert_eq!(q.waiting(), 0);
        // Its place is free again, and the slot goes to whoever waits next.
        let q3 = q.clone();
        let next = tokio::spawn(async move { q3.enter(None).await.map(|_| ()) });
        tokio::task::yield_now().await;
        drop(a);
        assert!(next.await.unwrap().is_ok());
    }

    #[test]
    fn the_expected_wait_shares_the_requests_ahead_among_the_slots() {
        let q = queue(2, 8, 1000);
        assert_eq!(q.expected_wait(0), Duration::from_millis(500), "first guess: 1 s per estimate");
        q.observe_service(Duration::from_millis(400));
        q.observe_service(Duration::from_millis(900));
        // A running mean: 400 + 0.2 × 500.
        assert_eq!(q.service_time(), Some(Duration::from_millis(500)));
        assert_eq!(q.expected_wait(3), Duration::from_millis(1000));
    }
}
