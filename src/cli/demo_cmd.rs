//! `b2tf demo`: the whole method on an object and a photo-like scene the program makes
//! itself (no downloads): onboard, render a scene, estimate, compare with the truth.

use super::demo_scene::{make_scene, report, sample_mesh, DemoArgs};
use super::estimate_cmd::{describe_runner_up, result_json, write_overlay};
use crate::estimate::{Detection, EstimateConfig, Estimator};
use crate::features::{EmbeddedBackbone, EmbeddedConfig};
use anyhow::{Context, Result};
use std::sync::Arc;

pub fn run(a: DemoArgs) -> Result<()> {
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    if a.server.is_some() {
        return super::demo_client::run(&a);
    }
    let mesh = sample_mesh();
    let backbone = Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).map_err(anyhow::Error::msg)?);
    let renderer = Arc::new(super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?);

    let store = crate::store::open(&format!("sqlite://{}", a.out.join("objects.db").display()))?;
    let model = super::cached_model("demo-box", &mesh, store.as_ref(), backbone.as_ref(), &renderer, Default::default())?;
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
            write_overlay(&scene.photo, None, &renderer, &model, p, &scene.k, &a.out.join("overlay.png"))?;
            println!("wrote {}/{{scene,mask,overlay}}.png and result.json", a.out.display());
        }
        None => println!("no pose: {}", result.reason.as_deref().unwrap_or("unknown")),
    }
    Ok(())
}
