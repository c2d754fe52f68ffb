//! Small real object models for tests (the crate's and tests/): a textured box onboarded
//! once per test binary at 128², 12 views, every template with its own patch rows (the
//! tests of rows per view share them from these). `None` (the test skips, after saying why)
//! without a GPU adapter, unless B2TF_REQUIRE_GPU is set, as elsewhere in the crate.

use super::{ObjectModel, OnboardConfig};
use crate::geometry::ViewSampling;
use crate::render::{RenderError, RenderPool, RendererConfig};
use std::sync::OnceLock;

/// 24 templates: 12 views, each also turned a half-turn.
pub fn small_model() -> Option<&'static ObjectModel> {
    static MODEL: OnceLock<Option<ObjectModel>> = OnceLock::new();
    MODEL.get_or_init(|| onboard_box(2)).as_ref()
}

/// 36 templates: 12 views at three in-plane turns (a third of a turn is not its own inverse,
/// as a half-turn is: tests of turned rows need it).
pub fn turned_model() -> Option<&'static ObjectModel> {
    static MODEL: OnceLock<Option<ObjectModel>> = OnceLock::new();
    MODEL.get_or_init(|| onboard_box(3)).as_ref()
}

fn onboard_box(in_plane_steps: u32) -> Option<ObjectModel> {
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
    let config = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps }, render_size: 128, patch_rows: super::PatchRows::PerTemplate, ..Default::default() };
    Some(super::onboard("obj-a", &mesh, &config, &backbone, &pool, &|_| {}).expect("onboarding the test object"))
}
