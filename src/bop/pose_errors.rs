//! BOP'19 pose-error functions: MSSD, MSPD and VSD, following
//! `bop_toolkit_lib/pose_error.py` (and `misc.py`, `visibility.py`).
//!
//! Units: every function is unit-agnostic — model points, pose translations,
//! depth maps, `delta`, `diameter` and (unnormalised) VSD `taus` must all share
//! the caller's unit. BOP evaluates in **millimetres** (`delta = 15`, diameters
//! from `models_info.json`), so BOP-comparable callers pass millimetres.
//! MSPD is in pixels.
//!
//! Poses are `T_cam_obj` (`x_cam = R·x_obj + t`, BOP's `cam_R_m2c`/`cam_t_m2c`).
//! Intrinsics are `k = [fx, fy, cx, cy]` (zero skew).
//!
//! `eval_calc_errors.py` short-cuts two errors before calling these functions:
//! MSSD is set to `+∞` unless [`spheres_overlap`], and VSD to `1.0` for every tau
//! unless [`sphere_projections_overlap`] (radius = diameter / 2). Callers that
//! want identical numbers apply the same gates (it also saves rendering).

use nalgebra::{Point3, Vector3};

use crate::geometry::Pose;

/// `[fx, fy, cx, cy]`.
pub type Intrinsics = [f64; 4];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricError {
    #[error("no model points")]
    EmptyPoints,
    #[error("no symmetry transformations (the identity at least is required)")]
    EmptySymmetries,
    #[error("intrinsics must be finite with non-zero focal lengths, got {0:?}")]
    BadIntrinsics(Intrinsics),
    #[error("depth map `{name}` holds {len} values, expected {width}x{height}")]
    BadDepthLen { name: &'static str, len: usize, width: usize, height: usize },
    #[error("depth maps differ in size: test {test:?}, gt {gt:?}, est {est:?}")]
    SizeMismatch { test: (usize, usize), gt: (usize, usize), est: (usize, usize) },
    #[error("diameter must be finite and > 0 to normalise VSD distances, got {0}")]
    BadDiameter(f64),
}

/// Maximum Symmetry-Aware Surface Distance:
/// `min over syms S of max over points x of ‖T_est·x − (T_gt∘S)·x‖`.
///
/// `syms` comes from [`crate::geometry::symmetry::symmetry_transformations`] (it
/// includes the identity) with translations in the unit of `pts`.
pub fn mssd(est: &Pose, gt: &Pose, pts: &[[f64; 3]], syms: &[Pose]) -> Result<f64, MetricError> {
    check_pts_syms(pts, syms)?;
    let pts_est: Vec<Point3<f64>> = pts.iter().map(|p| est.transform_point(&Point3::from(*p))).collect();
    let per_sym = syms.iter().map(|sym| {
        let gt_sym = gt.compose(sym); // R_gt·R_s, R_gt·t_s + t_gt
        nan_max(pts.iter().zip(&pts_est).map(|(p, pe)| {
            let d = pe - gt_sym.transform_point(&Point3::from(*p));
            (d.x * d.x + d.y * d.y + d.z * d.z).sqrt()
        }))
    });
    Ok(python_min(per_sym))
}

/// Maximum Symmetry-Aware Projection Distance (pixels):
/// `min over syms S of max over points x of ‖π(T_est·x) − π((T_gt∘S)·x)‖`.
pub fn mspd(est: &Pose, gt: &Pose, pts: &[[f64; 3]], k: Intrinsics, syms: &[Pose]) -> Result<f64, MetricError> {
    check_pts_syms(pts, syms)?;
    check_intrinsics(k)?;
    let proj_est = project_points(pts, k, est);
    let per_sym = syms.iter().map(|sym| {
        let proj_gt = Projector::new(k, &gt.compose(sym));
        nan_max(pts.iter().zip(&proj_est).map(|(p, pe)| {
            let pg = proj_gt.project(p);
            let (du, dv) = (pe[0] - pg[0], pe[1] - pg[1]);
            (du * du + dv * dv).sqrt()
        }))
    });
    Ok(python_min(per_sym))
}

/// Projects model points with `P = K·[R|t]` (as `misc.project_pts`). Points with
/// zero camera depth give non-finite coordinates, as in numpy.
pub fn project_points(pts: &[[f64; 3]], k: Intrinsics, pose: &Pose) -> Vec<[f64; 2]> {
    let proj = Projector::new(k, pose);
    pts.iter().map(|p| proj.project(p)).collect()
}

/// `P = K·[R|t]` as a 3×4 matrix.
struct Projector {
    p: [[f64; 4]; 3],
}

impl Projector {
    fn new(k: Intrinsics, pose: &Pose) -> Self {
        let r = pose.rotation.matrix();
        let t = pose.translation;
        let kk = [[k[0], 0.0, k[2]], [0.0, k[1], k[3]], [0.0, 0.0, 1.0]];
        let rt = |i: usize, j: usize| if j < 3 { r[(i, j)] } else { t[i] };
        let mut p = [[0.0; 4]; 3];
        for (i, row) in p.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = kk[i][0] * rt(0, j) + kk[i][1] * rt(1, j) + kk[i][2] * rt(2, j);
            }
        }
        Self { p }
    }

    fn project(&self, x: &[f64; 3]) -> [f64; 2] {
        let h = |row: &[f64; 4]| row[0] * x[0] + row[1] * x[1] + row[2] * x[2] + row[3];
        let z = h(&self.p[2]);
        [h(&self.p[0]) / z, h(&self.p[1]) / z]
    }
}

/// `eval_calc_errors.py` gate for MSSD: the bounding spheres overlap when the
/// distance of the two translations is below the diameter. Otherwise the
/// toolkit records MSSD = `+∞`.
pub fn spheres_overlap(t_est: &Vector3<f64>, t_gt: &Vector3<f64>, diameter: f64) -> bool {
    (t_est - t_gt).norm() < diameter
}

/// `misc.overlapping_sphere_projections(radius, t_est, t_gt)`: whether the image
/// projections of two spheres of `radius` centred at the translations overlap
/// (approximately). `eval_calc_errors.py` uses `radius = diameter / 2` and
/// records VSD = 1.0 for every tau when this is false.
pub fn sphere_projections_overlap(radius: f64, t_est: &Vector3<f64>, t_gt: &Vector3<f64>) -> bool {
    if t_est.z == 0.0 || t_gt.z == 0.0 {
        return false;
    }
    let (p1, p2) = (t_est / t_est.z, t_gt / t_gt.z);
    let (dx, dy) = (p1.x - p2.x, p1.y - p2.y);
    let proj_dist = (dx * dx + dy * dy).sqrt();
    proj_dist < radius * (1.0 / t_est.z + 1.0 / t_gt.z)
}

/// A depth image (Z along the optical axis), row-major, `0` = no measurement.
/// The unit is the caller's (mm for BOP).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: usize,
    pub height: usize,
    /// `data[y * width + x]`.
    pub data: Vec<f32>,
}

impl DepthMap {
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, MetricError> {
        let map = Self { width, height, data };
        map.check("depth")?;
        Ok(map)
    }

    /// An all-zero (nothing measured / nothing rendered) map.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self { width, height, data: vec![0.0; width * height] }
    }

    fn check(&self, name: &'static str) -> Result<(), MetricError> {
        if Some(self.data.len()) != self.width.checked_mul(self.height) {
            return Err(MetricError::BadDepthLen { name, len: self.data.len(), width: self.width, height: self.height });
        }
        Ok(())
    }
}

/// Distance from the camera centre per pixel, as `misc.depth_im_to_dist_im_fast`:
/// `sqrt(((x−cx)/fx·d)² + ((y−cy)/fy·d)² + d²)`, computed in f64 from f32 depth.
pub fn depth_to_distance(depth: &DepthMap, k: Intrinsics) -> Result<Vec<f64>, MetricError> {
    check_intrinsics(k)?;
    depth.check("depth")?;
    let pre_x: Vec<f64> = (0..depth.width).map(|x| (x as f64 - k[2]) / k[0]).collect();
    let mut out = Vec::with_capacity(depth.data.len());
    for y in 0..depth.height {
        let pre_y = (y as f64 - k[3]) / k[1];
        let row = &depth.data[y * depth.width..(y + 1) * depth.width];
        for (px, &d) in pre_x.iter().zip(row) {
            let d = f64::from(d);
            let (xd, yd) = (px * d, pre_y * d);
            out.push((xd * xd + yd * yd + d * d).sqrt());
        }
    }
    Ok(out)
}

/// Pixel-wise matching cost of VSD.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VsdCost {
    /// `dist ≥ tau` costs 1 (SIXD 2017 onwards, BOP19).
    #[default]
    Step,
    /// `min(dist / tau, 1)` (Hodan et al., ECCVW'16).
    TLinear,
}

/// Visible Surface Discrepancy, one error per `tau`, as `pose_error.vsd` with
/// `visib_mode = "bop19"` (pixels with missing test depth count as visible).
///
/// * `depth_est`, `depth_gt`: depth images **rendered by the caller** of the
///   object model alone at the estimated / ground-truth pose with intrinsics `k`
///   and the test image size; `0` outside the object.
/// * `depth_test`: the measured test depth image (`0` = missing), scaled to the
///   same unit (BOP: `depth * depth_scale` → mm).
/// * `delta`: visibility tolerance (BOP19: 15 mm, ITODD 5 mm).
/// * `taus`: misalignment tolerances; with `normalized_by_diameter` (BOP19) the
///   pixel distances are divided by `diameter` and taus are fractions of it
///   (BOP19: 0.05..=0.5 step 0.05).
///
/// If the union of the two visibility masks is empty every error is 1.0.
#[allow(clippy::too_many_arguments)]
pub fn vsd(
    depth_est: &DepthMap,
    depth_gt: &DepthMap,
    depth_test: &DepthMap,
    k: Intrinsics,
    delta: f64,
    taus: &[f64],
    normalized_by_diameter: bool,
    diameter: f64,
    cost_type: VsdCost,
) -> Result<Vec<f64>, MetricError> {
    depth_est.check("depth_est")?;
    depth_gt.check("depth_gt")?;
    depth_test.check("depth_test")?;
    let dims = |d: &DepthMap| (d.width, d.height);
    if dims(depth_est) != dims(depth_test) || dims(depth_gt) != dims(depth_test) {
        return Err(MetricError::SizeMismatch { test: dims(depth_test), gt: dims(depth_gt), est: dims(depth_est) });
    }
    if normalized_by_diameter && !(diameter.is_finite() && diameter > 0.0) {
        return Err(MetricError::BadDiameter(diameter));
    }
    let dist_test = depth_to_distance(depth_test, k)?;
    let dist_gt = depth_to_distance(depth_gt, k)?;
    let dist_est = depth_to_distance(depth_est, k)?;

    // The toolkit compares float32 differences with delta (float32 too).
    let delta32 = delta as f32;
    let visible = |model: f64, test: f64| ((model as f32 - test as f32) <= delta32 || test == 0.0) && model > 0.0;

    let mut union = 0usize;
    let mut dists = Vec::new(); // over the intersection, row-major
    for ((&dt, &dg), &de) in dist_test.iter().zip(&dist_gt).zip(&dist_est) {
        let vis_gt = visible(dg, dt);
        let vis_est = visible(de, dt) || (vis_gt && de > 0.0);
        if vis_gt || vis_est {
            union += 1;
        }
        if vis_gt && vis_est {
            let d = (dg - de).abs();
            dists.push(if normalized_by_diameter { d / diameter } else { d });
        }
    }
    if union == 0 {
        return Ok(vec![1.0; taus.len()]);
    }
    let comp = union - dists.len();
    Ok(taus
        .iter()
        .map(|&tau| {
            let cost_sum = match cost_type {
                VsdCost::Step => dists.iter().filter(|&&d| d >= tau).count() as f64,
                VsdCost::TLinear => {
                    let costs: Vec<f64> = dists.iter().map(|&d| if d / tau > 1.0 { 1.0 } else { d / tau }).collect();
                    numpy_sum(&costs)
                }
            };
            (cost_sum + comp as f64) / union as f64
        })
        .collect())
}

fn check_pts_syms(pts: &[[f64; 3]], syms: &[Pose]) -> Result<(), MetricError> {
    if pts.is_empty() {
        return Err(MetricError::EmptyPoints);
    }
    if syms.is_empty() {
        return Err(MetricError::EmptySymmetries);
    }
    Ok(())
}

fn check_intrinsics(k: Intrinsics) -> Result<(), MetricError> {
    if k.iter().all(|v| v.is_finite()) && k[0] != 0.0 && k[1] != 0.0 {
        Ok(())
    } else {
        Err(MetricError::BadIntrinsics(k))
    }
}

/// numpy `max`: NaN propagates. `values` must be non-empty (checked by callers).
fn nan_max(values: impl Iterator<Item = f64>) -> f64 {
    let mut m = f64::NEG_INFINITY;
    for v in values {
        if v.is_nan() {
            return f64::NAN;
        }
        if v > m {
            m = v;
        }
    }
    m
}

/// Python's builtin `min`: keeps the first item unless a later one compares `<`.
fn python_min(mut values: impl Iterator<Item = f64>) -> f64 {
    let mut best = values.next().unwrap_or(f64::NAN);
    for v in values {
        if v < best {
            best = v;
        }
    }
    best
}

/// `np.sum` of a contiguous float64 vector: `0.0 + pairwise_sum(a)` (checked
/// bit-for-bit against numpy 2.4 for lengths up to 300 000).
pub(crate) fn numpy_sum(a: &[f64]) -> f64 {
    0.0 + pairwise_sum(a)
}

/// numpy's `pairwise_sum` (8-way unrolled below 128 elements, recursive above).
pub(crate) fn pairwise_sum(a: &[f64]) -> f64 {
    let n = a.len();
    if n < 8 {
        a.iter().fold(0.0, |res, &x| res + x)
    } else if n <= 128 {
        let mut r = [0.0; 8];
        r.copy_from_slice(&a[..8]);
        let mut i = 8;
        while i < n - n % 8 {
            for (j, rj) in r.iter_mut().enumerate() {
                *rj += a[i + j];
            }
            i += 8;
        }
        let mut res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for &x in &a[i..] {
            res += x;
        }
        res
    } else {
        let mut n2 = n / 2;
        n2 -= n2 % 8;
        pairwise_sum(&a[..n2]) + pairwise_sum(&a[n2..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::symmetry::{symmetry_transformations, ContinuousSymmetry, DiscreteSymmetry};
    use nalgebra::{Rotation3, Vector3};

    const K: Intrinsics = [500.0, 500.0, 320.0, 240.0];

    fn cube(h: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for x in [-h, h] {
            for y in [-h, h] {
                for z in [-h, h] {
                    v.push([x, y, z]);
                }
            }
        }
        v
    }

    fn gt_pose() -> Pose {
        Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 0.1), Vector3::new(10.0, -5.0, 1000.0))
    }

    #[test]
    fn true_pose_scores_zero() {
        let pts = cube(10.0);
        let syms = [Pose::identity()];
        let gt = gt_pose();
        assert_eq!(mssd(&gt, &gt, &pts, &syms).unwrap(), 0.0);
        assert_eq!(mspd(&gt, &gt, &pts, K, &syms).unwrap(), 0.0);
    }

    #[test]
    fn known_translation_gives_exact_mssd_and_mspd() {
        // Cube with half-size 10 mm, identity rotation, centred 1000 mm in front.
        // Estimate shifted by (3, 4, 0) mm: every point moves by exactly 5 mm, so
        // MSSD = 5. In the image the shift is fx·(3, 4)/Z = 500·5/Z px, largest for
        // the nearest points (Z = 1000 − 10 = 990): MSPD = 2500 / 990 = 2.5252... px.
        let pts = cube(10.0);
        let syms = [Pose::identity()];
        let gt = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 1000.0));
        let est = Pose::new(Rotation3::identity(), Vector3::new(3.0, 4.0, 1000.0));
        assert!((mssd(&est, &gt, &pts, &syms).unwrap() - 5.0).abs() < 1e-12);
        assert!((mspd(&est, &gt, &pts, K, &syms).unwrap() - 2500.0 / 990.0).abs() < 1e-9);
    }

    #[test]
    fn discrete_symmetry_flip_scores_zero() {
        // Box (±20, ±10, ±5) symmetric under a 180° turn about the z axis through
        // x = 10 mm: x ↦ 20 − x, y ↦ −y, i.e. R = diag(−1, −1, 1), t = (20, 0, 0).
        let mut pts = Vec::new();
        for x in [-10.0, 30.0] {
            for y in [-10.0, 10.0] {
                for z in [-5.0, 5.0] {
                    pts.push([x, y, z]);
                }
            }
        }
        let flip = DiscreteSymmetry::from_row_major_4x4(&[-1.0, 0.0, 0.0, 20.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        let syms = symmetry_transformations(&[flip], &[], 0.01).unwrap();
        let gt = gt_pose();
        let flip_pose = syms[1];
        let est = gt.compose(&flip_pose);
        assert!(mssd(&est, &gt, &pts, &syms).unwrap() < 1e-9);
        assert!(mspd(&est, &gt, &pts, K, &syms).unwrap() < 1e-9);
        // Without the symmetry the flipped pose is far off (the far corners swap: 40 mm apart
        // in x and 20 in y → sqrt(40² + 20²)).
        let e = mssd(&est, &gt, &pts, &[Pose::identity()]).unwrap();
        assert!((e - (40.0f64 * 40.0 + 20.0 * 20.0).sqrt()).abs() < 1e-9, "{e}");
    }

    #[test]
    fn continuous_symmetry_any_angle_is_within_discretisation() {
        // Ring of radius 50 mm at z = ±20 (diameter ≈ 107.7 mm), symmetric about z.
        let mut pts = Vec::new();
        for i in 0..360 {
            let a = (i as f64).to_radians();
            for z in [-20.0, 20.0] {
                pts.push([50.0 * a.cos(), 50.0 * a.sin(), z]);
            }
        }
        let c = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.0, 0.0] };
        let syms = symmetry_transformations(&[], &[c], 0.01).unwrap();
        let gt = gt_pose();
        // Nearest discretised angle is at most π/315 away, so every point is off by at
        // most the chord 2·50·sin(π/630) ≈ 0.499 mm (< 0.01·diameter as the toolkit intends).
        let bound = 2.0 * 50.0 * (std::f64::consts::PI / 630.0).sin() + 1e-9;
        for angle in [0.123, 1.0, 2.5, -3.0, 5.9] {
            let rz = Pose::new(Rotation3::from_axis_angle(&Vector3::z_axis(), angle), Vector3::zeros());
            let est = gt.compose(&rz);
            let e = mssd(&est, &gt, &pts, &syms).unwrap();
            assert!(e <= bound, "angle {angle}: mssd {e}");
            // Same bound in pixels at Z ≈ 1000 − 20 mm: 500·0.5/980 ≈ 0.26 px.
            let p = mspd(&est, &gt, &pts, K, &syms).unwrap();
            assert!(p < 0.3, "angle {angle}: mspd {p}");
            // Without symmetries the error is large.
            assert!(mssd(&est, &gt, &pts, &[Pose::identity()]).unwrap() > 5.0);
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let gt = gt_pose();
        assert_eq!(mssd(&gt, &gt, &[], &[Pose::identity()]), Err(MetricError::EmptyPoints));
        assert_eq!(mssd(&gt, &gt, &cube(1.0), &[]), Err(MetricError::EmptySymmetries));
        assert!(mspd(&gt, &gt, &cube(1.0), [0.0, 1.0, 0.0, 0.0], &[Pose::identity()]).is_err());
        let a = DepthMap::zeros(4, 4);
        let b = DepthMap::zeros(5, 4);
        assert!(vsd(&a, &a, &b, KS, 15.0, &[0.1], true, 100.0, VsdCost::Step).is_err());
        let short = DepthMap { width: 4, height: 4, data: vec![0.0; 3] };
        assert!(vsd(&a, &short, &a, KS, 15.0, &[0.1], true, 100.0, VsdCost::Step).is_err());
        assert!(vsd(&a, &a, &a, KS, 15.0, &[0.1], true, 0.0, VsdCost::Step).is_err());
        assert!(DepthMap::new(2, 2, vec![0.0; 5]).is_err());
    }

    #[test]
    fn gates_match_toolkit_definitions() {
        let a = Vector3::new(0.0, 0.0, 1000.0);
        assert!(spheres_overlap(&a, &Vector3::new(0.0, 0.0, 1099.0), 100.0));
        assert!(!spheres_overlap(&a, &Vector3::new(0.0, 0.0, 1100.0), 100.0));
        // Threshold on the normalised image plane: 50·(1/1000 + 1/1000) = 0.1.
        assert!(!sphere_projections_overlap(50.0, &a, &Vector3::new(101.0, 0.0, 1000.0)));
        assert!(sphere_projections_overlap(50.0, &a, &Vector3::new(99.0, 0.0, 1000.0)));
        assert!(!sphere_projections_overlap(50.0, &a, &Vector3::new(0.0, 0.0, 0.0)));
    }

    // ---- VSD on 4×4 hand-made images --------------------------------------------
    // K = [100, 100, 1.5, 1.5]: pixel offsets are at most 1.5/100, so distance =
    // depth·s with 1 ≤ s ≤ sqrt(1 + 2·0.015²) ≈ 1.000225. All depth differences
    // below are 0, 10, 30, 50 or ≥ 60 mm, far from delta = 15 and from the taus,
    // so s never changes a decision. Row-major layout, `o` = object pixel.
    const KS: Intrinsics = [100.0, 100.0, 1.5, 1.5];

    /// BOP19 VSD (δ 15, normalised by a 100 mm diameter, step cost) on the test camera.
    fn vsd_step(est: &DepthMap, gt: &DepthMap, test: &DepthMap, taus: &[f64]) -> Vec<f64> {
        vsd(est, gt, test, KS, 15.0, taus, true, 100.0, VsdCost::Step).unwrap()
    }

    fn map(rows: [[f32; 4]; 4]) -> DepthMap {
        DepthMap::new(4, 4, rows.iter().flatten().copied().collect()).unwrap()
    }

    /// Object in columns `cols` at depth `d`, zero elsewhere.
    fn render(cols: std::ops::Range<usize>, d: f32) -> DepthMap {
        let mut rows = [[0.0f32; 4]; 4];
        for row in rows.iter_mut() {
            for c in cols.clone() {
                row[c] = d;
            }
        }
        map(rows)
    }

    #[test]
    fn vsd_true_pose_is_zero() {
        let gt = render(0..2, 100.0);
        let test = map([[100.0, 100.0, 200.0, 200.0]; 4]);
        let e = vsd_step(&gt, &gt, &test, &[0.05, 0.5]);
        assert_eq!(e, vec![0.0, 0.0]);
    }

    #[test]
    fn vsd_shifted_estimate() {
        // gt: columns 0-1 at 100; est: columns 1-2 at 100; test: object at 100 in
        // columns 0-1, wall at 200 elsewhere.
        // visib_gt = cols 0-1 (8 px). visib_est: col 1 (100 vs 100) and col 2
        // (100 − 200 ≤ 15) → cols 1-2 (8 px). inter = col 1 (4 px, distance 0),
        // union = cols 0-2 (12 px) → e = (0 + 8) / 12 = 2/3 for every tau.
        let gt = render(0..2, 100.0);
        let est = render(1..3, 100.0);
        let test = map([[100.0, 100.0, 200.0, 200.0]; 4]);
        let e = vsd_step(&est, &gt, &test, &[0.05, 0.5]);
        assert_eq!(e, vec![8.0 / 12.0, 8.0 / 12.0]);
    }

    #[test]
    fn vsd_test_depth_occludes_and_missing_depth_is_visible() {
        // gt render: columns 0-1 at 100. est render: same pixels at 110 (10 mm deeper).
        // test: an occluder at 50 over all of row 0; object at 100 in rows 1-3 of
        // columns 0-1 except pixel (row 3, col 1) with missing depth (0); wall 200.
        // visib_gt: row 0 hidden (100 − 50 = 50 > 15); rows 1-3 visible, (3,1) because
        // test = 0 → 6 px. visib_est: row 0 hidden (110 − 50 = 60); rows 1-3 visible
        // (110 − 100 = 10 ≤ 15, or test = 0) → same 6 px. inter = union = 6, comp = 0,
        // distances ≈ 10 mm → normalised 0.1 (diameter 100).
        // tau 0.05: all 6 cost 1 → e = 6/6 = 1; tau 0.2: none → e = 0.
        let gt = render(0..2, 100.0);
        let est = render(0..2, 110.0);
        let test = map([[50.0, 50.0, 50.0, 50.0], [100.0, 100.0, 200.0, 200.0], [100.0, 100.0, 200.0, 200.0], [100.0, 0.0, 200.0, 200.0]]);
        let e = vsd_step(&est, &gt, &test, &[0.05, 0.2]);
        assert_eq!(e, vec![1.0, 0.0]);
        // Unnormalised taus in mm give the same decisions.
        let e = vsd(&est, &gt, &test, KS, 15.0, &[5.0, 20.0], false, 100.0, VsdCost::Step).unwrap();
        assert_eq!(e, vec![1.0, 0.0]);
        // tlinear: cost = min(d/tau, 1) ≈ 0.1/0.2 = 0.5 per pixel → e ≈ 0.5.
        let e = vsd(&est, &gt, &test, KS, 15.0, &[0.2], true, 100.0, VsdCost::TLinear).unwrap();
        assert!((e[0] - 0.5).abs() < 1e-3, "{e:?}");
    }

    #[test]
    fn vsd_partial_visibility_uses_gt_mask_for_estimate() {
        // gt render: columns 0-1 at 100. est render: columns 1-2 at 130.
        // test: occluder at 50 over row 0; object at 100 in columns 0-1; wall 200.
        // visib_gt: rows 1-3 × cols 0-1 (6 px; row 0 hidden by the occluder).
        // est own test: col 1: 130 − 100 = 30 > 15 → hidden; col 2: 130 − 200 ≤ 15
        // → visible (rows 1-3; row 0: 130 − 50 = 80 → hidden). The toolkit adds
        // visib_gt ∧ (est > 0) = rows 1-3 × col 1, so visib_est = rows 1-3 × cols 1-2.
        // inter = rows 1-3 × col 1 (3 px, distance ≈ 30 mm = 0.3 normalised),
        // union = rows 1-3 × cols 0-2 (9 px), comp = 6.
        // tau 0.2: (3 + 6) / 9 = 1; tau 0.4: (0 + 6) / 9 = 2/3.
        let gt = render(0..2, 100.0);
        let est = render(1..3, 130.0);
        let test = map([[50.0, 50.0, 50.0, 50.0], [100.0, 100.0, 200.0, 200.0], [100.0, 100.0, 200.0, 200.0], [100.0, 100.0, 200.0, 200.0]]);
        let e = vsd_step(&est, &gt, &test, &[0.2, 0.4]);
        assert_eq!(e, vec![1.0, 6.0 / 9.0]);
    }

    #[test]
    fn vsd_empty_union_is_one() {
        // Nothing rendered in either pose.
        let empty = DepthMap::zeros(4, 4);
        let test = map([[100.0; 4]; 4]);
        let e = vsd_step(&empty, &empty, &test, &[0.05, 0.3, 0.5]);
        assert_eq!(e, vec![1.0; 3]);
        // Object fully occluded in gt and estimate rendered at the same occluded spot.
        let gt = render(0..2, 100.0);
        let test = map([[50.0; 4]; 4]);
        let e = vsd_step(&gt, &gt, &test, &[0.05]);
        assert_eq!(e, vec![1.0]);
    }

    #[test]
    fn distance_image_matches_formula() {
        let d = map([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 200.0]]);
        let dist = depth_to_distance(&d, KS).unwrap();
        // Pixel (3, 3): X = (3 − 1.5)/100·200 = 3, Y = 3, Z = 200.
        assert_eq!(dist[15], (9.0f64 + 9.0 + 40000.0).sqrt());
        assert_eq!(dist[0], 0.0);
    }

    #[test]
    fn pairwise_sum_matches_plain_sum_on_exact_values() {
        let v: Vec<f64> = (0..1000).map(|i| i as f64).collect();
        assert_eq!(pairwise_sum(&v), 499500.0);
        assert_eq!(numpy_sum(&v[..7]), 21.0);
        assert_eq!(numpy_sum(&[]), 0.0);
    }
}
