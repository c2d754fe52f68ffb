//! The contour refiner: from a pose hypothesis, align the object's projected outline with
//! the detection mask by correspondence lines and regularised Gauss–Newton, coarse to fine
//! over line scales, without rendering. It keeps the hypothesis when its own agreement
//! measure says the result is no better, so a good pose is never drifted away.

use super::lines::{build_lines, Line, LineScale, PhotoLines};
use super::posterior::Posterior;
use super::solve::{apply_update, gauss_newton_update, PointTerm, Regularisation};
use crate::estimate::refine::{RefineContext, RefineReport, Refined, Refiner};
use crate::geometry::Pose;
use crate::onboard::ContourModel;
use crate::render::RenderPool;
use nalgebra::Vector3;
use std::sync::Arc;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ContourRefinerConfig {
    /// First segment length as a share of the object's apparent diameter (clamped to
    /// `max_segment_px`); each later scale shrinks it, down to 1 px.
    pub first_segment_share: f64,
    pub max_segment_px: f64,
    /// Scales from coarse to fine, as factors of the first segment length.
    pub scale_factors: Vec<f64>,
    /// Segments on each side of a line's centre.
    pub segments: usize,
    /// Correspondence passes per scale, and pose updates per pass.
    pub passes_per_scale: usize,
    pub updates_per_pass: usize,
    pub regularisation: Regularisation,
    /// At least this share of the lines must find an edge for a pose to be refined at all.
    pub min_edge_share: f64,
    /// Weigh each line by the probability that its mask edge is the object's own rather
    /// than an occluder's (`occlusion.rs`); off, only the robust biweight guards.
    #[serde(default = "default_occlusion_model")]
    pub occlusion_model: bool,
    /// A local method's reach: a result turned more than this from the hypothesis, or moved
    /// in depth by more than this share of its distance, ran off along a direction the
    /// visible outline leaves open (a sliver of a hidden object) and is not taken.
    #[serde(default = "default_max_turn_deg")]
    pub max_turn_deg: f64,
    #[serde(default = "default_max_depth_change")]
    pub max_depth_change: f64,
    /// Which objects' lines, at the fine scales, take the photo's edge as the outline where
    /// it shows one clearly near the mask's (`photo_edge`); the others use the mask alone.
    #[serde(default)]
    pub photo_edges: PhotoEdges,
    /// Keep the start where the result agrees less with the mask than it did (measured at
    /// both on lines of the verification scale). Off, the start's agreement is measured
    /// only where the start is kept for another reason (its report).
    #[serde(default = "default_compare_with_start")]
    pub compare_with_start: bool,
}

/// Where the contour refiner reads outlines off the photo's edges, not the mask's alone.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum PhotoEdges {
    /// The mask alone, for every object.
    Off,
    /// Objects without colours of their own (no texture, no vertex colours) only: their
    /// outline is the only strong edge near it.
    Untextured,
    /// Every object; on an object with colours only the lines whose print stays plain
    /// inside the outline as far as the edge finder reads (`ContourModel::plain_share`), so
    /// that no print edge is there to be taken for the outline. On every line of textured
    /// objects, print edges beside the outline moved small objects' depths outward
    /// (docs/benchmarks/estimation-outlines.md, "Outlines from the photo's edges").
    #[default]
    Plain,
    /// Every line of every object.
    All,
}

impl PhotoEdges {
    /// How lines read `image` for an object with this mesh; `None` where they use the mask
    /// alone.
    pub(super) fn lines<'a>(self, image: &'a image::RgbImage, mesh: &crate::mesh::Mesh) -> Option<PhotoLines<'a>> {
        let coloured = mesh.has_colours();
        match self {
            Self::Off => None,
            Self::Untextured => (!coloured).then_some(PhotoLines { image, plain_only: false }),
            Self::Plain => Some(PhotoLines { image, plain_only: coloured }),
            Self::All => Some(PhotoLines { image, plain_only: false }),
        }
    }
}

fn default_max_turn_deg() -> f64 {
    30.0
}

fn default_max_depth_change() -> f64 {
    0.25
}

fn default_occlusion_model() -> bool {
    true
}

fn default_compare_with_start() -> bool {
    true
}

impl Default for ContourRefinerConfig {
    fn default() -> Self {
        Self {
            first_segment_share: 1.0 / 30.0,
            max_segment_px: 8.0,
            scale_factors: vec![1.0, 0.6, 0.35, 0.2],
            segments: 8,
            passes_per_scale: 2,
            updates_per_pass: 2,
            regularisation: Regularisation::default(),
            min_edge_share: 0.3,
            occlusion_model: true,
            max_turn_deg: default_max_turn_deg(),
            max_depth_change: default_max_depth_change(),
            photo_edges: PhotoEdges::default(),
            compare_with_start: true,
        }
    }
}

/// How well the outline at a pose agrees with the mask, measured on lines of one fixed
/// scale: the share of lines that find an edge near where the model says, in [0, 1].
#[derive(Clone, Copy, Debug, Default)]
pub struct Agreement {
    pub score: f64,
    pub lines: usize,
    pub lines_with_edge: usize,
    /// Weighted RMS of the outline offsets of the lines with an edge, px.
    pub residual_px: f64,
}

impl Agreement {
    pub(super) fn report(&self, moved: bool, note: Option<String>) -> RefineReport {
        RefineReport { moved, residual_px: self.residual_px, lines: self.lines, lines_with_edge: self.lines_with_edge, agreement: self.score, note, ..RefineReport::default() }
    }
}

fn agreement(lines: &[Line], scale: &LineScale) -> Agreement {
    let tolerance = 2.0 * scale.segment_px;
    let mut a = Agreement { lines: lines.len(), ..Default::default() };
    let (mut num, mut den) = (0.0, 0.0);
    for l in lines.iter().filter(|l| l.edge) {
        a.lines_with_edge += 1;
        a.score += (-0.5 * (l.mean / tolerance).powi(2)).exp();
        num += l.mean * l.mean / l.variance;
        den += 1.0 / l.variance;
    }
    a.score /= lines.len().max(1) as f64;
    a.residual_px = if den > 0.0 { (num / den).sqrt() } else { f64::NAN };
    a
}

/// What every measurement at a pose needs (`ContourRefiner::inputs`).
pub(super) type Inputs<'a> = (Arc<ContourModel>, Vector3<f64>, Posterior<'a>);

pub struct ContourRefiner {
    pub(super) renderer: Arc<RenderPool>,
    pub config: ContourRefinerConfig,
}

impl ContourRefiner {
    pub fn new(renderer: Arc<RenderPool>) -> Self {
        Self { renderer, config: ContourRefinerConfig::default() }
    }

    /// Apparent diameter of the object at `pose`, px.
    pub(super) fn apparent_diameter(ctx: &RefineContext<'_>, pose: &Pose, centre: &Vector3<f64>) -> f64 {
        let z = (pose.rotation * centre + pose.translation).z.max(1e-6);
        ctx.intrinsics.fx.max(ctx.intrinsics.fy) * ctx.model.diameter() / z
    }

    pub(super) fn scales(&self, diameter_px: f64) -> Vec<LineScale> {
        let first = (diameter_px * self.config.first_segment_share).clamp(1.0, self.config.max_segment_px);
        self.config.scale_factors.iter().map(|f| LineScale { segment_px: (first * f).max(1.0), segments: self.config.segments }).collect()
    }

    /// What every measurement at a pose needs: the contour model (built now for an object
    /// stored without one), the object centre and the mask's posterior.
    pub(super) fn inputs<'a>(&self, ctx: &RefineContext<'a>) -> Result<Inputs<'a>, String> {
        let cm = ctx.model.contour_model_or_build(&self.renderer).map_err(|e| e.to_string())?;
        Ok((cm, Vector3::from(ctx.model.mesh.bbox_center()), if ctx.mask_is_probability { Posterior::probabilities(ctx.mask) } else { Posterior::new(ctx.mask, ctx.unknown) }))
    }

    /// Agreement at `pose` on the verification scale for the object's size there.
    pub(super) fn agreement_at(&self, ctx: &RefineContext<'_>, cm: &ContourModel, centre: &Vector3<f64>, post: &Posterior<'_>, pose: &Pose) -> Agreement {
        let scale = self.verification_scale(Self::apparent_diameter(ctx, pose, centre));
        agreement(&build_lines(cm, centre, pose, ctx.intrinsics, post, scale, None), &scale)
    }

    /// The agreement of `pose` with the mask on the verification scale (what `refine`
    /// compares before and after, and what hypothesis verification reads).
    pub fn agreement(&self, ctx: &RefineContext<'_>, pose: &Pose) -> Result<Agreement, String> {
        let (cm, centre, post) = self.inputs(ctx)?;
        Ok(self.agreement_at(ctx, &cm, &centre, &post, pose))
    }

    /// Lines of the second scale, twice as long: wide enough to see an outline a few
    /// pixels off, fine enough to score its offset.
    fn verification_scale(&self, diameter_px: f64) -> LineScale {
        let s = self.scales(diameter_px);
        let mid = s.get(1).or(s.first()).copied().unwrap_or(LineScale { segment_px: 1.0, segments: self.config.segments });
        LineScale { segment_px: mid.segment_px, segments: 2 * mid.segments }
    }
}

/// A refinement taken through its first (coarsest) line scale, to be finished
/// ([`ContourRefiner::finish`]) or dropped where other hypotheses agree better there
/// (verification's cut, `VerifyConfig::finished`).
pub struct CoarseRun<'a> {
    inputs: Inputs<'a>,
    start: Pose,
    pose: Pose,
    scales: Vec<LineScale>,
    /// Agreement with the mask on the coarse scale's last lines (built before the last
    /// pass's updates): what the cut ranks runs by, read off lines built anyway.
    pub coarse_agreement: f64,
    last: LastStep,
}

/// What the last pose update said, reported with the refined pose.
#[derive(Clone, Copy)]
struct LastStep {
    /// The depth's standard deviation, the visible share of the outline and the share of
    /// lines whose outline came from the photo's edge.
    depth_sigma: f64,
    visible: f64,
    photo_share: f64,
}

/// A refinement begun: already over (the start kept, for a reason in its report), or
/// through its first scale.
// The run is several times a `Refined` (it carries the mask's posterior table), but a
// `Begun` lives only until it is sorted into finished and running: not worth a box each.
#[allow(clippy::large_enum_variant)]
pub enum Begun<'a> {
    Done(Refined),
    Coarse(CoarseRun<'a>),
}

impl ContourRefiner {
    /// The start kept, with its agreement and `note` as the report.
    fn kept(&self, ctx: &RefineContext<'_>, inputs: &Inputs<'_>, start: Pose, note: String) -> Refined {
        let (cm, centre, post) = inputs;
        Refined { pose: start, report: self.agreement_at(ctx, cm, centre, post, &start).report(false, Some(note)) }
    }

    /// Runs the line scales `scales` from `run.pose`, the first pass on `first` where it
    /// is given (lines already built at that pose on the first of them). The agreement of
    /// the last lines built (scored on the last pass only: only the cut reads it), or why
    /// the run left the field of view.
    fn run_scales(&self, ctx: &RefineContext<'_>, run: &mut CoarseRun<'_>, scales: &[LineScale], mut first: Option<Vec<Line>>) -> Result<f64, String> {
        let k = ctx.intrinsics;
        let radius = ctx.model.mesh.bounding_radius();
        let photo = self.config.photo_edges.lines(ctx.image, &ctx.model.mesh);
        let mut last_agreement = f64::NAN;
        let passes = scales.len() * self.config.passes_per_scale;
        for (pass, scale) in scales.iter().flat_map(|s| std::iter::repeat_n(s, self.config.passes_per_scale)).enumerate() {
            let (cm, centre, post) = &run.inputs;
            let lines = first.take().unwrap_or_else(|| build_lines(cm, centre, &run.pose, k, post, *scale, photo));
            if pass + 1 == passes {
                last_agreement = agreement(&lines, scale).score;
            }
            run.last.photo_share = lines.iter().filter(|l| l.photo_edge).count() as f64 / lines.len().max(1) as f64;
            for _ in 0..self.config.updates_per_pass {
                let Some(step) = gauss_newton_update(&lines, PointTerm::NONE, &run.pose, &run.start, k, &self.config.regularisation, radius, self.config.occlusion_model) else { break };
                run.pose = apply_update(&run.pose, &step.omega, &step.v);
                run.last.depth_sigma = step.depth_sigma(&run.pose);
                // Lines without an edge (hidden entirely, or past the image border)
                // count as not visible.
                run.last.visible = step.own_edges / lines.len().max(1) as f64;
            }
            if run.pose.translation.z <= 0.0 || !run.pose.translation.iter().all(|x| x.is_finite()) {
                return Err("no improvement: the update left the camera's field of view".into());
            }
        }
        Ok(last_agreement)
    }

    /// Checks the start and runs the first line scale from it.
    pub fn begin<'a>(&self, ctx: &RefineContext<'a>, start: Pose) -> Result<Begun<'a>, String> {
        let inputs = self.inputs(ctx)?;
        let (cm, centre, post) = &inputs;
        let scales = self.scales(Self::apparent_diameter(ctx, &start, centre));
        let photo = self.config.photo_edges.lines(ctx.image, &ctx.model.mesh);
        // Too few lines see the mask's outline (empty, wrong or far-off mask): no update
        // could be trusted. The first pass measures at the start on these lines.
        let coarse = build_lines(cm, centre, &start, ctx.intrinsics, post, scales[0], photo);
        let edges = coarse.iter().filter(|l| l.edge).count();
        if (edges as f64) < self.config.min_edge_share * coarse.len().max(1) as f64 {
            let note = format!("no improvement: {edges} of {} lines see the mask's outline", coarse.len());
            return Ok(Begun::Done(self.kept(ctx, &inputs, start, note)));
        }
        let last = LastStep { depth_sigma: f64::NAN, visible: f64::NAN, photo_share: f64::NAN };
        let first_scale = [scales[0]];
        let mut run = CoarseRun { inputs, start, pose: start, scales, coarse_agreement: f64::NAN, last };
        match self.run_scales(ctx, &mut run, &first_scale, Some(coarse)) {
            Ok(a) => run.coarse_agreement = a,
            Err(note) => return Ok(Begun::Done(self.kept(ctx, &run.inputs, start, note))),
        }
        Ok(Begun::Coarse(run))
    }

    /// Runs the remaining line scales of `run`, and keeps its start where the result ran
    /// beyond a local method's reach or agrees less with the mask than the start did.
    pub fn finish(&self, ctx: &RefineContext<'_>, mut run: CoarseRun<'_>) -> Result<Refined, String> {
        let finer = run.scales[1..].to_vec();
        if let Err(note) = self.run_scales(ctx, &mut run, &finer, None) {
            return Ok(self.kept(ctx, &run.inputs, run.start, note));
        }
        let inputs = &run.inputs;
        let (cm, centre, post) = inputs;
        let (start, pose) = (run.start, run.pose);
        let turn = start.rotation.rotation_to(&pose.rotation).angle().to_degrees();
        let (z0, z1) = ((start.rotation * centre + start.translation).z, (pose.rotation * centre + pose.translation).z);
        if turn > self.config.max_turn_deg || (z1 - z0).abs() > self.config.max_depth_change * z0 {
            let note = format!("no improvement: the result turned {turn:.0}° and moved {:.0} % in depth, beyond a local refinement's reach", 100.0 * (z1 - z0).abs() / z0);
            return Ok(self.kept(ctx, inputs, start, note));
        }
        let after = self.agreement_at(ctx, cm, centre, post, &pose);
        if self.config.compare_with_start {
            let before = self.agreement_at(ctx, cm, centre, post, &start);
            if after.score < before.score {
                let note = format!("no improvement: contour agreement {:.3} after, {:.3} before", after.score, before.score);
                return Ok(Refined { pose: start, report: before.report(false, Some(note)) });
            }
        }
        let LastStep { depth_sigma, visible, photo_share } = run.last;
        Ok(Refined { pose, report: RefineReport { depth_sigma_m: depth_sigma, visible_fraction: visible, photo_edge_share: photo_share, ..after.report(true, None) } })
    }
}

impl Refiner for ContourRefiner {
    fn name(&self) -> &str {
        "contour"
    }

    fn refine(&self, ctx: &RefineContext<'_>, start: Pose) -> Result<Refined, String> {
        match self.begin(ctx, start)? {
            Begun::Done(r) => Ok(r),
            Begun::Coarse(run) => self.finish(ctx, run),
        }
    }
}
