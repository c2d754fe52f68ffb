//! Object symmetries from a BOP `models_info.json` and their expansion into the
//! set of symmetry transformations used by MSSD/MSPD.
//!
//! Mirrors `bop_toolkit_lib/misc.py::get_symmetry_transformations`:
//! * the identity comes first, followed by the discrete symmetries in file order;
//! * every continuous symmetry is discretised into `ceil(π / max_sym_disc_step)`
//!   rotations (note: π, not 1 — the toolkit reasons that the vertex furthest from
//!   the axis travels at most `π·diam / n` per step), angle `i · 2π / n`,
//!   `i = 0..n`, about the normalised axis through `offset`
//!   (`t = −R·offset + offset`);
//! * if there are continuous symmetries, every discrete transformation (identity
//!   included) is combined with every continuous one as `R = R_c·R_d`,
//!   `t = R_c·t_d + t_c` (discrete outer loop, continuous inner loop); otherwise
//!   the discrete list is returned as is.
//!
//! Units: translations keep the unit of the file (millimetres for BOP data). Use
//! [`scale_translations`] with [`MM_TO_M`] to express them in metres.
//!
//! Rotations are kept *as given* (no re-orthonormalisation), because the toolkit
//! uses the raw 3×3 blocks of the (rounded) file values.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::Pose;

/// Millimetres → metres, for [`scale_translations`].
pub const MM_TO_M: f64 = 1e-3;

/// Upper bound on the discretisation of one continuous symmetry, so that a
/// nonsensical `max_sym_disc_step` cannot exhaust memory.
pub const MAX_CONTINUOUS_STEPS: usize = 1_000_000;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SymmetryError {
    #[error("models_info: object {obj_id}: {message}")]
    Parse { obj_id: String, message: String },
    #[error("models_info: object {obj_id}: symmetries_discrete[{index}] has {len} values, expected 16 (row-major 4x4)")]
    DiscreteLen { obj_id: String, index: usize, len: usize },
    #[error("models_info: object {obj_id}: symmetries_continuous[{index}] has a zero-length axis")]
    ZeroAxisInFile { obj_id: String, index: usize },
    #[error("continuous symmetry {index} has a zero-length or non-finite axis")]
    ZeroAxis { index: usize },
    #[error("max_sym_disc_step must be finite and > 0 and give at most {MAX_CONTINUOUS_STEPS} steps, got {0}")]
    BadStep(f64),
    #[error("models_info is not a JSON object keyed by object id: {0}")]
    NotAnObject(String),
}

/// One discrete symmetry: `x ↦ rotation·x + translation` in model coordinates. Stored and
/// sent as the flattened row-major 4×4 matrix, as BOP's `models_info.json` writes it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(into = "Vec<f64>", try_from = "Vec<f64>")]
pub struct DiscreteSymmetry {
    /// Upper-left 3×3 block of the 4×4 matrix, exactly as in the file.
    pub rotation: Matrix3<f64>,
    /// Last column of the 4×4 matrix (file unit, mm for BOP).
    pub translation: Vector3<f64>,
}

impl DiscreteSymmetry {
    /// From a flattened row-major 4×4 matrix (the bottom row is ignored, as in the toolkit).
    pub fn from_row_major_4x4(m: &[f64; 16]) -> Self {
        let rotation = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        Self { rotation, translation: Vector3::new(m[3], m[7], m[11]) }
    }

    /// The flattened row-major 4×4 matrix (bottom row 0, 0, 0, 1).
    pub fn to_row_major_4x4(&self) -> [f64; 16] {
        let (r, t) = (&self.rotation, &self.translation);
        [r[(0, 0)], r[(0, 1)], r[(0, 2)], t.x, r[(1, 0)], r[(1, 1)], r[(1, 2)], t.y, r[(2, 0)], r[(2, 1)], r[(2, 2)], t.z, 0.0, 0.0, 0.0, 1.0]
    }

    pub fn from_pose(pose: &Pose) -> Self {
        Self { rotation: *pose.rotation.matrix(), translation: pose.translation }
    }
}

impl From<DiscreteSymmetry> for Vec<f64> {
    fn from(d: DiscreteSymmetry) -> Self {
        d.to_row_major_4x4().to_vec()
    }
}

impl TryFrom<Vec<f64>> for DiscreteSymmetry {
    type Error = String;
    fn try_from(v: Vec<f64>) -> Result<Self, String> {
        let m: [f64; 16] = v.as_slice().try_into().map_err(|_| format!("a discrete symmetry has 16 values (row-major 4×4), not {}", v.len()))?;
        if m.iter().any(|x| !x.is_finite()) {
            return Err("a discrete symmetry has a value that is not a finite number".into());
        }
        Ok(Self::from_row_major_4x4(&m))
    }
}

/// One continuous rotational symmetry (`models_info.json` format).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContinuousSymmetry {
    /// Direction of the axis (need not be unit length; it is normalised).
    pub axis: [f64; 3],
    /// A point on the axis (file unit, mm for BOP).
    pub offset: [f64; 3],
}

/// The symmetries of one object, as BOP writes them: each continuous symmetry is an axis
/// the object may turn about freely; the discrete ones are the other transformations (with
/// a continuous axis, only those not already a turn about it, e.g. a cylinder's flip).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ObjectSymmetries {
    pub discrete: Vec<DiscreteSymmetry>,
    pub continuous: Vec<ContinuousSymmetry>,
}

/// Where an object's symmetries came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SymmetrySource {
    /// Found by onboarding from the mesh's geometry and appearance.
    Mesh,
    /// Given by the user (BOP `models_info.json`).
    ModelsInfo,
}

/// An onboarded object's symmetries (translations and offsets in metres) and their source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KnownSymmetries {
    pub source: SymmetrySource,
    #[serde(flatten)]
    pub symmetries: ObjectSymmetries,
}

impl KnownSymmetries {
    /// A continuous symmetry: a pose's rotation about its axis is arbitrary.
    pub fn arbitrary_rotation_about_axis(&self) -> bool {
        !self.symmetries.continuous.is_empty()
    }

    /// One line for people: "none (found from the mesh)", "3 discrete (…)", "continuous
    /// about (0.00, 0.00, 1.00) and 1 discrete (given in models_info)".
    pub fn describe(&self) -> String {
        let what = self.symmetries.describe();
        let source = match self.source {
            SymmetrySource::Mesh => "found from the mesh",
            SymmetrySource::ModelsInfo => "given in models_info",
        };
        format!("{what} ({source})")
    }
}

impl ObjectSymmetries {
    /// "none", "3 discrete", "continuous about (0.00, 0.00, 1.00) and 1 discrete".
    pub fn describe(&self) -> String {
        let mut parts: Vec<String> = self.continuous.iter().map(|c| format!("continuous about ({:.2}, {:.2}, {:.2})", c.axis[0], c.axis[1], c.axis[2])).collect();
        if !self.discrete.is_empty() {
            parts.push(format!("{} discrete", self.discrete.len()));
        }
        if parts.is_empty() {
            "none".to_string()
        } else {
            parts.join(" and ")
        }
    }

    /// Every discrete symmetry a finite rotation (RᵀR = I within 1e-3, det +1) and
    /// translation; every continuous axis finite and not zero, its offset finite.
    pub fn validate(&self) -> Result<(), String> {
        for (i, d) in self.discrete.iter().enumerate() {
            let r = &d.rotation;
            let finite = r.iter().chain(d.translation.iter()).all(|x| x.is_finite());
            if !finite || (r.transpose() * r - Matrix3::identity()).norm() > 1e-3 || r.determinant() < 0.0 {
                return Err(format!("discrete symmetry {i} is not a rotation and a translation"));
            }
        }
        for (i, c) in self.continuous.iter().enumerate() {
            if axis_norm(&c.axis).is_none() || c.offset.iter().any(|x| !x.is_finite()) {
                return Err(format!("continuous symmetry {i} has a zero or non-finite axis or offset"));
            }
        }
        Ok(())
    }

    pub fn is_empty(&self) -> bool {
        self.discrete.is_empty() && self.continuous.is_empty()
    }

    /// The same symmetries with translations and offsets multiplied by `factor`
    /// (e.g. [`MM_TO_M`] for a BOP file's millimetres).
    pub fn scaled(&self, factor: f64) -> Self {
        Self {
            discrete: self.discrete.iter().map(|d| DiscreteSymmetry { rotation: d.rotation, translation: d.translation * factor }).collect(),
            continuous: self.continuous.iter().map(|c| ContinuousSymmetry { axis: c.axis, offset: c.offset.map(|o| o * factor) }).collect(),
        }
    }

    /// See [`symmetry_transformations`].
    pub fn transformations(&self, max_sym_disc_step: f64) -> Result<Vec<Pose>, SymmetryError> {
        symmetry_transformations(&self.discrete, &self.continuous, max_sym_disc_step)
    }
}

/// The subset of a `models_info.json` entry we read; other keys are ignored.
#[derive(Debug, Deserialize)]
struct RawEntry {
    #[serde(default)]
    symmetries_discrete: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    symmetries_continuous: Option<Vec<ContinuousSymmetry>>,
}

/// Parses the symmetries of one `models_info.json` entry (`obj_id` is only used in errors).
pub fn parse_model_info(obj_id: impl std::fmt::Display, entry: &serde_json::Value) -> Result<ObjectSymmetries, SymmetryError> {
    let obj = obj_id.to_string();
    let raw: RawEntry = serde_json::from_value(entry.clone()).map_err(|e| SymmetryError::Parse { obj_id: obj.clone(), message: e.to_string() })?;
    let mut out = ObjectSymmetries::default();
    for (index, flat) in raw.symmetries_discrete.unwrap_or_default().iter().enumerate() {
        let m: &[f64; 16] = flat.as_slice().try_into().map_err(|_| SymmetryError::DiscreteLen { obj_id: obj.clone(), index, len: flat.len() })?;
        out.discrete.push(DiscreteSymmetry::from_row_major_4x4(m));
    }
    for (index, sym) in raw.symmetries_continuous.unwrap_or_default().into_iter().enumerate() {
        if axis_norm(&sym.axis).is_none() {
            return Err(SymmetryError::ZeroAxisInFile { obj_id: obj.clone(), index });
        }
        out.continuous.push(sym);
    }
    Ok(out)
}

/// Parses a whole `models_info.json` (`{"1": {...}, "2": {...}}`) into symmetries per object id.
pub fn parse_models_info(json: &str) -> Result<BTreeMap<u32, ObjectSymmetries>, SymmetryError> {
    let map: BTreeMap<String, serde_json::Value> = serde_json::from_str(json).map_err(|e| SymmetryError::NotAnObject(e.to_string()))?;
    let mut out = BTreeMap::new();
    for (key, entry) in &map {
        let id: u32 = key.trim().parse().map_err(|_| SymmetryError::Parse { obj_id: key.clone(), message: "key is not an unsigned integer object id".into() })?;
        out.insert(id, parse_model_info(id, entry)?);
    }
    Ok(out)
}

/// Number of rotations a continuous symmetry is discretised into:
/// `ceil(π / max_sym_disc_step)` (315 for the BOP19 value 0.01).
pub fn continuous_steps_count(max_sym_disc_step: f64) -> Result<usize, SymmetryError> {
    let n = (std::f64::consts::PI / max_sym_disc_step).ceil();
    if max_sym_disc_step.is_nan() || max_sym_disc_step <= 0.0 || !n.is_finite() || n > MAX_CONTINUOUS_STEPS as f64 {
        return Err(SymmetryError::BadStep(max_sym_disc_step));
    }
    Ok(n as usize)
}

/// The full set of symmetry transformations (identity first), as
/// `misc.get_symmetry_transformations(model_info, max_sym_disc_step)`.
///
/// BOP19 uses `max_sym_disc_step = 0.01`. Translations are in the unit of the
/// inputs (mm for BOP files). Each returned `Pose` maps model coordinates to
/// model coordinates and is applied as `gt ∘ sym` by MSSD/MSPD.
pub fn symmetry_transformations(discrete: &[DiscreteSymmetry], continuous: &[ContinuousSymmetry], max_sym_disc_step: f64) -> Result<Vec<Pose>, SymmetryError> {
    let mut trans_disc = Vec::with_capacity(discrete.len() + 1);
    trans_disc.push(Pose::identity());
    trans_disc.extend(discrete.iter().map(|d| Pose::new(Rotation3::from_matrix_unchecked(d.rotation), d.translation)));

    let mut trans_cont = Vec::new();
    if !continuous.is_empty() {
        let count = continuous_steps_count(max_sym_disc_step)?;
        let step = 2.0 * std::f64::consts::PI / count as f64;
        trans_cont.reserve(count * continuous.len());
        for (index, sym) in continuous.iter().enumerate() {
            let norm = axis_norm(&sym.axis).ok_or(SymmetryError::ZeroAxis { index })?;
            let unit = [sym.axis[0] / norm, sym.axis[1] / norm, sym.axis[2] / norm];
            let offset = Vector3::from(sym.offset);
            for i in 0..count {
                let r = axis_angle_matrix(i as f64 * step, &unit);
                // t = -R·offset + offset
                let t = -(r * offset) + offset;
                trans_cont.push(Pose::new(Rotation3::from_matrix_unchecked(r), t));
            }
        }
    }

    if trans_cont.is_empty() {
        return Ok(trans_disc);
    }
    let mut out = Vec::with_capacity(trans_disc.len() * trans_cont.len());
    for d in &trans_disc {
        for c in &trans_cont {
            // R = R_c·R_d, t = R_c·t_d + t_c
            out.push(c.compose(d));
        }
    }
    Ok(out)
}

/// Returns copies of `poses` with translations multiplied by `factor`
/// (e.g. [`MM_TO_M`] to turn BOP millimetres into metres).
pub fn scale_translations(poses: &[Pose], factor: f64) -> Vec<Pose> {
    poses.iter().map(|p| Pose::new(p.rotation, p.translation * factor)).collect()
}

/// `sqrt(a·a)` when it is finite and non-zero (the toolkit divides by it).
fn axis_norm(a: &[f64; 3]) -> Option<f64> {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    (n.is_finite() && n > 0.0).then_some(n)
}

/// Rotation about a unit axis, built term by term like `transform.rotation_matrix`:
/// `diag(cos) + (u·uᵀ)(1 − cos) + [u·sin]×`.
fn axis_angle_matrix(angle: f64, u: &[f64; 3]) -> Matrix3<f64> {
    let (s, c) = (angle.sin(), angle.cos());
    let d = [u[0] * s, u[1] * s, u[2] * s];
    let skew = [[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]];
    let mut m = Matrix3::zeros();
    for i in 0..3 {
        for j in 0..3 {
            let diag = if i == j { c } else { 0.0 };
            m[(i, j)] = (diag + u[i] * u[j] * (1.0 - c)) + skew[i][j];
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn no_symmetry_gives_identity_only() {
        let t = symmetry_transformations(&[], &[], 0.01).unwrap();
        assert_eq!(t, vec![Pose::identity()]);
    }

    #[test]
    fn discrete_only_keeps_file_order_after_identity() {
        let flip = DiscreteSymmetry::from_row_major_4x4(&[-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let t = symmetry_transformations(&[flip], &[], 0.01).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0], Pose::identity());
        assert_eq!(*t[1].rotation.matrix(), flip.rotation);
    }

    #[test]
    fn continuous_step_count_uses_pi() {
        // ceil(pi / 0.01) = ceil(314.159...) = 315
        assert_eq!(continuous_steps_count(0.01).unwrap(), 315);
        assert_eq!(continuous_steps_count(1.0).unwrap(), 4);
        assert!(continuous_steps_count(0.0).is_err());
        assert!(continuous_steps_count(f64::NAN).is_err());
        assert!(continuous_steps_count(-1.0).is_err());
    }

    #[test]
    fn continuous_rotates_about_offset_axis() {
        // Axis z through (10, 0, 0), given unnormalised.
        let c = ContinuousSymmetry { axis: [0.0, 0.0, 2.0], offset: [10.0, 0.0, 0.0] };
        let t = symmetry_transformations(&[], &[c], 1.0).unwrap(); // 4 steps: 0, 90, 180, 270 deg
        assert_eq!(t.len(), 4);
        assert!((t[0].to_homogeneous() - Pose::identity().to_homogeneous()).norm() < 1e-15);
        // Points on the axis are fixed.
        for s in &t {
            let p = s.transform_point(&Point3::new(10.0, 0.0, 7.0));
            assert!((p - Point3::new(10.0, 0.0, 7.0)).norm() < 1e-12);
        }
        // 180 deg: (11, 0, 0) -> (9, 0, 0).
        let p = t[2].transform_point(&Point3::new(11.0, 0.0, 0.0));
        assert!((p - Point3::new(9.0, 0.0, 0.0)).norm() < 1e-12);
    }

    #[test]
    fn combination_is_discrete_outer_continuous_inner() {
        let flip_x = DiscreteSymmetry::from_row_major_4x4(&[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 5.0, 0.0, 0.0, 0.0, 1.0]);
        let c = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.0, 0.0] };
        let t = symmetry_transformations(&[flip_x], &[c], 0.01).unwrap();
        assert_eq!(t.len(), 2 * 315);
        // First block: identity discrete × continuous; entry 315 is R_c(0)·flip = flip.
        assert!((t[315].rotation.matrix() - flip_x.rotation).norm() < 1e-15);
        assert!((t[315].translation - flip_x.translation).norm() < 1e-15);
        // t = R_c·t_d + t_c with t_c = 0 (axis through the origin).
        let rc = t[1].rotation;
        let expect = rc * flip_x.translation;
        assert!((t[316].translation - expect).norm() < 1e-12);
    }

    #[test]
    fn parses_models_info_and_names_object_on_error() {
        let json = r#"{
            "1": {"diameter": 100.0, "min_x": -1},
            "2": {"diameter": 50.0,
                  "symmetries_discrete": [[-1,0,0,0, 0,-1,0,0, 0,0,1,0, 0,0,0,1]],
                  "symmetries_continuous": [{"axis": [0,0,1], "offset": [0,0,0]}]}
        }"#;
        let m = parse_models_info(json).unwrap();
        assert!(m[&1].discrete.is_empty() && m[&1].continuous.is_empty());
        assert_eq!(m[&2].discrete.len(), 1);
        assert_eq!(m[&2].continuous.len(), 1);
        assert_eq!(m[&2].transformations(0.01).unwrap().len(), 630);

        let bad = r#"{"7": {"symmetries_discrete": [[1,0,0]]}}"#;
        let err = parse_models_info(bad).unwrap_err();
        assert!(err.to_string().contains("object 7"), "{err}");
        let bad_axis = r#"{"9": {"symmetries_continuous": [{"axis": [0,0,0], "offset": [0,0,0]}]}}"#;
        assert!(parse_models_info(bad_axis).unwrap_err().to_string().contains("object 9"));
        let bad_type = r#"{"3": {"symmetries_continuous": [{"axis": [0,0], "offset": [0,0,0]}]}}"#;
        assert!(parse_models_info(bad_type).unwrap_err().to_string().contains("object 3"));
    }

    #[test]
    fn mm_to_m_helper() {
        let p = Pose::new(Rotation3::identity(), Vector3::new(10.0, -20.0, 1000.0));
        let s = scale_translations(&[p], MM_TO_M);
        assert!(close(s[0].translation.z, 1.0, 1e-15));
        assert!(close(s[0].translation.x, 0.01, 1e-15));
    }
}
