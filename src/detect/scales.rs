//! Which image scales to search. The templates show the object's bounding sphere
//! `canonical_px` across; an image resampled by ρ shows an object at distance z that size
//! when ρ = canonical / (2 f tan(asin(r / z))). So the object's radius, the focal length and
//! a distance range fix the scales worth searching. Scales come from one ladder shared by
//! all objects (quarter octaves), so one image's response maps serve every object.

/// Ladder rung `k` resamples the image by 2^(1 − k/4): from 2 (objects half the canonical
/// size) down.
pub const RUNGS: usize = 29;
const STEPS_PER_OCTAVE: f64 = 4.0;

pub fn rung_scale(k: usize) -> f64 {
    2f64.powf(1.0 - k as f64 / STEPS_PER_OCTAVE)
}

/// Resampling factor at which an object of bounding radius `radius_m` at `distance_m`
/// appears `canonical_px` across through focal length `f` (pixels).
pub fn scale_for_distance(canonical_px: f64, f: f64, radius_m: f64, distance_m: f64) -> f64 {
    let s = (radius_m / distance_m).min(1.0);
    canonical_px / (2.0 * f * s.asin().tan())
}

/// The inverse: distance of the sphere centre at which resampling by `rho` shows the
/// object `canonical_px` across.
pub fn distance_for_scale(canonical_px: f64, f: f64, radius_m: f64, rho: f64) -> f64 {
    radius_m / (canonical_px / (2.0 * f * rho)).atan().sin()
}

/// Ladder rungs within [rho_min, rho_max], widened by half a step so the ends are covered.
pub fn rungs_between(rho_min: f64, rho_max: f64) -> Vec<usize> {
    let half = 2f64.powf(0.5 / STEPS_PER_OCTAVE);
    (0..RUNGS).filter(|&k| (rho_min / half..=rho_max * half).contains(&rung_scale(k))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_and_scale_are_inverse() {
        for z in [0.3, 0.8, 2.5] {
            let rho = scale_for_distance(40.0, 600.0, 0.05, z);
            assert!((distance_for_scale(40.0, 600.0, 0.05, rho) - z).abs() < 1e-9);
        }
        // Farther objects need less downsampling to look canonical... i.e. a larger ρ.
        assert!(scale_for_distance(40.0, 600.0, 0.05, 2.0) > scale_for_distance(40.0, 600.0, 0.05, 0.5));
    }

    #[test]
    fn rungs_cover_the_range_and_nothing_far_outside() {
        let r = rungs_between(0.25, 1.0);
        assert_eq!(r, vec![4, 5, 6, 7, 8, 9, 10, 11, 12]);
        assert!(rungs_between(5.0, 9.0).is_empty());
    }
}
