//! `b2tf bench detect --estimate-store URL`: the one-call path users take (image + object
//! id → poses: the service's `Estimate` naming `objects`, detection then estimation with
//! confirmation) on the detection benchmark's scenes. Each answered pose is rendered and
//! its silhouette's box scored against the truth like a detection, with the confirmation
//! score as its score: so recall, AP and the answers on images without the object are the
//! detector's figures as a caller of `Estimate` meets them.

use crate::detect::detector::bbox_of;
use crate::detect::DetectOptions;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::RenderPool;
use crate::service::base64_bytes::Base64Bytes;
use crate::service::requests::{EstimateOptions, EstimateRequest, ImageInput, IntrinsicsInput};
use crate::service::{Core, CoreConfig};
use anyhow::{Context, Result};
use image::RgbImage;

/// The service core on the store holding the benchmark's objects, onboarded under their
/// mesh files' names (`b2tf onboard --id obj_000001 …`).
pub struct OneCall {
    core: Core,
    /// The detector's settings of every call (its threshold applies to the confirmation).
    detect: DetectOptions,
    /// Instances answered (with or without a pose), over all calls.
    pub answered: usize,
    pub ms: Vec<f64>,
}

impl OneCall {
    pub fn open(store_url: &str, ids: &[String], detect: DetectOptions) -> Result<Self> {
        // The renderers keep every searched object, as a cell's server would be set up for them
        // (`serve --render-meshes`).
        let render_meshes = crate::render::RendererConfig::keeping(ids.len()).max_cached_meshes;
        let core = Core::new(CoreConfig { store_url: store_url.into(), render_meshes, ..Default::default() }).with_context(|| format!("opening {store_url}"))?;
        let listed = core.list_objects().map_err(|e| anyhow::anyhow!("listing {store_url}: {e}"))?;
        if let Some(missing) = ids.iter().find(|id| !listed.iter().any(|o| o.id == **id)) {
            anyhow::bail!("--estimate-store {store_url} has no object {missing:?}: onboard each searched mesh under its file's name (b2tf onboard --mesh … --id {missing})");
        }
        Ok(Self { core, detect, answered: 0, ms: Vec::new() })
    }

    /// The boxes (rendered silhouettes of the answered poses) and confirmation scores of
    /// `instances` instances of `object_id` asked for in `rgb`.
    pub fn answer(&mut self, rgb: &RgbImage, k: &Intrinsics, object_id: &str, mesh: &Mesh, instances: usize, pool: &RenderPool) -> Result<Vec<([f64; 4], f32)>> {
        let req = EstimateRequest {
            image: ImageInput { encoded: None, raw_rgb8: Some(Base64Bytes(rgb.as_raw().clone())), width: Some(rgb.width()), height: Some(rgb.height()) },
            intrinsics: IntrinsicsInput { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height },
            detections: Vec::new(),
            objects: vec![object_id.to_string()],
            detect: self.detect.clone(),
            options: EstimateOptions { instances_per_object: instances, ..Default::default() },
            depth: None,
        };
        let answer = self.core.estimate(&req, None).map_err(|e| anyhow::anyhow!("estimating {object_id}: {e}"))?;
        self.ms.push(answer.total_ms);
        let mut out = Vec::new();
        for r in &answer.results {
            self.answered += 1;
            let Some(p) = &r.pose else { continue };
            let pose = Pose::from_row_major(&p.r, p.t);
            let silhouette = pool.render(mesh, &pose, k, &Default::default())?.mask;
            if let Some(b) = bbox_of(&silhouette) {
                out.push((b, r.confirmation_score.unwrap_or(0.0)));
            }
        }
        Ok(out)
    }
}
