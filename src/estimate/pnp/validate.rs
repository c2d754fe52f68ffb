//! Input checks, so that everything downstream may assume finite numbers, enough matches and
//! a point spread that can pin a pose down.

use nalgebra::Vector3;

use super::spread::{spread, Spread};
use super::{PnpConfig, PnpError, MIN_POINTS};
use crate::geometry::Intrinsics;

/// Variance below which a point set counts as one point: 1 µm² in 3D (metres), 10⁻⁶ px² in
/// the image. Far below anything real, far above rounding.
const COINCIDENT_VAR_M2: f64 = 1e-12;
const COINCIDENT_VAR_PX2: f64 = 1e-6;
/// Second-largest over largest principal variance below which the set counts as a line.
const COLLINEAR_RATIO: f64 = 1e-12;

/// Fewest matches a result may rest on: the config's floor, never below `MIN_POINTS`.
pub(crate) fn min_support(cfg: &PnpConfig) -> usize {
    cfg.min_inliers.max(MIN_POINTS)
}

pub(crate) fn check_inputs(image: &[[f64; 2]], object: &[[f64; 3]], k: &Intrinsics, cfg: &PnpConfig) -> Result<(), PnpError> {
    if image.len() != object.len() {
        return Err(PnpError::LengthMismatch { image: image.len(), object: object.len() });
    }
    check_config(cfg)?;
    if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) {
        return Err(PnpError::NonFinite);
    }
    if !(k.fx > 0.0 && k.fy > 0.0) {
        return Err(PnpError::BadIntrinsics);
    }
    let finite = image.iter().flatten().chain(object.iter().flatten()).all(|v| v.is_finite());
    if !finite {
        return Err(PnpError::NonFinite);
    }
    let need = min_support(cfg);
    if image.len() < need {
        return Err(PnpError::NotEnoughPoints { got: image.len(), need });
    }
    if degenerate_spread(image, object, 0..image.len()) {
        return Err(PnpError::Degenerate);
    }
    Ok(())
}

fn check_config(cfg: &PnpConfig) -> Result<(), PnpError> {
    if !(cfg.reprojection_threshold_px.is_finite() && cfg.reprojection_threshold_px > 0.0) {
        return Err(PnpError::BadConfig("reprojection_threshold_px must be finite and positive"));
    }
    if !(cfg.confidence > 0.0 && cfg.confidence < 1.0) {
        return Err(PnpError::BadConfig("confidence must lie in (0, 1)"));
    }
    if cfg.max_iterations == 0 {
        return Err(PnpError::BadConfig("max_iterations must be positive"));
    }
    Ok(())
}

/// Whether the matches `idx` have their object points, or their image points, all on one
/// line or at one place: then no pose (or a one-parameter family of them) explains them.
pub(crate) fn degenerate_spread(image: &[[f64; 2]], object: &[[f64; 3]], idx: impl Iterator<Item = usize> + Clone) -> bool {
    let lifted = |i: usize| Vector3::new(image[i][0], image[i][1], 0.0);
    collinear_or_coincident(idx.clone().map(|i| Vector3::from(object[i])), COINCIDENT_VAR_M2) || collinear_or_coincident(idx.map(lifted), COINCIDENT_VAR_PX2)
}

/// From the principal variances: the largest tells coincident, the middle one collinear
/// (a planar set, 3D or the image lifted to z = 0, only has a zero smallest one).
fn collinear_or_coincident(points: impl Iterator<Item = Vector3<f64>> + Clone, coincident_var: f64) -> bool {
    match spread(points) {
        Some(Spread { variances: [largest, middle, _], .. }) => largest <= coincident_var || middle <= COLLINEAR_RATIO * largest,
        None => true,
    }
}
