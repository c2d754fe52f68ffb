//! Refining a pose on its print as well as its outline. The contour refiner alone cannot
//! tell a small object turned a few degrees from one a little nearer or farther: the
//! outline barely differs. Its print does. A few rounds of: render the pose, find its print
//! points in the photo (`print_points`), and take Gauss–Newton steps on the finest outline
//! lines and those points together.

use super::print_points::{print_points, PrintPoint, PrintPointConfig, WindowRender};
use super::refiner::ContourRefiner;
use super::solve::{apply_update, gauss_newton_update, PointTerm};
use crate::estimate::refine::{RefineContext, RefineReport};
use crate::estimate::select::window_camera;
use crate::geometry::Pose;
use crate::render::{RenderOptions, RenderOutput};

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrintRefineConfig {
    /// Rounds of render, match and update (0: off).
    pub rounds: usize,
    /// Gauss–Newton steps per round.
    pub updates_per_round: usize,
    pub points: PrintPointConfig,
    /// Standard deviation of a print point's position in the photo, px: a patch correlated
    /// to a fraction of a pixel, less what the render-to-real gap blurs. 0.5 by
    /// measurement: one instance more of 80 than 1.0 on each of three 10-HOPE sets
    /// (docs/benchmarks/estimation-outlines.md, "Estimated among the other detections, and
    /// refining on the print").
    pub point_sigma_px: f64,
    /// A print point agrees with a pose when the photo shows it within this many pixels of
    /// where the pose puts it.
    pub agree_px: f64,
    /// The result is taken only where this many more print points agree with it than with
    /// the pose it started from, and its outline agrees with the mask no less (to
    /// `contour_slack`).
    pub min_gain: usize,
    pub contour_slack: f64,
}

impl Default for PrintRefineConfig {
    fn default() -> Self {
        Self { rounds: 3, updates_per_round: 2, points: PrintPointConfig::default(), point_sigma_px: 0.5, agree_px: 1.5, min_gain: 3, contour_slack: 0.02 }
    }
}

/// What refining on the print made of a pose.
pub struct PrintRefined {
    pub pose: Pose,
    pub report: RefineReport,
    /// Its render over the window it was asked for.
    pub render: RenderOutput,
}

/// A round that moves the pose less than this (a turn, and a shift as a share of the
/// distance) has settled: a twentieth of a degree, and 0.05 %, are far below what a
/// pixel of a small object's print shows.
const SETTLED_RAD: f64 = 0.05 * std::f64::consts::PI / 180.0;
const SETTLED_SHARE: f64 = 5e-4;

impl ContourRefiner {
    /// `start` refined on its outline and its print together, rendered over `window` of the
    /// image; `None` where the object has no colours (no print to find), or where the result
    /// does not agree with more of the print (`PrintRefineConfig::min_gain`) or agrees
    /// less with the mask.
    ///
    /// `rendered`: `start` already rendered over `window` (verification's render of the
    /// winner), which saves one render.
    pub fn refine_on_print(
        &self,
        ctx: &RefineContext<'_>,
        start: &Pose,
        window: (u32, u32, u32, u32),
        rendered: Option<&RenderOutput>,
        cfg: &PrintRefineConfig,
    ) -> Result<Option<PrintRefined>, String> {
        if cfg.rounds == 0 || !ctx.model.mesh.has_colours() {
            return Ok(None);
        }
        let (cm, centre, post) = self.inputs(ctx)?;
        let k = ctx.intrinsics;
        let camera = window_camera(k, window).map_err(|e| e.to_string())?;
        let radius = ctx.model.mesh.bounding_radius();
        let photo = self.config.photo_edges.lines(ctx.image, &ctx.model.mesh);
        let find = |render: &RenderOutput, pose: &Pose| print_points(&WindowRender { render, pose, window, camera: &camera }, ctx.image, ctx.mask, ctx.unknown, &cfg.points);
        let look = |pose: &Pose| -> Result<(RenderOutput, Vec<PrintPoint>), String> {
            let render = self.renderer.render(&ctx.model.mesh, pose, &camera, &RenderOptions::default()).map_err(|e| e.to_string())?;
            let points = find(&render, pose);
            Ok((render, points))
        };
        let agreeing = |points: &[PrintPoint]| points.iter().filter(|p| p.offset_px <= cfg.agree_px).count();
        let mut points = match rendered {
            Some(r) if r.mask.dimensions() == (window.2, window.3) => find(r, start),
            _ => look(start)?.1,
        };
        let mut render = None;
        let agreeing_before = agreeing(&points);
        let mut pose = *start;
        // The pose the current points were found at.
        let mut looked = *start;
        // The last step's depth σ, and the shares of its lines that saw the object's own
        // outline and that took it from the photo's edge.
        let mut last = None;
        for _ in 0..cfg.rounds {
            if points.is_empty() {
                break;
            }
            let scale = *self.scales(Self::apparent_diameter(ctx, &pose, &centre)).last().expect("at least one scale");
            let lines = super::lines::build_lines(&cm, &centre, &pose, k, &post, scale, photo);
            for _ in 0..cfg.updates_per_round {
                let Some(s) =
                    gauss_newton_update(&lines, PointTerm { points: &points, sigma_px: cfg.point_sigma_px }, &pose, start, k, &self.config.regularisation, radius, self.config.occlusion_model)
                else {
                    break;
                };
                pose = apply_update(&pose, &s.omega, &s.v);
                let n = lines.len().max(1) as f64;
                last = Some((s.depth_sigma(&pose), s.own_edges / n, lines.iter().filter(|l| l.photo_edge).count() as f64 / n));
            }
            if pose.translation.z <= 0.0 || !pose.translation.iter().all(|x| x.is_finite()) {
                return Ok(None);
            }
            // Settled: where the points were last found is the result, and another render
            // would show the same.
            if looked.rotation.rotation_to(&pose.rotation).angle() < SETTLED_RAD && (looked.translation - pose.translation).norm() < SETTLED_SHARE * looked.translation.z {
                pose = looked;
                break;
            }
            let (r, p) = look(&pose)?;
            (render, points, looked) = (Some(r), p, pose);
        }
        let (Some((depth_sigma_m, visible_fraction, photo_edge_share)), Some(render)) = (last, render) else { return Ok(None) };
        let agreeing_after = agreeing(&points);
        let before = self.agreement_at(ctx, &cm, &centre, &post, start);
        let after = self.agreement_at(ctx, &cm, &centre, &post, &pose);
        let taken = agreeing_after >= agreeing_before + cfg.min_gain && after.score >= before.score - cfg.contour_slack;
        tracing::debug!(
            agreeing_before,
            agreeing_after,
            points = points.len(),
            contour_before = before.score,
            contour_after = after.score,
            turn_deg = start.rotation.rotation_to(&pose.rotation).angle().to_degrees(),
            dz_mm = (pose.translation.z - start.translation.z) * 1e3,
            taken,
            "refined on the print"
        );
        if !taken {
            return Ok(None);
        }
        let report = RefineReport { depth_sigma_m, visible_fraction, photo_edge_share, print_points: Some([agreeing_before, agreeing_after]), ..after.report(true, None) };
        Ok(Some(PrintRefined { pose, report, render }))
    }
}
