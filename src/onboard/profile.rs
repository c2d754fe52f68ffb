//! Where an onboarding's time goes, for `b2tf bench onboard` to print and the next speed
//! step to be chosen from. The templates are made view by view on all cores, so their
//! crops, descriptors and 3D points are told as shares of the threads' time there; every
//! other stage runs alone and is told in wall-clock time.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Wall-clock seconds of each onboarding stage, and the split of the views' parallel work.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OnboardProfile {
    /// The base views rendered and read back (one batch of views at a time).
    pub renders_s: f64,
    /// The views' templates made from their renders, on all cores.
    pub views_s: f64,
    /// Of the threads' time in `views_s`: turned crops sampled, the backbone's
    /// descriptors, the patches' 3D points and silhouettes (shares adding up to 1).
    pub view_shares: ViewShares,
    /// The contour model (tracking and the contour refiner).
    pub contours_s: f64,
    /// The shape model of the colour detector.
    pub detector_s: f64,
    /// The mesh's symmetries.
    pub symmetries_s: f64,
    /// Rows shared per view, PCA and descriptor coding (whichever the settings ask for).
    pub compress_s: f64,
}

/// Each view step's share of the threads' time spent making templates (0–1, adding up to 1).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewShares {
    pub crops: f64,
    pub features: f64,
    pub points: f64,
}

/// Thread time of the views' three steps, summed over the threads that make them.
#[derive(Default)]
pub(super) struct ViewClock {
    crops_ns: AtomicU64,
    features_ns: AtomicU64,
    points_ns: AtomicU64,
}

/// One of the views' steps.
#[derive(Clone, Copy)]
pub(super) enum ViewStep {
    Crops,
    Features,
    Points,
}

impl ViewClock {
    /// Runs `f`, adding its time to `step`'s.
    pub(super) fn time<T>(&self, step: ViewStep, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let out = f();
        let counter = match step {
            ViewStep::Crops => &self.crops_ns,
            ViewStep::Features => &self.features_ns,
            ViewStep::Points => &self.points_ns,
        };
        counter.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        out
    }

    /// Each step's share of the three's time; all zero where nothing was timed.
    pub(super) fn shares(&self) -> ViewShares {
        let [c, f, p] = [&self.crops_ns, &self.features_ns, &self.points_ns].map(|n| n.load(Ordering::Relaxed) as f64);
        let sum = c + f + p;
        if sum <= 0.0 {
            return ViewShares::default();
        }
        ViewShares { crops: c / sum, features: f / sum, points: p / sum }
    }
}

/// Runs `f` and adds its wall-clock seconds to `slot`.
pub(super) fn timed<T>(slot: &mut f64, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let out = f();
    *slot += t.elapsed().as_secs_f64();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shares follow the time each step took and add up to one; no time, no shares.
    #[test]
    fn view_shares_follow_the_time_taken() {
        let clock = ViewClock::default();
        assert_eq!(clock.shares(), ViewShares::default());
        clock.time(ViewStep::Crops, || std::thread::sleep(std::time::Duration::from_millis(30)));
        clock.time(ViewStep::Features, || std::thread::sleep(std::time::Duration::from_millis(10)));
        let s = clock.shares();
        assert!(s.crops > s.features && s.features > 0.0 && s.points == 0.0, "{s:?}");
        assert!((s.crops + s.features + s.points - 1.0).abs() < 1e-12);
        let mut slot = 1.0;
        assert_eq!(timed(&mut slot, || 7), 7);
        assert!(slot >= 1.0);
    }
}
