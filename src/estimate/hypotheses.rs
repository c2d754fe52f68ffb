//! Pose hypotheses for one mask beyond PnP's: the RRC axis variants (90°/180°/270° about
//! the object's axes: the flips an outline cannot tell apart from the pose itself) and the
//! poses of the best retrieved templates placed where the mask is. Hypothesis
//! verification refines them all and keeps the one the evidence favours.

use super::rrc::{variant_pose, variant_rotations};
use crate::geometry::{CropBox, Intrinsics, Pose};
use crate::onboard::ObjectModel;
use nalgebra::{Rotation3, Vector3};

/// Where a hypothesis came from (reported in the diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind", content = "index")]
pub enum Source {
    /// The PnP (or RRC) pose of the pipeline.
    Pipeline,
    /// That pose turned by RRC variant `i` (1–9) about the object's centre.
    Flip(usize),
    /// Retrieved template number `i` (0 = best), placed at the mask.
    Template(usize),
}

/// The pipeline's pose, its nine axis variants, and the first `templates` retrieved
/// templates placed in the query crop.
pub fn candidates(model: &ObjectModel, pose: &Pose, retrieved: &[usize], templates: usize, query_crop: &CropBox, k: &Intrinsics) -> Vec<(Source, Pose)> {
    let centre = Vector3::from(model.mesh.bbox_center());
    let mut out = vec![(Source::Pipeline, *pose)];
    for (i, delta) in variant_rotations().iter().enumerate().skip(1) {
        out.push((Source::Flip(i), variant_pose(pose, delta, &centre)));
    }
    for (i, &t) in retrieved.iter().take(templates).enumerate() {
        if let Some(p) = place_template(model, t, query_crop, k) {
            out.push((Source::Template(i), p));
        }
    }
    out
}

/// The pose that makes the query crop look like template `t`'s crop: the object centre
/// where the template's crop has it, the depth from the ratio of the crop sizes, and the
/// template's rotation turned so its optical axis becomes the ray through that centre.
pub fn place_template(model: &ObjectModel, t: usize, query_crop: &CropBox, k: &Intrinsics) -> Option<Pose> {
    let tp = &model.templates[t];
    let kt = &model.render_intrinsics;
    let centre = Vector3::from(model.mesh.bbox_center());
    let c_t = tp.pose.rotation * centre + tp.pose.translation;
    let uv_t = kt.project(&nalgebra::Point3::from(c_t))?;
    let (cu, cv) = tp.crop.to_crop(uv_t.x, uv_t.y);
    let (u, v) = query_crop.to_image(cu, cv);
    // Same share of the crop ⇒ same apparent size: z ∝ focal / window side.
    let z = c_t.z * (k.fx.max(k.fy) / kt.fx.max(kt.fy)) * (tp.crop.side / query_crop.side);
    let ray = Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
    let turn = Rotation3::rotation_between(&Vector3::z(), &ray).unwrap_or_else(Rotation3::identity);
    let rotation = turn * tp.pose.rotation;
    let c_q = ray * z;
    Some(Pose::new(rotation, c_q - rotation * centre))
}
