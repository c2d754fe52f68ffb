//! Rotation matrices as BOP files hold them, judged the way the BOP toolkit uses them.
//!
//! The toolkit (`inout.load_scene_gt`, `load_bop_results`) reshapes the nine numbers into a
//! matrix and computes every error with that matrix as it is: no check, no
//! re-orthonormalisation. Real ground truth is far from exact: the LM-O poses shipped in the
//! toolkit's own tests (`gt-pbrreal-rgb-mmodel_lmo-test_lmo.csv`, 1445 poses) have R·Rᵀ off
//! the identity by up to 9.6·10⁻³ (median 2.3·10⁻⁴) and determinants off 1 by up to
//! 1.4·10⁻²; T-LESS's, written with 8 decimals, stay below 2·10⁻⁶. So a matrix is kept as
//! given, a warning says when it is visibly not a rotation, and only what no rounding or
//! annotation noise explains (a scaled, mirrored, degenerate matrix) is refused.

use crate::geometry::Pose;
use nalgebra::{Matrix3, Rotation3, Vector3};
use std::path::Path;

/// Deviations above this are reported (one warning per file): well above the rounding of
/// 8 written decimals (T-LESS: 2·10⁻⁶), below what LM-O's annotations show.
pub const WARN_ABOVE: f64 = 1e-4;
/// Deviations above this are refused: seven times LM-O's worst (1.4·10⁻²), and far below
/// what real mistakes give (a mirror: 2; mm for m: 10⁹; a zeroed row: 1).
pub const REFUSE_ABOVE: f64 = 0.1;

/// How far `r` (row-major) is from a rotation: the larger of |det R − 1| and the largest
/// entry of |R·Rᵀ − I|. `Err` names `field` and says what is wrong when it is too far
/// (above [`REFUSE_ABOVE`]) or not finite.
pub fn check_rotation(field: &str, r: &[f64; 9]) -> Result<f64, String> {
    if let Some(i) = r.iter().position(|v| !v.is_finite()) {
        return Err(format!("{field}: value {} is {}, not a finite number", i + 1, r[i]));
    }
    let m = Matrix3::from_row_slice(r);
    let det = m.determinant();
    if (det - 1.0).abs() > REFUSE_ABOVE {
        return Err(format!("{field}: not a rotation: determinant is {det} (a rotation's is 1)"));
    }
    let off = (m * m.transpose() - Matrix3::identity()).abs().max();
    if off > REFUSE_ABOVE {
        return Err(format!("{field}: not a rotation: R·Rᵀ differs from the identity by up to {off}"));
    }
    Ok(off.max((det - 1.0).abs()))
}

/// A pose whose rotation is the file's matrix unchanged (`r` row-major), as the toolkit
/// scores it; `translation` in the library's metres. Only for matrices that passed
/// [`check_rotation`]: the `Rotation3` is then a rotation up to [`REFUSE_ABOVE`].
pub fn pose_as_given(r: &[f64; 9], translation: [f64; 3]) -> Pose {
    Pose::new(Rotation3::from_matrix_unchecked(Matrix3::from_row_slice(r)), Vector3::from(translation))
}

/// The matrices of one file that are visibly not rotations, summed up into one warning.
#[derive(Debug, Default)]
pub struct LooseRotations {
    checked: usize,
    loose: usize,
    /// The largest deviation and where it is (e.g. "image 3, instance 1").
    worst: Option<(f64, String)>,
}

impl LooseRotations {
    /// Records one checked matrix's deviation; `at` is called only when it is worth a note.
    pub fn note(&mut self, deviation: f64, at: impl FnOnce() -> String) {
        self.checked += 1;
        if deviation <= WARN_ABOVE {
            return;
        }
        self.loose += 1;
        if self.worst.as_ref().is_none_or(|(w, _)| deviation > *w) {
            self.worst = Some((deviation, at()));
        }
    }

    /// One line for `path` when some matrices deviated more than [`WARN_ABOVE`].
    pub fn warning(&self, path: &Path, field: &str) -> Option<String> {
        let (worst, at) = self.worst.as_ref()?;
        Some(format!(
            "{}: {} of {} {field} matrices are rotations only to within {worst:.1e} ({at}); \
             scored as given, as the BOP toolkit does",
            path.display(),
            self.loose,
            self.checked
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rotation about z by 0.3 rad whose first entry is off by `nudge`, as annotation
    /// noise leaves it.
    fn noisy(nudge: f64) -> [f64; 9] {
        let (s, c) = 0.3f64.sin_cos();
        [c + nudge, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]
    }

    #[test]
    fn annotation_noise_is_accepted_with_its_size() {
        assert!(check_rotation("R", &noisy(0.0)).unwrap() < 1e-15);
        // LM-O-like: 3·10⁻³ off. R·Rᵀ's (0,0) entry is (c + 3e-3)² + s² − 1 ≈ 6e-3·c.
        let d = check_rotation("R", &noisy(3e-3)).unwrap();
        assert!((d - (2.0 * 3e-3 * 0.3f64.cos() + 9e-6)).abs() < 1e-12, "{d}");
    }

    #[test]
    fn broken_matrices_are_refused_naming_the_field() {
        let cases: [([f64; 9], &str); 5] = [
            ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0], "cam_R_m2c: not a rotation: determinant is -1"),
            ([1000.0, 0.0, 0.0, 0.0, 1000.0, 0.0, 0.0, 0.0, 1000.0], "determinant is 1000000000"),
            ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], "determinant is 0"),
            ([1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "cam_R_m2c: not a rotation: R·Rᵀ differs from the identity by up to 0.5"),
            ([1.0, 0.0, f64::NAN, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "cam_R_m2c: value 3 is NaN"),
        ];
        for (r, needle) in cases {
            let err = check_rotation("cam_R_m2c", &r).unwrap_err();
            assert!(err.contains(needle), "{err:?} lacks {needle:?}");
        }
    }

    #[test]
    fn the_pose_keeps_the_matrix_unchanged() {
        let r = noisy(3e-3);
        let p = pose_as_given(&r, [0.1, 0.2, 0.3]);
        assert_eq!(p.rotation_row_major(), r);
        assert_eq!(p.translation, Vector3::new(0.1, 0.2, 0.3));
    }

    #[test]
    fn one_warning_names_the_count_and_the_worst() {
        let mut l = LooseRotations::default();
        let path = Path::new("scene_gt.json");
        l.note(1e-6, || unreachable!("below the warning level"));
        assert_eq!(l.warning(path, "cam_R_m2c"), None);
        l.note(3e-3, || "image 1, instance 0".into());
        l.note(9e-3, || "image 2, instance 1".into());
        l.note(5e-3, || "image 3, instance 0".into());
        let w = l.warning(path, "cam_R_m2c").unwrap();
        assert_eq!(w, "scene_gt.json: 3 of 4 cam_R_m2c matrices are rotations only to within 9.0e-3 (image 2, instance 1); scored as given, as the BOP toolkit does");
    }
}
