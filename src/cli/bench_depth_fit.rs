//! `b2tf bench depth-fit`: the depth fit (`estimate::depth_fit`) on its own, on generated
//! cases with known truth: the object rendered at a random view in front of a wall, the
//! depth through the sensor model (`depth::sensor`), a start pose perturbed from the truth
//! (a turn about the object's centre, a shift, and optionally an error along the ray as a
//! box's depth has), and the model surface its render at the start shows. Prints the
//! errors after the fit and its time. With `--dump DIR` each case's points, poses and depth
//! are written for a peer to fit the same points (tools/bench/icp_peer.py runs Open3D's
//! point-to-plane ICP on them).

use crate::depth::sensor::fill_with_plane;
use crate::depth::DepthImage;
use crate::estimate::depth_fit::{fit, visible_samples, DepthFitConfig};
use crate::eval::pose_error::{rotation_error_deg, translation_error_m};
use crate::geometry::views::view_pose;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Units;
use anyhow::{Context, Result};
use nalgebra::{Rotation3, Unit, Vector3};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchDepthFitArgs {
    /// Mesh to fit (default: the generated sample box).
    #[arg(long)]
    pub mesh: Option<PathBuf>,
    #[arg(long)]
    pub units: Option<Units>,
    #[arg(long, default_value_t = 40)]
    pub cases: usize,
    /// The start pose's turn from the truth, degrees, and shift, millimetres.
    #[arg(long, default_value_t = 5.0)]
    pub degrees: f64,
    #[arg(long, default_value_t = 10.0)]
    pub mm: f64,
    /// And this much too deep along the ray through the object's centre, millimetres.
    #[arg(long, default_value_t = 0.0)]
    pub depth_mm: f64,
    /// The renderer's exact depth instead of the sensor model's.
    #[arg(long)]
    pub exact_depth: bool,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write each case (points, normals, poses, depth PNG) here for a peer to fit.
    #[arg(long, value_name = "DIR")]
    pub dump: Option<PathBuf>,
}

#[derive(serde::Serialize)]
struct Case {
    k: [f64; 4],
    width: u32,
    height: u32,
    /// Object-frame model points and normals the start pose's render shows.
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    diameter: f64,
    /// The object's bounding-box centre, object frame: where centre errors are measured.
    centre: [f64; 3],
    /// 4×4 row-major object-to-camera transforms.
    start: [f64; 16],
    truth: [f64; 16],
    fitted: [f64; 16],
    fit_ms: f64,
    /// depth_NNNN.png: uint16, 0.1 mm units.
    depth_png: String,
}

fn matrix(p: &Pose) -> [f64; 16] {
    let r = p.rotation_row_major();
    [r[0], r[1], r[2], p.translation.x, r[3], r[4], r[5], p.translation.y, r[6], r[7], r[8], p.translation.z, 0.0, 0.0, 0.0, 1.0]
}

pub fn run(a: BenchDepthFitArgs) -> Result<()> {
    let mesh = match &a.mesh {
        Some(p) => super::bench_scenes::bench_meshes(std::slice::from_ref(p), a.units)?.remove(0).1,
        None => crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], 3),
    };
    let pool = super::open_renderer(1)?;
    let k = Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480)?;
    let sensor = super::depth_sensor(a.exact_depth);
    let centre = Vector3::from(mesh.bbox_center());
    let diameter = mesh.diameter();
    if let Some(d) = &a.dump {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    let mut rng = Rng::new(a.seed);
    let (mut rot, mut trans, mut before_rot, mut before_trans, mut ms) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for i in 0..a.cases {
        let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal().abs() + 0.3).normalize();
        let truth = view_pose(&dir, rng.uniform() * std::f64::consts::TAU, &centre, rng.range(0.5, 1.0));
        let render = pool.render(&mesh, &truth, &k, &Default::default())?;
        let mut exact = render.depth.clone();
        let at = (truth.rotation * centre + truth.translation).z;
        fill_with_plane(&mut exact, &k, at * 1.5, (0.0, 0.0));
        let measured = sensor.measure(&exact, Some(&render.rgb), &k, a.seed ^ (i as u64 + 1).wrapping_mul(0x9e37_79b9));
        let depth = DepthImage::from_metres(k.width, k.height, measured.clone())?;
        let axis = Unit::new_normalize(Vector3::new(rng.normal(), rng.normal(), rng.normal()));
        let turn = Rotation3::from_axis_angle(&axis, a.degrees.to_radians());
        let shift = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize() * (a.mm / 1000.0);
        let c = truth.rotation * centre + truth.translation;
        let along = c.normalize() * (a.depth_mm / 1000.0);
        // Turned about the object's centre, then moved.
        let start = Pose::new(turn * truth.rotation, turn * (truth.translation - c) + c + shift + along);
        let seen = pool.render(&mesh, &start, &k, &Default::default())?;
        let samples = visible_samples(&seen, &start, &k);
        let t = Instant::now();
        let (fitted, _) = fit(&samples, &start, &depth, &k, diameter, &DepthFitConfig::default());
        let fit_ms = t.elapsed().as_secs_f64() * 1e3;
        let centred = |p: &Pose| Pose::new(p.rotation, p.rotation * centre + p.translation);
        rot.push(rotation_error_deg(&fitted, &truth));
        trans.push(translation_error_m(&centred(&fitted), &centred(&truth)) * 1e3);
        before_rot.push(rotation_error_deg(&start, &truth));
        before_trans.push(translation_error_m(&centred(&start), &centred(&truth)) * 1e3);
        ms.push(fit_ms);
        if let Some(d) = &a.dump {
            let png = format!("depth_{i:04}.png");
            let tenths: Vec<u16> = measured.iter().map(|&z| (z * 1e4).round().min(65535.0) as u16).collect();
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(k.width, k.height, tenths).expect("w × h").save(d.join(&png))?;
            let case = Case {
                k: [k.fx, k.fy, k.cx, k.cy],
                width: k.width,
                height: k.height,
                points: samples.iter().map(|s| s.point.into()).collect(),
                normals: samples.iter().map(|s| s.normal.into()).collect(),
                diameter,
                centre: centre.into(),
                start: matrix(&start),
                truth: matrix(&truth),
                fitted: matrix(&fitted),
                fit_ms,
                depth_png: png,
            };
            std::fs::write(d.join(format!("case_{i:04}.json")), serde_json::to_string(&case)?)?;
        }
    }
    let summary = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() as f64 - 1.0) * q).round() as usize];
        format!("{:.2} | {:.2}", at(0.5), at(0.9))
    };
    let within = rot.iter().zip(&trans).filter(|(r, t)| **r < 1.0 && **t < 2.0).count();
    println!("{} cases, start {}° / {} mm off (+{} mm along the ray), {} depth:\n", a.cases, a.degrees, a.mm, a.depth_mm, if a.exact_depth { "exact" } else { "sensor-model" });
    println!("| | rotation error °, median | p90 | centre error mm, median | p90 | within 1° and 2 mm | ms, median | p90 |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    println!("| start | {} | {} | | | |", summary(&mut before_rot), summary(&mut before_trans));
    println!("| depth fit | {} | {} | {within} of {} | {} |", summary(&mut rot), summary(&mut trans), a.cases, summary(&mut ms));
    Ok(())
}
