//! Synthetic correspondences: a ~15 cm object 0.3–1.0 m in front of a 640×480, f = 600
//! camera, random rotations, Gaussian pixel noise, outliers as uniform random image points.

use nalgebra::{Point3, Quaternion, Rotation3, UnitQuaternion, Vector3};

use super::matches::Matches;
use super::p3p::p3p;
use super::refine::{levenberg_marquardt, LmOptions};
use super::rng::SplitMix64;
use super::*;
use crate::geometry::{Intrinsics, Pose};

fn camera() -> Intrinsics {
    Intrinsics::new(600.0, 600.0, 320.0, 240.0, 640, 480).unwrap()
}

fn gaussian(rng: &mut SplitMix64) -> f64 {
    // Box–Muller; 1 − u keeps the logarithm finite.
    let (u, v) = (1.0 - rng.unit(), rng.unit());
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

fn random_rotation(rng: &mut SplitMix64) -> Rotation3<f64> {
    // A normalised 4D Gaussian is uniform on the unit quaternions, hence on SO(3).
    let q = Quaternion::new(gaussian(rng), gaussian(rng), gaussian(rng), gaussian(rng));
    UnitQuaternion::from_quaternion(q).to_rotation_matrix()
}

#[derive(Clone, Copy)]
enum Shape {
    Cube,
    /// A flat face: every object point has z = 0.
    Plane,
}

struct Scene {
    k: Intrinsics,
    truth: Pose,
    object: Vec<[f64; 3]>,
    image: Vec<[f64; 2]>,
    inlier: Vec<bool>,
}

fn scene(seed: u64, n: usize, noise_px: f64, outlier_ratio: f64, shape: Shape) -> Scene {
    let mut rng = SplitMix64::new(seed);
    let k = camera();
    let depth = 0.3 + 0.7 * rng.unit();
    // Object centre somewhere over the central part of the image.
    let centre = k.back_project(160.0 + 320.0 * rng.unit(), 120.0 + 240.0 * rng.unit(), depth);
    let truth = Pose::new(random_rotation(&mut rng), centre.coords);
    let side = |rng: &mut SplitMix64| 0.15 * (rng.unit() - 0.5);
    let (mut object, mut image, mut inlier) = (Vec::new(), Vec::new(), Vec::new());
    while object.len() < n {
        let x = [
            side(&mut rng),
            side(&mut rng),
            match shape {
                Shape::Cube => side(&mut rng),
                Shape::Plane => 0.0,
            },
        ];
        let Some(uv) = k.project(&truth.transform_point(&Point3::from(x))) else { continue };
        let outlier = rng.unit() < outlier_ratio;
        let uv = if outlier { [k.width as f64 * rng.unit(), k.height as f64 * rng.unit()] } else { [uv.x + noise_px * gaussian(&mut rng), uv.y + noise_px * gaussian(&mut rng)] };
        object.push(x);
        image.push(uv);
        inlier.push(!outlier);
    }
    Scene { k, truth, object, image, inlier }
}

fn config(seed: u64) -> PnpConfig {
    PnpConfig { seed, ..PnpConfig::default() }
}

/// The angle between two rotations, from ‖A − B‖_F = 2√2·sin(θ/2): unlike the acos of the
/// trace, it resolves angles far below 1e-8 rad.
fn angle_between(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    let chord = (a.matrix() - b.matrix()).norm() / (2.0 * std::f64::consts::SQRT_2);
    2.0 * chord.min(1.0).asin()
}

/// (rotation error in radians, translation error in metres per metre of true depth).
fn errors(s: &Scene, pose: &Pose) -> (f64, f64) {
    let rot = angle_between(&s.truth.rotation, &pose.rotation);
    (rot, (pose.translation - s.truth.translation).norm() / s.truth.translation.z)
}

#[test]
fn p3p_finds_the_true_pose_among_its_solutions() {
    for seed in 0..200 {
        let s = scene(seed, 3, 0.0, 0.0, Shape::Cube);
        let world = [0, 1, 2].map(|i| Vector3::from(s.object[i]));
        let bearings = [0, 1, 2].map(|i| s.k.back_project(s.image[i][0], s.image[i][1], 1.0).coords.normalize());
        let solutions = p3p(&world, &bearings);
        let best = solutions.as_slice().iter().map(|p| angle_between(&p.rotation, &s.truth.rotation) + (p.translation - s.truth.translation).norm()).fold(f64::INFINITY, f64::min);
        assert!(best < 1e-8, "seed {seed}: {} solutions, best off by {best:e}", solutions.as_slice().len());
        for p in solutions.as_slice() {
            for x in &world {
                assert!(p.transform_point(&Point3::from(*x)).z > 0.0, "seed {seed}: a point behind the camera");
            }
        }
    }
}

#[test]
fn p3p_rejects_a_collinear_triple() {
    let world = [Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.1, 0.0, 0.0), Vector3::new(0.2, 0.0, 0.0)];
    let bearings = [Vector3::z(), Vector3::new(0.1, 0.0, 1.0).normalize(), Vector3::new(0.2, 0.0, 1.0).normalize()];
    assert!(p3p(&world, &bearings).as_slice().is_empty());
}

#[test]
fn exact_matches_give_the_exact_pose() {
    for (seed, shape) in (0..20).map(|s| (s, Shape::Cube)).chain((0..20).map(|s| (100 + s, Shape::Plane))) {
        let s = scene(seed, 50, 0.0, 0.0, shape);
        let r = solve_pnp_ransac(&s.image, &s.object, &s.k, &config(seed)).unwrap();
        let (rot, trans) = errors(&s, &r.pose);
        assert!(rot < 1e-6 && trans * s.truth.translation.z < 1e-6, "seed {seed}: {rot:e} rad, {trans:e} m/m");
        assert_eq!(r.inliers.len(), 50);
        assert!(r.mean_reprojection_error_px < 1e-6);
    }
}

#[test]
fn anisotropic_focal_lengths() {
    let s = scene(11, 60, 0.0, 0.0, Shape::Cube);
    let k = Intrinsics::new(580.0, 640.0, 330.0, 250.0, 640, 480).unwrap();
    let image: Vec<[f64; 2]> = s
        .object
        .iter()
        .map(|x| {
            let uv = k.project(&s.truth.transform_point(&Point3::from(*x))).unwrap();
            [uv.x, uv.y]
        })
        .collect();
    let r = solve_pnp_ransac(&image, &s.object, &k, &config(0)).unwrap();
    let (rot, trans) = errors(&s, &r.pose);
    assert!(rot < 1e-6 && trans < 1e-6, "{rot:e} rad, {trans:e} m/m");
}

#[test]
fn results_are_reproducible_for_a_seed() {
    let s = scene(7, 200, 1.0, 0.7, Shape::Cube);
    let a = solve_pnp_ransac(&s.image, &s.object, &s.k, &config(3)).unwrap();
    let b = solve_pnp_ransac(&s.image, &s.object, &s.k, &config(3)).unwrap();
    assert_eq!(a, b);
}

/// Sum of squared pixel errors of the true inliers under `pose`.
fn true_inlier_cost(s: &Scene, pose: &Pose) -> f64 {
    (0..s.object.len())
        .filter(|&i| s.inlier[i])
        .map(|i| {
            let uv = s.k.project(&pose.transform_point(&Point3::from(s.object[i]))).unwrap();
            (uv.x - s.image[i][0]).powi(2) + (uv.y - s.image[i][1]).powi(2)
        })
        .sum()
}

/// 1 px noise, 70 % outliers, 300 matches, 20 scenes per shape, all must pass.
///
/// The bounds are the noise floor, not wishes: the maximum-likelihood pose (least squares on
/// the true inliers, started at the truth) is itself up to ~0.7° and ~6 mm per metre of depth
/// off on the cube over 200 scenes (~90 inliers on a 15 cm object: depth σ ≈ z / 350), and
/// up to ~2.7° / ~10 mm/m on the plane (4.1° / 12.6 mm/m for our estimate over 300 scenes,
/// see `survey`). So each result must fit the true inliers as well as that oracle does
/// (≤ 2 % more squared error), keep nearly all of them, and stay within bounds a little
/// above the worst seen.
#[test]
fn noisy_matches_with_70_percent_outliers() {
    for (shape, first_seed, max_rot_deg, max_trans) in [(Shape::Cube, 1000, 1.0, 0.010), (Shape::Plane, 2000, 5.0, 0.020)] {
        let (mut worst_rot, mut worst_trans) = (0.0f64, 0.0f64);
        for seed in first_seed..first_seed + 20 {
            let s = scene(seed, 300, 1.0, 0.7, shape);
            let r = solve_pnp_ransac(&s.image, &s.object, &s.k, &config(seed)).unwrap();
            let (rot, trans) = errors(&s, &r.pose);
            worst_rot = worst_rot.max(rot.to_degrees());
            worst_trans = worst_trans.max(trans);
            assert!(rot.to_degrees() < max_rot_deg && trans < max_trans, "seed {seed}: {:.3}°, {:.2} mm/m", rot.to_degrees(), trans * 1e3);

            let m = Matches::new(&s.image, &s.object, &s.k, 4.0);
            let truth_in: Vec<usize> = (0..s.object.len()).filter(|&i| s.inlier[i]).collect();
            let oracle = levenberg_marquardt(&m, &truth_in, &s.truth, &LmOptions { max_iterations: 50, huber_px: None });
            let (ours, best) = (true_inlier_cost(&s, &r.pose), true_inlier_cost(&s, &oracle));
            assert!(ours <= 1.02 * best, "seed {seed}: squared error {ours:.1} px² vs oracle {best:.1} px²");
            let found = r.inliers.iter().filter(|&&i| s.inlier[i]).count();
            assert!(found as f64 >= 0.95 * truth_in.len() as f64, "seed {seed}: {found} of {} true inliers", truth_in.len());
            assert!(r.inliers.len() - found <= 3, "seed {seed}: {} false inliers", r.inliers.len() - found);
            assert!(r.mean_reprojection_error_px < 2.0);
        }
        println!("{:?}: worst {worst_rot:.3}°, {:.2} mm/m", shape as u8, worst_trans * 1e3);
    }
}

#[test]
fn without_refinement_the_pose_is_still_close() {
    let s = scene(42, 300, 1.0, 0.7, Shape::Cube);
    let r = solve_pnp_ransac(&s.image, &s.object, &s.k, &PnpConfig { refine: false, ..config(1) }).unwrap();
    let (rot, trans) = errors(&s, &r.pose);
    assert!(rot.to_degrees() < 1.0 && trans < 0.01, "{rot} rad, {trans} m/m");
}

fn solve(s: &Scene) -> Result<PnpResult, PnpError> {
    solve_pnp_ransac(&s.image, &s.object, &s.k, &config(0))
}

#[test]
fn too_few_matches() {
    let mut s = scene(1, 3, 0.0, 0.0, Shape::Cube);
    assert_eq!(solve(&s), Err(PnpError::NotEnoughPoints { got: 3, need: 6 }));
    s.image.clear();
    s.object.clear();
    assert_eq!(solve(&s), Err(PnpError::NotEnoughPoints { got: 0, need: 6 }));
    let s = scene(1, 4, 0.0, 0.0, Shape::Cube);
    let cfg = PnpConfig { min_inliers: 0, ..config(0) };
    assert!(solve_pnp_ransac(&s.image, &s.object, &s.k, &cfg).is_ok(), "four exact matches suffice");
}

#[test]
fn mismatched_lengths() {
    let mut s = scene(1, 10, 0.0, 0.0, Shape::Cube);
    s.image.pop();
    assert_eq!(solve(&s), Err(PnpError::LengthMismatch { image: 9, object: 10 }));
}

#[test]
fn non_finite_input() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut s = scene(1, 10, 0.0, 0.0, Shape::Cube);
        s.image[3][1] = bad;
        assert_eq!(solve(&s), Err(PnpError::NonFinite));
        let mut s = scene(1, 10, 0.0, 0.0, Shape::Cube);
        s.object[7][2] = bad;
        assert_eq!(solve(&s), Err(PnpError::NonFinite));
        let mut s = scene(1, 10, 0.0, 0.0, Shape::Cube);
        s.k.cx = bad;
        assert_eq!(solve(&s), Err(PnpError::NonFinite));
    }
    let mut s = scene(1, 10, 0.0, 0.0, Shape::Cube);
    s.k.fx = -600.0;
    assert_eq!(solve(&s), Err(PnpError::BadIntrinsics));
}

#[test]
fn bad_config() {
    let s = scene(1, 10, 0.0, 0.0, Shape::Cube);
    for cfg in [
        PnpConfig { reprojection_threshold_px: 0.0, ..config(0) },
        PnpConfig { reprojection_threshold_px: f64::NAN, ..config(0) },
        PnpConfig { confidence: 1.0, ..config(0) },
        PnpConfig { max_iterations: 0, ..config(0) },
    ] {
        assert!(matches!(solve_pnp_ransac(&s.image, &s.object, &s.k, &cfg), Err(PnpError::BadConfig(_))));
    }
}

/// Exact projections of degenerate object point sets (so the image is consistent), and
/// degenerate image point sets against a good object.
#[test]
fn degenerate_point_sets() {
    let k = camera();
    let truth = Pose::new(Rotation3::from_euler_angles(0.2, -0.4, 0.1), Vector3::new(0.02, -0.01, 0.6));
    let project = |x: &[f64; 3]| {
        let uv = k.project(&truth.transform_point(&Point3::from(*x))).unwrap();
        [uv.x, uv.y]
    };
    let line: Vec<[f64; 3]> = (0..20).map(|i| [0.005 * i as f64, -0.003 * i as f64, 0.002 * i as f64]).collect();
    let point: Vec<[f64; 3]> = vec![[0.01, 0.02, 0.03]; 20];
    for object in [line, point] {
        let image: Vec<[f64; 2]> = object.iter().map(project).collect();
        assert_eq!(solve_pnp_ransac(&image, &object, &k, &config(0)), Err(PnpError::Degenerate));
    }
    let good = scene(3, 20, 0.0, 0.0, Shape::Cube);
    let image_line: Vec<[f64; 2]> = (0..20).map(|i| [100.0 + 10.0 * i as f64, 50.0 + 7.0 * i as f64]).collect();
    let image_point = vec![[320.0, 240.0]; 20];
    for image in [image_line, image_point] {
        assert_eq!(solve_pnp_ransac(&image, &good.object, &k, &config(0)), Err(PnpError::Degenerate));
    }
}

/// The consensus set gets the same check as the input: good as a whole, degenerate on a line.
#[test]
fn collinear_subset_is_degenerate() {
    let s = scene(5, 30, 0.0, 0.0, Shape::Cube);
    let mut object = s.object.clone();
    let mut image = s.image.clone();
    for i in 0..10 {
        object[i] = [0.01 * i as f64, 0.02 * i as f64, 0.005];
        image[i] = [100.0 + i as f64, 200.0 - 3.0 * i as f64 + (i * i) as f64];
    }
    assert!(!super::validate::degenerate_spread(&image, &object, 0..30));
    assert!(super::validate::degenerate_spread(&image, &object, 0..10));
    assert!(super::validate::degenerate_spread(&s.image, &s.object, [2, 2, 2, 2].into_iter()));
}

#[test]
fn pure_noise_has_no_consensus() {
    let s = scene(9, 200, 0.0, 1.0, Shape::Cube);
    match solve(&s) {
        Err(PnpError::NoConsensus { best_inliers }) => assert!(best_inliers < 6),
        other => panic!("{other:?}"),
    }
}

/// Hostile but finite input (huge, tiny, repeated, behind the camera) gets an answer or an
/// error, never a panic.
#[test]
fn hostile_input_never_panics() {
    let mut rng = SplitMix64::new(77);
    let values = [0.0, 1.0, -1.0, 1e-300, -1e-300, 1e300, -1e300, 0.1, 320.0, 1e-9];
    for _ in 0..2000 {
        let n = rng.below(12);
        let pick = |rng: &mut SplitMix64| {
            if rng.below(2) == 0 {
                values[rng.below(values.len())]
            } else {
                2.0 * rng.unit() - 1.0
            }
        };
        let object: Vec<[f64; 3]> = (0..n).map(|_| [pick(&mut rng), pick(&mut rng), pick(&mut rng)]).collect();
        let image: Vec<[f64; 2]> = (0..n).map(|_| [1000.0 * pick(&mut rng), 1000.0 * pick(&mut rng)]).collect();
        let cfg = PnpConfig { min_inliers: rng.below(6), max_iterations: 200, ..config(rng.next_u64()) };
        let _ = solve_pnp_ransac(&image, &object, &camera(), &cfg);
    }
}

/// `cargo test --release -- --ignored --nocapture time_per_call`
#[test]
#[ignore]
fn time_per_call() {
    let scenes: Vec<Scene> = (0..50).map(|i| scene(5000 + i, 300, 1.0, 0.7, Shape::Cube)).collect();
    let start = std::time::Instant::now();
    let mut iterations = 0;
    let rounds = 10;
    for _ in 0..rounds {
        for (i, s) in scenes.iter().enumerate() {
            iterations += solve_pnp_ransac(&s.image, &s.object, &s.k, &config(i as u64)).unwrap().iterations;
        }
    }
    let calls = (rounds * scenes.len()) as f64;
    println!("300 matches, 70 % outliers: {:.3} ms per call, {:.0} RANSAC samples per call", start.elapsed().as_secs_f64() * 1e3 / calls, iterations as f64 / calls);
}

/// Wider than the gating test: how often each criterion of `noisy_matches_with_70_percent_outliers`
/// would fail over many scenes and harder settings. `cargo test -- --ignored --nocapture survey`
#[test]
#[ignore]
fn survey() {
    for (shape, n, outliers) in [(Shape::Cube, 300, 0.7), (Shape::Plane, 300, 0.7), (Shape::Cube, 100, 0.7), (Shape::Cube, 300, 0.8), (Shape::Plane, 100, 0.8)] {
        let (mut errors_, mut worse_than_oracle, mut lost_inliers, mut worst_rot, mut worst_trans) = (0, 0, 0, 0.0f64, 0.0f64);
        let trials = 300;
        for seed in 0..trials {
            let s = scene(50_000 + seed, n, 1.0, outliers, shape);
            let Ok(r) = solve_pnp_ransac(&s.image, &s.object, &s.k, &config(seed)) else {
                errors_ += 1;
                continue;
            };
            let (rot, trans) = errors(&s, &r.pose);
            worst_rot = worst_rot.max(rot.to_degrees());
            worst_trans = worst_trans.max(trans);
            let m = Matches::new(&s.image, &s.object, &s.k, 4.0);
            let truth_in: Vec<usize> = (0..n).filter(|&i| s.inlier[i]).collect();
            let oracle = levenberg_marquardt(&m, &truth_in, &s.truth, &LmOptions { max_iterations: 50, huber_px: None });
            if true_inlier_cost(&s, &r.pose) > 1.02 * true_inlier_cost(&s, &oracle) {
                worse_than_oracle += 1;
            }
            if (r.inliers.iter().filter(|&&i| s.inlier[i]).count() as f64) < 0.95 * truth_in.len() as f64 {
                lost_inliers += 1;
            }
        }
        println!(
            "shape {} n {n} outliers {outliers}: {trials} trials, errors {errors_}, worse than oracle {worse_than_oracle}, lost >5 % inliers {lost_inliers}, worst {worst_rot:.2}° {:.1} mm/m",
            shape as u8,
            worst_trans * 1e3
        );
    }
}
