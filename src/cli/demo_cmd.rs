//! `b2tf demo`: the whole method on an object and a photo-like scene the program makes
//! itself (no downloads): onboard, render a scene, estimate, compare with the truth.

use super::estimate_cmd::{describe_pose, describe_runner_up, result_json, write_overlay};
use crate::estimate::{Detection, EstimateConfig, Estimator};
use crate::eval::degrade::{add_noise, clutter_background, composite, gaussian_blur};
use crate::features::{EmbeddedBackbone, EmbeddedConfig};
use crate::geometry::views::view_pose;
use crate::geometry::{geodesic_distance, Intrinsics};
use crate::mesh::procedural::{textured_box, Rng};
use crate::render::RenderOptions;
use anyhow::{Context, Result};
use nalgebra::Vector3;
use std::path::PathBuf;
use std::sync::Arc;

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

pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    if a.server.is_some() {
        return super::demo_client::run(&a);
    }
    let mesh = sample_mesh();
    let backbone = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).map_err(anyhow::Error::msg)?);
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);

    let store = crate::store::open(&format!("sqlite://{}", a.out.join("objects.db").display()))?;
    let model = super::cached_model("demo-box", &mesh, store.as_ref(), backbone.as_ref(), &renderer, Default::default(), Default::default())?;
    println!("demo object: {} templates, {} patches", model.template_count(), model.patch_count());

    let scene = make_scene(&mesh, &renderer, a.seed, &a.out)?;
    let estimator = Estimator::new(backbone, renderer.clone());
    let cfg = EstimateConfig { rrc: !a.no_rrc, ..Default::default() };
    let result = estimator.estimate(&model, &scene.photo, &scene.k, &[Detection::new(scene.mask.clone(), 1.0)], &cfg)?;
    std::fs::write(a.out.join("result.json"), serde_json::to_vec_pretty(&result_json(&model, &result))?)?;
    match &result.pose {
        Some(p) => {
            report(&scene.truth, p, result.score, model.diameter(), result.timings.total);
            if let Some(u) = &result.runner_up {
                println!("{}", describe_runner_up(u));
            }
            write_overlay(&scene.photo, &renderer, &model, p, &scene.k, &a.out.join("overlay.png"))?;
            println!("wrote {}/{{scene,mask,overlay}}.png and result.json", a.out.display());
        }
        None => println!("no pose: {}", result.reason.as_deref().unwrap_or("unknown")),
    }
    Ok(())
}
