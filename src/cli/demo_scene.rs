//! What a demo is, for both of its paths (in-process, `demo_cmd`, and through a running
//! server, `demo_client`): its arguments, the sample object, the photo-like scene it makes
//! and the report against the truth.

use super::estimate_cmd::describe_pose;
use crate::eval::degrade::{add_noise, clutter_background, composite, gaussian_blur};
use crate::geometry::views::view_pose;
use crate::geometry::{geodesic_distance, Intrinsics};
use crate::mesh::procedural::{textured_box, Rng};
use crate::render::RenderOptions;
use anyhow::Result;
use nalgebra::Vector3;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Output folder: object model, scene image, mask, result JSON and overlay.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Scene seed (object pose, lighting, clutter).
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Skip render-guided re-correspondence.
    #[arg(long)]
    pub no_rrc: bool,
    /// Run against a running `b2tf serve` instead of in-process: its gRPC endpoint
    /// (grpc://HOST:PORT, or grpcs:// for TLS). The sample is onboarded and the pose
    /// estimated through the API.
    #[arg(long)]
    pub server: Option<String>,
    /// API key for --server (also $B2TF_API_KEY).
    #[arg(long, env = "B2TF_API_KEY", hide_env_values = true)]
    pub api_key: Option<String>,
    /// CA certificate (PEM) to trust for grpcs:// (e.g. a self-signed server certificate).
    #[arg(long)]
    pub ca_cert: Option<PathBuf>,
}

/// The generated sample object the demo onboards.
pub fn sample_mesh() -> crate::mesh::Mesh {
    textured_box([0.10, 0.06, 0.16], 3)
}

/// A photo-like scene of `mesh`: random pose, light, clutter, blur and sensor noise.
pub struct DemoScene {
    pub k: Intrinsics,
    pub truth: crate::geometry::Pose,
    pub photo: image::RgbImage,
    pub mask: image::GrayImage,
}

pub fn make_scene(mesh: &crate::mesh::Mesh, renderer: &crate::render::RenderPool, seed: u64, out: &std::path::Path) -> Result<DemoScene> {
    let k = Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480)?;
    let mut rng = Rng::new(seed);
    let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let mut truth = view_pose(&dir, rng.range(0.0, std::f64::consts::TAU), &Vector3::zeros(), rng.range(0.45, 0.6));
    truth.translation += Vector3::new(rng.range(-0.06, 0.06), rng.range(-0.04, 0.04), 0.0);
    let light = RenderOptions { light_dir: [rng.range(-1.0, 1.0) as f32, rng.range(-1.0, 1.0) as f32, -1.0], light_intensity: 0.8, ambient: 0.25, ..RenderOptions::default() };
    let r = renderer.render(mesh, &truth, &k, &light)?;
    let bg = clutter_background(k.width, k.height, &mut rng);
    let photo = add_noise(&gaussian_blur(&composite(&r.rgb, &r.mask, &bg), 0.8), 3.0, &mut rng);
    photo.save(out.join("scene.png"))?;
    r.mask.save(out.join("mask.png"))?;
    Ok(DemoScene { k, truth, photo, mask: r.mask })
}

/// Prints the estimate against the truth.
pub fn report(truth: &crate::geometry::Pose, estimate: &crate::geometry::Pose, score: f32, diameter_m: f64, ms: f64) {
    println!("truth:    {}", describe_pose(truth, 1.0));
    println!("estimate: {}", describe_pose(estimate, score));
    let rot = geodesic_distance(&estimate.rotation, &truth.rotation).to_degrees();
    let trans = (estimate.translation - truth.translation).norm() * 1e3;
    println!("error: rotation {rot:.1}°, translation {trans:.1} mm (object diameter {:.0} mm); {ms:.0} ms", diameter_m * 1e3);
}
