//! Jobs run side by side on a few plain threads, answers kept in the jobs' order: how one
//! request's instances are estimated in parallel (the service, `bop run`, `bench estimate`).
//!
//! Plain threads rather than rayon tasks, on purpose: an instance's estimate blocks on the
//! render pool and on the backbone's queue, and its own stages already spread over rayon's
//! pool. A rayon worker that blocked there would hold a core of that pool, and one that
//! stole another instance while waiting on its own stages could end up waiting on itself.
//! A plain thread that calls into rayon only hands work to the pool and waits.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

/// `f` over `items` on up to `threads` threads (at least one; none started for one job or
/// one thread), answers in the items' order. The first error stops jobs not yet started
/// and is returned (of several, the one of the earliest item); jobs already running finish.
/// The caller's tracing span is entered on every thread, so the jobs' logs keep the
/// request they belong to.
pub fn ordered_map<T, R, E>(items: Vec<T>, threads: usize, f: impl Fn(T) -> Result<R, E> + Sync) -> Result<Vec<R>, E>
where
    T: Send,
    R: Send,
    E: Send,
{
    let threads = threads.max(1).min(items.len());
    if threads <= 1 {
        return items.into_iter().map(f).collect();
    }
    let n = items.len();
    let items: Vec<Mutex<Option<T>>> = items.into_iter().map(|t| Mutex::new(Some(t))).collect();
    let answers: Vec<Mutex<Option<Result<R, E>>>> = (0..n).map(|_| Mutex::new(None)).collect();
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let span = tracing::Span::current();
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                let _entered = span.enter();
                while !failed.load(Ordering::Relaxed) {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(i).and_then(|slot| slot.lock().unwrap_or_else(|e| e.into_inner()).take()) else { break };
                    let answer = f(item);
                    if answer.is_err() {
                        failed.store(true, Ordering::Relaxed);
                    }
                    *answers[i].lock().unwrap_or_else(|e| e.into_inner()) = Some(answer);
                }
            });
        }
    });
    // Jobs run in order of their index, so every job before an error has its answer;
    // after the first error the rest may be missing.
    let mut out = Vec::with_capacity(n);
    for slot in answers {
        match slot.into_inner().unwrap_or_else(|e| e.into_inner()) {
            Some(Ok(r)) => out.push(r),
            Some(Err(e)) => return Err(e),
            None => break,
        }
    }
    debug_assert_eq!(out.len(), n, "a job without an answer before any error");
    Ok(out)
}

/// Instance threads for one request when the server runs `max_estimates` requests at once:
/// the cores shared among them, at least two (an estimate waits on renders and on the
/// backbone's queue now and then; on 2 cores two threads measured within the run-to-run
/// spread of one, docs/benchmarks.md "per image", so the floor costs nothing there).
pub fn instance_threads(max_estimates: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (cores / max_estimates.max(1)).max(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_keep_the_items_order_whatever_the_threads() {
        for threads in [0, 1, 2, 3, 8, 50] {
            // Later items finish first: the order must not come from finishing times.
            let out: Result<Vec<u64>, ()> = ordered_map((0..20u64).collect(), threads, |i| {
                std::thread::sleep(std::time::Duration::from_millis(20 - i));
                Ok(i * i)
            });
            assert_eq!(out.unwrap(), (0..20u64).map(|i| i * i).collect::<Vec<_>>(), "{threads} threads");
        }
    }

    #[test]
    fn jobs_run_side_by_side() {
        let running = AtomicUsize::new(0);
        let most = AtomicUsize::new(0);
        let _: Vec<()> = ordered_map::<_, _, ()>((0..8).collect::<Vec<u32>>(), 4, |_| {
            let now = running.fetch_add(1, Ordering::SeqCst) + 1;
            most.fetch_max(now, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(30));
            running.fetch_sub(1, Ordering::SeqCst);
            Ok(())
        })
        .unwrap();
        let most = most.load(Ordering::SeqCst);
        assert!((2..=4).contains(&most), "at most 4 at once and more than one: {most}");
    }

    #[test]
    fn the_first_error_stops_jobs_not_started() {
        let started = AtomicUsize::new(0);
        let out: Result<Vec<u32>, String> = ordered_map((0..100u32).collect(), 2, |i| {
            started.fetch_add(1, Ordering::SeqCst);
            if i == 3 {
                return Err(format!("job {i} failed"));
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
            Ok(i)
        });
        assert_eq!(out.unwrap_err(), "job 3 failed");
        assert!(started.load(Ordering::SeqCst) < 100, "jobs after the error were not started");
    }

    #[test]
    fn of_several_errors_the_earliest_item_is_told() {
        let out: Result<Vec<u32>, u32> = ordered_map((0..4u32).collect(), 4, |i| {
            // Item 0 fails last.
            std::thread::sleep(std::time::Duration::from_millis(if i == 0 { 40 } else { 1 }));
            Err(i)
        });
        assert_eq!(out.unwrap_err(), 0);
    }

    #[test]
    fn at_least_two_instance_threads() {
        assert!(instance_threads(1) >= 2);
        assert!(instance_threads(1000) == 2);
    }
}
