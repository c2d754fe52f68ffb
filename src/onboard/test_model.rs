//! A small real object model for tests (the crate's and tests/): a textured box onboarded
//! once per test binary at 24 templates of 128². `None` (the test skips, after saying why)
//! without a GPU adapter, unless B2TF_REQUIRE_GPU is set, as elsewhere in the crate.

use super::{ObjectModel, OnboardConfig};
use crate::geometry::ViewSampling;
use crate::render::{RenderError, RenderPool, RendererConfig};
use std::sync::OnceLock;

pub fn small_model() -> Option<&'static ObjectModel> {
    static MODEL: OnceLock<Option<ObjectModel>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let pool = match RenderPool::new(1, RendererConfig::default()) {
                Ok(p) => p,
                Err(e @ RenderError::NoAdapter { .. }) if std::env::var_os("B2TF_REQUIRE_GPU").is_none() => {
                    eprintln!("SKIPPED (no GPU adapter): {e}");
                    return None;
                }
                Err(e) => panic!("{e}"),
            };
            let backbone = crate::features::EmbeddedBackbone::new(crate::features::EmbeddedConfig::default()).expect("embedded backbone");
            let mesh = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
            let config = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 2 }, render_size: 128, ..Default::default() };
            Some(super::onboard("obj-a", &mesh, &config, &backbone, &pool, &|_| {}).expect("onboarding the test object"))
        })
        .as_ref()
}
