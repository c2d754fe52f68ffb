//! The final refinement stage. The paper uses MegaPose (a trained network); here a
//! `Refiner` is any pose → pose step: the default passes the pose through unchanged, the
//! training-free ones align the silhouette (`silhouette_refiner`) or the contour
//! (`contour`) with the detection mask.

use crate::geometry::{Intrinsics, Pose};
use crate::onboard::ObjectModel;
use image::{GrayImage, RgbImage};

/// The refiners an estimate can run, by name (CLI `--refiner`, API `options.refiner`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum RefinerKind {
    /// Pass the pose through (the paper's pipeline without MegaPose).
    None,
    /// Scale the depth to the best silhouette IoU (a few renders).
    SilhouetteDepth,
    /// Align the projected contour with the mask's outline (no rendering). The default:
    /// it measured best (docs/benchmarks/estimation-verification.md, "Contour refiner").
    #[default]
    Contour,
}

impl RefinerKind {
    pub const ALL: [RefinerKind; 3] = [RefinerKind::None, RefinerKind::SilhouetteDepth, RefinerKind::Contour];

    pub fn name(self) -> &'static str {
        match self {
            RefinerKind::None => "none",
            RefinerKind::SilhouetteDepth => "silhouette-depth",
            RefinerKind::Contour => "contour",
        }
    }
}

impl std::str::FromStr for RefinerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| format!("unknown refiner {s:?}: none, silhouette-depth or contour"))
    }
}

/// What a refiner may look at.
pub struct RefineContext<'a> {
    pub model: &'a ObjectModel,
    pub image: &'a RgbImage,
    pub intrinsics: &'a Intrinsics,
    pub mask: &'a GrayImage,
    /// Pixels where the mask's outline says nothing about this object (e.g. other
    /// detections that may hide it); `None`: the mask holds everywhere.
    pub unknown: Option<&'a GrayImage>,
    /// The mask holds foreground probabilities (value / 255, e.g. from colour histograms
    /// while tracking) rather than object / not object (any non-zero value).
    pub mask_is_probability: bool,
    /// The caller's box, where the mask is one of its proposals (`Detection::from_box`):
    /// verification judges a pose by how well it fills the box as well as the mask.
    pub from_box: Option<crate::masks::PixelBox>,
    /// The depth camera's image registered to `image`, where the caller sent one:
    /// verification fits each rendered hypothesis to it (`estimate::depth_fit`).
    pub depth: Option<&'a crate::depth::DepthImage>,
}

/// What a refiner did to one hypothesis.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RefineReport {
    /// Whether the pose changed.
    pub moved: bool,
    /// Weighted RMS offset (px) between the projected model outline and the mask's outline
    /// along the lines that found one (contour refiner; NaN for the others).
    pub residual_px: f64,
    /// Correspondence lines, and how many of them found the mask's outline.
    pub lines: usize,
    pub lines_with_edge: usize,
    /// The refiner's own measure of fit in [0, 1] (contour: share of lines with an edge
    /// close to the model's outline; silhouette-depth: render IoU).
    pub agreement: f64,
    /// Why the pose was kept, when it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// Standard deviation of the refined pose's depth (camera z, metres) that the contour
    /// refiner's last step implies (its line offsets' variances through the normal
    /// equations, prior included); NaN (null) where it did not move the pose, and for the
    /// other refiners.
    pub depth_sigma_m: f64,
    /// Share of the outline's correspondence lines that the contour refiner's last step
    /// took to see the object's own edge (the rest: hidden by something in front, past the
    /// image border, or showing no edge); NaN (null) where it did not move the pose, and
    /// for the other refiners.
    pub visible_fraction: f64,
    /// Share of the contour refiner's last lines whose outline came from the photo's edge
    /// rather than the mask's pixel steps (`contour::photo_edge`; 0 where photo edges are
    /// off for the object); NaN (null) where it did not move the pose, and for the other
    /// refiners.
    pub photo_edge_share: f64,
    /// Where the kept pose was refined on its print (`contour::print_refine`): how many
    /// print points the photo showed where the pose before and the result put them (the
    /// refinement is kept only where the second is clearly the larger); absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub print_points: Option<[usize; 2]>,
    /// The refined pose of a box proposal was then moved back until its outline covered
    /// the caller's box (`estimate::box_prior`); absent otherwise.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub moved_to_box: bool,
    /// The selected pose of a box cut by the image's border was then brought nearer until
    /// its outline reached the box's free edge (`box_prior::to_free_edge`); absent
    /// otherwise.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub moved_to_free_edge: bool,
    /// The pose fitted to the measured depth, and what the depth says of it
    /// (`estimate::depth_fit`); absent without depth.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_fit: Option<super::depth_fit::DepthFit>,
}

impl Default for RefineReport {
    fn default() -> Self {
        Self {
            moved: false,
            residual_px: 0.0,
            lines: 0,
            lines_with_edge: 0,
            agreement: 0.0,
            note: None,
            depth_sigma_m: f64::NAN,
            visible_fraction: f64::NAN,
            photo_edge_share: f64::NAN,
            print_points: None,
            moved_to_box: false,
            moved_to_free_edge: false,
            depth_fit: None,
        }
    }
}

pub struct Refined {
    pub pose: Pose,
    pub report: RefineReport,
}

pub trait Refiner: Send + Sync {
    fn name(&self) -> &str;
    fn refine(&self, ctx: &RefineContext<'_>, pose: Pose) -> Result<Refined, String>;
}

/// Returns the pose unchanged.
pub struct PassThrough;

impl Refiner for PassThrough {
    fn name(&self) -> &str {
        "none"
    }

    fn refine(&self, _: &RefineContext<'_>, pose: Pose) -> Result<Refined, String> {
        Ok(Refined { pose, report: RefineReport { residual_px: f64::NAN, agreement: f64::NAN, ..Default::default() } })
    }
}
