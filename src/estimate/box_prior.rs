//! What a caller's box says of the depth, whatever mask was proposed inside it.
//!
//! A box from a detector bounds the object's visible pixels, and the visible pixels are
//! inside the whole object's outline: at the right pose the projected outline covers the
//! box. A mask proposed from the box that took in only part of the object (one printed
//! face, the lit half) pulls the refined pose away until its outline fits that part: the
//! object ends far behind where it is (on real YCB-V frames, sugar boxes 0.4 m too deep).
//! Such a pose is moved back along its viewing ray until its outline covers the box. The
//! converse does not hold (an occluder may hide much of the object), so a pose whose
//! outline is larger than the box is left alone.
//!
//! It holds only for tight boxes: a box drawn loose brings the object nearer by its
//! looseness. By default ([`BoxPrior::Auto`]) it holds for objects whose mesh has no
//! colours, whose depth only the outline can tell, and not for printed ones, whose print
//! pins the depth already (docs/estimation.md, "What the box says of the depth").

use super::hypotheses::{outline_box, seen_at};
use crate::geometry::{Intrinsics, Pose};
use crate::masks::PixelBox;
use crate::mesh::Mesh;
use nalgebra::{Vector2, Vector3};
use serde::Deserialize;

/// Whether a box proposal's poses are held to cover the caller's box
/// (`EstimateConfig::box_prior`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum BoxPrior {
    /// For a mesh without colours (texture or vertex colours), not for one with them. On
    /// the real YCB-V frames (bare meshes) the prior took the AR from boxes from 0.258 to
    /// 0.403; on generated scenes over real photos it gained on bare meshes and lost on
    /// textured ones, whose print fixes the depth where the outline cannot.
    #[default]
    Auto,
    /// Always: the caller's boxes are drawn tight (a detector trained on tight boxes).
    Tight,
    /// Never: loosely drawn boxes (a fixed region of interest); the pose fits its proposal.
    Off,
}

impl BoxPrior {
    /// Whether the prior holds for an object with this mesh.
    pub fn holds(self, mesh: &Mesh) -> bool {
        match self {
            BoxPrior::Auto => !mesh.has_colours(),
            BoxPrior::Tight => true,
            BoxPrior::Off => false,
        }
    }

    /// The prior as a caller's yes / no (gRPC's optional bool, HTTP's and older configs'
    /// true / false): yes, tight; no, off. Unsaid is the caller's default.
    pub fn from_flag(flag: bool) -> Self {
        if flag {
            BoxPrior::Tight
        } else {
            BoxPrior::Off
        }
    }
}

/// `box_prior` as it is said: a name (`auto`, `tight`, `off`) or, as configs and requests
/// said it before the names, true (tight) or false (off).
pub fn deserialize<'de, D: serde::Deserializer<'de>>(d: D) -> Result<BoxPrior, D::Error> {
    #[derive(serde::Deserialize)]
    #[serde(untagged)]
    enum Said {
        Flag(bool),
        Name(BoxPrior),
    }
    Ok(match Said::deserialize(d).map_err(|_| serde::de::Error::custom("box_prior: expected true, false, \"auto\", \"tight\" or \"off\""))? {
        Said::Flag(flag) => BoxPrior::from_flag(flag),
        Said::Name(p) => p,
    })
}

/// How much larger than the outline (ratio of sides) the box may be before the pose is
/// moved. None: on real frames (docs/estimation.md, "What the box says of the depth") any
/// slack, or moving only to its edge, did worse with tight boxes, with boxes 5 % too
/// small and on average; only boxes drawn 5 % too large did better with a slack of 0.15.
pub const BOX_SLACK: f64 = 0.0;
/// Mesh vertices projected to measure the outline (every n-th, at most this many): more
/// than elsewhere, since a missed corner vertex here moves the pose in depth.
const OUTLINE_POINTS: usize = 50_000;

/// A pose's projected outline (its vertices' box, pixels) and its centre's projection:
/// what both moves of this module grow about.
struct Outlined {
    lo: [f64; 2],
    hi: [f64; 2],
    /// The mesh's box centre, in the object's frame and projected.
    centre: Vector3<f64>,
    uv: Vector2<f64>,
    /// The centre's camera depth.
    z: f64,
}

impl Outlined {
    /// `None` where the pose (or a vertex) is not in front of the camera.
    fn of(mesh: &Mesh, pose: &Pose, k: &Intrinsics) -> Option<Self> {
        let (lo, hi) = outline_box(mesh, pose, k, OUTLINE_POINTS)?;
        let centre = Vector3::from(mesh.bbox_center());
        let c = pose.rotation * centre + pose.translation;
        let uv = k.project(&nalgebra::Point3::from(c))?;
        Some(Outlined { lo, hi, centre, uv: Vector2::new(uv.x, uv.y), z: c.z })
    }

    /// `pose` brought nearer until its outline is `scale` times as large, its centre seen
    /// at `target`; the rotation turns with the viewing ray so the object is seen as before.
    fn nearer(&self, pose: &Pose, scale: f64, target: Vector2<f64>, k: &Intrinsics) -> Pose {
        let seen_from = Vector3::new((self.uv.x - k.cx) / k.fx, (self.uv.y - k.cy) / k.fy, 1.0);
        seen_at(&pose.rotation, &self.centre, &seen_from, (target.x, target.y), self.z / scale, k)
    }
}

/// A box's corners as the outline's are kept: min and max (u, v).
fn corners(b: &PixelBox) -> ([f64; 2], [f64; 2]) {
    ([b.x0 as f64, b.y0 as f64], [b.x1 as f64, b.y1 as f64])
}

/// `pose` brought nearer along its viewing ray, and shifted, until its projected outline
/// covers `b` (the smallest such move), where the box is wider or taller than the outline
/// by more than [`BOX_SLACK`]; the rotation turns with the ray so the object is seen as
/// before. `None` where the outline covers the box already, or the pose is not in front of
/// the camera.
pub fn covering_box(mesh: &Mesh, pose: &Pose, b: &PixelBox, k: &Intrinsics) -> Option<Pose> {
    let o = Outlined::of(mesh, pose, k)?;
    let ((lo, hi), (b_lo, b_hi)) = ((o.lo, o.hi), corners(b));
    let (outline_w, outline_h) = (hi[0] - lo[0], hi[1] - lo[1]);
    if outline_w <= 0.0 || outline_h <= 0.0 {
        return None;
    }
    let scale = ((b_hi[0] - b_lo[0]) / outline_w).max((b_hi[1] - b_lo[1]) / outline_h);
    if scale <= 1.0 + BOX_SLACK {
        return None;
    }
    // The outline grows about the centre's projection, then shifts the least that puts the
    // box inside it.
    let uv = o.uv;
    let mut shift = [0.0; 2];
    for a in 0..2 {
        let (g_lo, g_hi) = (uv[a] + (lo[a] - uv[a]) * scale, uv[a] + (hi[a] - uv[a]) * scale);
        shift[a] = if b_lo[a] < g_lo {
            b_lo[a] - g_lo
        } else if b_hi[a] > g_hi {
            b_hi[a] - g_hi
        } else {
            0.0
        };
    }
    Some(o.nearer(pose, scale, uv + Vector2::new(shift[0], shift[1]), k))
}

/// The share of a box's side within which its edge counts as cut by the image's border.
pub const BORDER_MARGIN: f64 = 0.02;

/// `pose` brought nearer along its viewing ray where `b` is cut by the image's border on
/// one side of an axis and the outline falls short of the box's free edge on the other:
/// the outline grows about the centre's projection until that edge reaches the box's.
/// `None` where no box edge is cut or the outline reaches the free edges already.
pub fn to_free_edge(mesh: &Mesh, pose: &Pose, b: &PixelBox, k: &Intrinsics) -> Option<Pose> {
    let o = Outlined::of(mesh, pose, k)?;
    let ((lo, hi, uv), (b_lo, b_hi)) = ((o.lo, o.hi, o.uv), corners(b));
    let image = [k.width as f64, k.height as f64];
    let mut scale = 0.0f64;
    for a in 0..2 {
        let margin = (BORDER_MARGIN * (b_hi[a] - b_lo[a])).max(1.0);
        let free = match (b_lo[a] <= margin, b_hi[a] >= image[a] - margin) {
            (false, true) if b_lo[a] < uv[a] && lo[a] < uv[a] && hi[a] >= image[a] => (uv[a] - b_lo[a]) / (uv[a] - lo[a]),
            (true, false) if uv[a] < b_hi[a] && uv[a] < hi[a] && lo[a] <= 0.0 => (b_hi[a] - uv[a]) / (hi[a] - uv[a]),
            _ => 0.0,
        };
        scale = scale.max(free);
    }
    (scale > 1.0).then(|| o.nearer(pose, scale, uv, k))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn cube() -> Mesh {
        crate::mesh::procedural::textured_box([0.08, 0.04, 0.02], 3)
    }

    fn camera() -> Intrinsics {
        Intrinsics::new(600.0, 600.0, 320.0, 240.0, 640, 480).unwrap()
    }

    fn outline(mesh: &Mesh, pose: &Pose, k: &Intrinsics) -> ([f64; 2], [f64; 2]) {
        outline_box(mesh, pose, k, OUTLINE_POINTS).unwrap()
    }

    #[test]
    fn a_pose_too_far_for_its_box_comes_back_to_cover_it() {
        let (mesh, k) = (cube(), camera());
        let truth = Pose::new(Rotation3::from_euler_angles(0.3, 0.2, 0.1), Vector3::new(0.02, -0.01, 0.6));
        let (lo, hi) = outline(&mesh, &truth, &k);
        let b = PixelBox { x0: lo[0].ceil() as u32, y0: lo[1].ceil() as u32, x1: hi[0].floor() as u32, y1: hi[1].floor() as u32 };
        // The same rotation at 1.5× the depth, as a half-mask pulls it.
        let far = Pose::new(truth.rotation, truth.translation * 1.5);
        let near = covering_box(&mesh, &far, &b, &k).expect("too far for its box");
        assert!((near.translation - truth.translation).norm() < 0.02, "{:?} against {:?}", near.translation, truth.translation);
        let (lo, hi) = outline(&mesh, &near, &k);
        assert!(lo[0] <= b.x0 as f64 + 1.0 && lo[1] <= b.y0 as f64 + 1.0 && hi[0] >= b.x1 as f64 - 1.0 && hi[1] >= b.y1 as f64 - 1.0);
        // Covering the box now, it stays (to rounding).
        assert!(covering_box(&mesh, &near, &b, &k).is_none_or(|p| (p.translation - near.translation).norm() < 1e-6));
    }

    #[test]
    fn a_pose_too_far_for_a_box_cut_by_the_border_comes_to_its_free_edge() {
        let (mesh, k) = (cube(), camera());
        // Long side upright, the lower part below the image: the box ends at the border.
        let truth = Pose::new(Rotation3::from_euler_angles(0.1, 0.2, std::f64::consts::FRAC_PI_2), Vector3::new(0.01, 0.105, 0.3));
        let (lo, hi) = outline(&mesh, &truth, &k);
        assert!(hi[1] > 500.0 && lo[1] > 300.0, "{lo:?} {hi:?}");
        let b = PixelBox { x0: lo[0].round() as u32, y0: lo[1].round() as u32, x1: hi[0].round() as u32, y1: 480 };
        // 20 % too far, the outline still running off the image: the box's height is only
        // the outline's cut, its top edge what is left to hold.
        let far = Pose::new(truth.rotation, truth.translation * 1.2);
        let near = to_free_edge(&mesh, &far, &b, &k).expect("short of the box's top");
        assert!((near.translation - truth.translation).norm() < 0.008, "{:?} against {:?}", near.translation, truth.translation);
        // Its outline's top now at the box's, to within two pixels (the growth about the
        // centre's projection is a perspective approximation).
        assert!((outline(&mesh, &near, &k).0[1] - b.y0 as f64).abs() < 2.0);
        // A box the border does not cut is the sized prior's, not this.
        let inside = PixelBox { y1: 470, ..b };
        assert!(to_free_edge(&mesh, &far, &inside, &k).is_none());
        // An outline that ends inside the image is not cut by it: nothing to hold.
        let whole = Pose::new(truth.rotation, Vector3::new(0.01, 0.0, 0.6));
        assert!(to_free_edge(&mesh, &whole, &b, &k).is_none());
    }

    #[test]
    fn a_pose_larger_than_its_box_is_left_alone() {
        let (mesh, k) = (cube(), camera());
        let pose = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, 0.5));
        // The box of the object's left half: an occluder hides the rest.
        let b = PixelBox { x0: 290, y0: 220, x1: 320, y1: 260 };
        assert!(covering_box(&mesh, &pose, &b, &k).is_none());
        // Behind the camera there is no outline to move.
        let behind = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.0, -0.5));
        assert!(covering_box(&mesh, &behind, &b, &k).is_none());
    }

    #[test]
    fn by_default_the_prior_holds_for_meshes_without_colours() {
        let bare = cube().without_appearance();
        let printed = cube();
        assert!(printed.has_colours() && !bare.has_colours());
        assert!(BoxPrior::default().holds(&bare) && !BoxPrior::default().holds(&printed));
        assert!(BoxPrior::Tight.holds(&printed) && !BoxPrior::Off.holds(&bare));
        assert_eq!([true, false].map(BoxPrior::from_flag), [BoxPrior::Tight, BoxPrior::Off]);
        assert_eq!(BoxPrior::default(), BoxPrior::Auto);
    }

    #[test]
    fn the_prior_is_said_by_name_or_as_the_flag_it_was() {
        #[derive(serde::Deserialize)]
        struct C {
            #[serde(deserialize_with = "deserialize")]
            p: BoxPrior,
        }
        let said = |v: &str| serde_json::from_str::<C>(&format!("{{\"p\": {v}}}")).map(|c| c.p);
        assert_eq!(said("true").unwrap(), BoxPrior::Tight);
        assert_eq!(said("false").unwrap(), BoxPrior::Off);
        assert_eq!(said("\"auto\"").unwrap(), BoxPrior::Auto);
        assert_eq!(said("\"tight\"").unwrap(), BoxPrior::Tight);
        let e = said("\"loose\"").unwrap_err().to_string();
        assert!(e.contains("box_prior") && e.contains("\"tight\""), "{e}");
    }
}
