//! Pose hypotheses for one mask beyond PnP's: the RRC axis variants (90°/180°/270° about
//! the object's axes: the flips an outline cannot tell apart from the pose itself), finer
//! spins about the same axes (a can or bottle turned about its axis keeps its outline at
//! every angle, not only at quarter turns), and the poses of the best retrieved templates
//! placed where the mask is. Hypothesis verification refines them all and keeps the one
//! the evidence favours.

use super::rrc::{variant_pose, variant_rotations};
use crate::geometry::{CropBox, Intrinsics, Pose, ScaleShift};
use crate::mesh::Mesh;
use crate::onboard::ObjectModel;
use nalgebra::{Rotation3, Vector2, Vector3};

/// Where a hypothesis came from (reported in the diagnostics).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "kind", content = "index")]
pub enum Source {
    /// The PnP (or RRC) pose of the pipeline.
    Pipeline,
    /// That pose re-placed at the mask, where its outline and the mask disagree in size or
    /// place (`replaced_at_mask`); the flips and spins are then taken about it.
    Replaced,
    /// That pose turned by RRC variant `i` (1–9) about the object's centre.
    Flip(usize),
    /// Retrieved template number `i` (0 = best), placed at the mask.
    Template(usize),
    /// The template with the `i`-th most matches (0 = most), placed where its matches put
    /// it (`placement::matched_templates`).
    Matched(usize),
    /// Axis variant `i` (1–9) of the rendered hypothesis whose print agreed best with the
    /// photo's, where the winner's agreed with nothing (`pipeline::second_look`).
    PrintFlip(usize),
    /// That pose turned `degrees` about the object's `axis` (0 = x, 1 = y, 2 = z) through its
    /// centre: the angles between the quarter turns of `Flip`.
    Spin { axis: usize, degrees: u32 },
    /// The winner tilted a little across the line of sight: `0`, `1` each way about the
    /// axis nearest the camera's x, `2`, `3` about the other (`pipeline::nudge`).
    Nudge(usize),
    /// The caller's hint pose `i` (`Estimator::estimate_hinted`).
    Hint(usize),
    /// The `i`-th best template view placed on the measured depth (`depth_search`).
    DepthView(usize),
}

impl std::fmt::Display for Source {
    /// A short label for tables: `pipeline`, `flip-3`, `template-0`, `spin-z-45`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::Pipeline => write!(f, "pipeline"),
            Source::Replaced => write!(f, "replaced"),
            Source::Flip(i) => write!(f, "flip-{i}"),
            Source::Template(i) => write!(f, "template-{i}"),
            Source::Matched(i) => write!(f, "matched-{i}"),
            Source::PrintFlip(i) => write!(f, "print-flip-{i}"),
            Source::Hint(i) => write!(f, "hint-{i}"),
            Source::Nudge(i) => write!(f, "nudge-{i}"),
            Source::DepthView(i) => write!(f, "depth-view-{i}"),
            Source::Spin { axis, degrees } => write!(f, "spin-{}-{degrees}", ['x', 'y', 'z'].get(*axis).copied().unwrap_or('?')),
        }
    }
}

/// The start (the pipeline's pose, or `start_without_pnp`'s, labelled by where it came
/// from), that pose `replaced` at the mask where given, the nine axis variants and the
/// spins (`spin_steps` equal steps of a whole turn about each object axis, the quarter
/// turns left out as the variants hold them; 0 or 4 adds none) of the re-placed pose if
/// any, else of the start, and the first `templates` retrieved templates placed in the
/// query crop (`templates` and `spin_steps` of `cfg`; the start not twice).
pub fn candidates(
    model: &ObjectModel,
    (start, pose): (Source, &Pose),
    replaced: Option<&Pose>,
    retrieved: &[usize],
    cfg: &super::VerifyConfig,
    query_crop: &CropBox,
    k: &Intrinsics,
) -> Vec<(Source, Pose)> {
    let centre = Vector3::from(model.mesh.bbox_center());
    let mut out = vec![(start, *pose)];
    let base = match replaced {
        Some(r) => {
            out.push((Source::Replaced, *r));
            r
        }
        None => pose,
    };
    out.extend(flips(model, base).map(|(i, p)| (Source::Flip(i), p)));
    out.extend(spins(base, &centre, cfg.spin_steps));
    for (i, &t) in retrieved.iter().take(cfg.templates).enumerate() {
        if Source::Template(i) == start {
            continue;
        }
        if let Some(p) = place_template(model, t, query_crop, k) {
            out.push((Source::Template(i), p));
        }
    }
    out
}

/// Where verification starts when PnP found no pose (too few or too scattered matches: a
/// small, blurred or mostly hidden object): the template with the most matches where its
/// matches put it (`matched`, most first), else the best retrieved template placed at the
/// mask; `None` where neither exists. Its flips, spins and the other templates are then
/// verified as they would be about a PnP pose, so a failed PnP costs the estimate a
/// start, not the answer.
pub fn start_without_pnp(model: &ObjectModel, matched: &[Pose], retrieved: &[usize], query_crop: &CropBox, k: &Intrinsics) -> Option<(Source, Pose)> {
    if let Some(&p) = matched.first() {
        return Some((Source::Matched(0), p));
    }
    let &t = retrieved.first()?;
    place_template(model, t, query_crop, k).map(|p| (Source::Template(0), p))
}

/// The nine axis variants of `pose` (90°, 180° and 270° about each object axis through
/// the object's centre), numbered 1–9 as `rrc::variant_rotations`.
pub fn flips<'a>(model: &ObjectModel, pose: &'a Pose) -> impl Iterator<Item = (usize, Pose)> + 'a {
    let centre = Vector3::from(model.mesh.bbox_center());
    variant_rotations().into_iter().enumerate().skip(1).map(move |(i, delta)| (i, variant_pose(pose, &delta, &centre)))
}

/// `pose` turned about the object axes through `centre` by every multiple of a
/// `steps`-th of a turn that is not a quarter turn.
fn spins(pose: &Pose, centre: &Vector3<f64>, steps: usize) -> Vec<(Source, Pose)> {
    let mut out = Vec::new();
    for (axis, step) in (0..3).flat_map(|axis| (1..steps).map(move |step| (axis, step))) {
        let degrees = 360.0 * step as f64 / steps as f64;
        if (degrees / 90.0).fract().abs() < 1e-9 {
            continue;
        }
        out.push((Source::Spin { axis, degrees: degrees.round() as u32 }, turned_about(pose, centre, axis, degrees)));
    }
    out
}

/// `pose` turned by `degrees` about object axis `axis` (0 = x, 1 = y, 2 = z) through
/// `centre`: the spins.
fn turned_about(pose: &Pose, centre: &Vector3<f64>, axis: usize, degrees: f64) -> Pose {
    let delta = Rotation3::from_axis_angle(&[Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()][axis], degrees.to_radians());
    variant_pose(pose, &delta, centre)
}

/// The pose that makes the query crop look like template `t`'s crop: [`place_in`] with
/// the query crop's own mapping from crop to image.
pub fn place_template(model: &ObjectModel, t: usize, query_crop: &CropBox, k: &Intrinsics) -> Option<Pose> {
    place_in(model, t, &query_crop.to_image_map(), k)
}

/// Template `t` placed so that its crop pixels land on the image pixels `to_image` maps
/// them to: the object centre where the template's crop has it, the depth from the ratio
/// of the scales (image pixels per crop pixel), and the template's rotation turned so its
/// optical axis becomes the ray through that centre.
pub fn place_in(model: &ObjectModel, t: usize, to_image: &ScaleShift, k: &Intrinsics) -> Option<Pose> {
    let tp = &model.templates[t];
    let kt = &model.render_intrinsics;
    let centre = Vector3::from(model.mesh.bbox_center());
    let c_t = tp.pose.rotation * centre + tp.pose.translation;
    let uv_t = kt.project(&nalgebra::Point3::from(c_t))?;
    let (cu, cv) = tp.crop.to_crop(uv_t.x, uv_t.y);
    let [u, v] = to_image.apply([cu, cv]);
    // Same size in pixels ⇒ same apparent size: z ∝ focal / pixels per crop pixel.
    let z = c_t.z * (k.fx.max(k.fy) / kt.fx.max(kt.fy)) * (tp.crop.scale() / to_image.scale);
    if !(z.is_finite() && z > 0.0) {
        return None;
    }
    // The template's object centre is on its optical axis.
    Some(seen_at(&tp.pose.rotation, &centre, &Vector3::z(), (u, v), z, k))
}

/// An object turned by `rotation` whose `centre` (object frame) was seen along `from_ray`,
/// moved so that centre is at depth `z` on the ray through pixel `(u, v)`, the rotation
/// turned with the ray so the object is seen as it was.
pub(super) fn seen_at(rotation: &Rotation3<f64>, centre: &Vector3<f64>, from_ray: &Vector3<f64>, (u, v): (f64, f64), z: f64, k: &Intrinsics) -> Pose {
    let ray = Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
    let turn = Rotation3::rotation_between(from_ray, &ray).unwrap_or_else(Rotation3::identity);
    let rotation = turn * rotation;
    Pose::new(rotation, ray * z - rotation * centre)
}

/// How far a pose's projected outline box may differ from the mask's box, in size (ratio
/// of the long sides) and centre (share of the mask's long side), before its flips and
/// spins are taken about it re-placed at the mask instead.
const PLACEMENT_SLACK: f64 = 0.25;
/// Mesh vertices projected to measure an outline's box (every n-th, at most this many).
pub(super) const OUTLINE_POINTS: usize = 2000;

/// `pose` moved where the mask is, where its projected outline's box and the mask's box
/// (`mask_box`: min u, min v, max u, max v, inclusive pixels) disagree by more than
/// `PLACEMENT_SLACK`: the depth from the ratio of their long sides, the object's centre
/// shifted with the box's centre, and the rotation turned with the viewing ray so the
/// object is seen as before. `None` where they agree, or the pose is not in front of the
/// camera. A PnP pose can be far off in depth; turned about a wrong place, its flips and
/// spins cannot reach the right pose.
pub fn replaced_at_mask(mesh: &Mesh, pose: &Pose, mask_box: (u32, u32, u32, u32), k: &Intrinsics) -> Option<Pose> {
    let (lo, hi) = outline_box(mesh, pose, k, OUTLINE_POINTS)?;
    let (m_lo, m_hi) = ([mask_box.0 as f64, mask_box.1 as f64], [mask_box.2 as f64 + 1.0, mask_box.3 as f64 + 1.0]);
    let long = |lo: [f64; 2], hi: [f64; 2]| (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let mid = |lo: [f64; 2], hi: [f64; 2]| Vector2::new(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]));
    let (pose_long, mask_long) = (long(lo, hi), long(m_lo, m_hi));
    if pose_long <= 0.0 {
        return None;
    }
    let scale = mask_long / pose_long;
    let (pose_mid, mask_mid) = (mid(lo, hi), mid(m_lo, m_hi));
    if scale.ln().abs() < (1.0 + PLACEMENT_SLACK).ln() && (pose_mid - mask_mid).norm() / mask_long < PLACEMENT_SLACK {
        return None;
    }
    let centre = Vector3::from(mesh.bbox_center());
    let c = pose.rotation * centre + pose.translation;
    let uv = k.project(&nalgebra::Point3::from(c))?;
    // The outline scaled onto the mask's box: the centre keeps its place in the box.
    let target = mask_mid + (uv - pose_mid) * scale;
    let seen_from = Vector3::new((uv.x - k.cx) / k.fx, (uv.y - k.cy) / k.fy, 1.0);
    Some(seen_at(&pose.rotation, &centre, &seen_from, (target.x, target.y), c.z / scale, k))
}

/// The box (min, max pixel coordinates) of `mesh`'s vertices projected at `pose`, every
/// n-th vertex so that at most `points` are; `None` where one is not in front of the camera.
pub(super) fn outline_box(mesh: &Mesh, pose: &Pose, k: &Intrinsics, points: usize) -> Option<([f64; 2], [f64; 2])> {
    let positions = mesh.positions();
    let stride = positions.len().div_ceil(points.max(1)).max(1);
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in positions.iter().step_by(stride) {
        let uv = k.project(&nalgebra::Point3::from(pose.rotation * Vector3::from(p.map(f64::from)) + pose.translation))?;
        for a in 0..2 {
            lo[a] = lo[a].min(uv[a]);
            hi[a] = hi[a].max(uv[a]);
        }
    }
    Some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The mask box (inclusive pixels) of `mesh`'s outline at `pose`, every vertex counted.
    fn mask_box_of(mesh: &Mesh, pose: &Pose, k: &Intrinsics) -> (u32, u32, u32, u32) {
        let (lo, hi) = outline_box(mesh, pose, k, usize::MAX).unwrap();
        (lo[0].round() as u32, lo[1].round() as u32, hi[0].round() as u32 - 1, hi[1].round() as u32 - 1)
    }

    #[test]
    fn a_pose_far_off_in_depth_is_replaced_where_the_mask_is_and_seen_alike() {
        let mesh = crate::mesh::procedural::textured_box([0.08, 0.04, 0.02], 3);
        let k = Intrinsics::new(600.0, 600.0, 320.0, 240.0, 640, 480).unwrap();
        let turned = Rotation3::from_euler_angles(0.4, -0.3, 0.8);
        let truth = Pose::new(turned, Vector3::new(0.05, -0.02, 0.4));
        let mask_box = mask_box_of(&mesh, &truth, &k);
        // Seen the same way (the rotation turned with the viewing ray), but at twice the
        // distance and off to the side: PnP's depth gone wrong.
        let far_c = Vector3::new(-0.06, 0.05, 0.8);
        let turn = Rotation3::rotation_between(&(truth.rotation * Vector3::from(mesh.bbox_center()) + truth.translation), &far_c).unwrap();
        let rotation = turn * turned;
        let far = Pose::new(rotation, far_c - rotation * Vector3::from(mesh.bbox_center()));
        let r = replaced_at_mask(&mesh, &far, mask_box, &k).expect("boxes disagree");
        assert!((r.translation - truth.translation).norm() < 0.01, "{:?} against {:?}", r.translation, truth.translation);
        assert!((r.rotation.inverse() * truth.rotation).angle().to_degrees() < 1.0);
        // Where the outline fits the mask's box already, nothing is replaced.
        assert!(replaced_at_mask(&mesh, &truth, mask_box, &k).is_none());
        // Nor where the pose is behind the camera.
        assert!(replaced_at_mask(&mesh, &Pose::new(turned, Vector3::new(0.0, 0.0, -0.5)), mask_box, &k).is_none());
    }

    #[test]
    fn spins_fill_the_turns_between_the_flips() {
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.01, 0.02, 0.5));
        let centre = Vector3::new(0.01, -0.02, 0.03);
        assert!(spins(&pose, &centre, 0).is_empty() && spins(&pose, &centre, 4).is_empty());
        let eight = spins(&pose, &centre, 8);
        assert_eq!(eight.len(), 12, "45°, 135°, 225° and 315° about three axes");
        for (s, p) in &eight {
            let Source::Spin { axis, degrees } = *s else { unreachable!() };
            assert!(degrees % 90 != 0 && axis < 3, "{s:?}");
            // Turned about the object's centre: the centre stays where it was seen.
            assert!(((p.rotation * centre + p.translation) - (pose.rotation * centre + pose.translation)).norm() < 1e-12);
            let turn = (pose.rotation.inverse() * p.rotation).angle().to_degrees();
            assert!((turn - degrees.min(360 - degrees) as f64).abs() < 1e-6, "{s:?}: {turn}");
        }
        assert_eq!(spins(&pose, &centre, 12).len(), 24);
        assert_eq!(eight[0].0.to_string(), "spin-x-45");
        assert_eq!(eight[11].0.to_string(), "spin-z-315");
    }
}
