//! `b2tf demo`: the whole method on an object and a photo-like scene the program makes
//! itself (no downloads): onboard, render a scene, estimate, compare with the truth.

use super::estimate_cmd::{describe_pose, result_json, write_overlay};
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
}

pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    let mesh = textured_box([0.10, 0.06, 0.16], 3);
    let backbone = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).map_err(anyhow::Error::msg)?);
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);

    let store = crate::store::open(&format!("sqlite://{}", a.out.join("objects.db").display()))?;
    let model = super::cached_model("demo-box", &mesh, store.as_ref(), backbone.as_ref(), &renderer)?;
    println!("demo object: {} templates, {} patches", model.template_count(), model.patch_count());

    // A photo-like scene: random pose, light, clutter, blur and sensor noise.
    let k = Intrinsics::new(600.0, 600.0, 319.5, 239.5, 640, 480)?;
    let mut rng = Rng::new(a.seed);
    let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let mut truth = view_pose(&dir, rng.range(0.0, std::f64::consts::TAU), &Vector3::zeros(), rng.range(0.45, 0.6));
    truth.translation += Vector3::new(rng.range(-0.06, 0.06), rng.range(-0.04, 0.04), 0.0);
    let light = RenderOptions { light_dir: [rng.range(-1.0, 1.0) as f32, rng.range(-1.0, 1.0) as f32, -1.0], light_intensity: 0.8, ambient: 0.25, ..RenderOptions::default() };
    let r = renderer.render(&mesh, &truth, &k, &light)?;
    let bg = clutter_background(k.width, k.height, &mut rng);
    let photo = add_noise(&gaussian_blur(&composite(&r.rgb, &r.mask, &bg), 0.8), 3.0, &mut rng);
    photo.save(a.out.join("scene.png"))?;
    r.mask.save(a.out.join("mask.png"))?;

    let estimator = Estimator::new(backbone, renderer.clone());
    let cfg = EstimateConfig { rrc: !a.no_rrc, ..Default::default() };
    let result = estimator.estimate(&model, &photo, &k, &[Detection { mask: r.mask.clone(), score: 1.0 }], &cfg)?;
    std::fs::write(a.out.join("result.json"), serde_json::to_vec_pretty(&result_json(&model, &result))?)?;
    println!("truth:    {}", describe_pose(&truth, 1.0));
    match &result.pose {
        Some(p) => {
            println!("estimate: {}", describe_pose(p, result.score));
            let rot = geodesic_distance(&p.rotation, &truth.rotation).to_degrees();
            let trans = (p.translation - truth.translation).norm() * 1e3;
            println!("error: rotation {rot:.1}°, translation {trans:.1} mm (object diameter {:.0} mm); {:.0} ms", model.diameter() * 1e3, result.timings.total);
            write_overlay(&photo, &renderer, &model, p, &k, &a.out.join("overlay.png"))?;
            println!("wrote {}/{{scene,mask,overlay}}.png and result.json", a.out.display());
        }
        None => println!("no pose: {}", result.reason.as_deref().unwrap_or("unknown")),
    }
    Ok(())
}
