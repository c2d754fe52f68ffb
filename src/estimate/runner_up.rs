//! The answer's runner-up: the best-scored verified hypothesis that is another answer (its
//! surface more than a tenth of the object's diameter from the answer's, up to the object's
//! symmetries, BOP's MSSD threshold), and the verification score by which it lost. A small
//! margin says the evidence could not tell two poses apart (a half-turn of an elongated
//! object, a tilt of a small one): a caller can look again, from elsewhere, or act on both.

use super::hypotheses::Source;
use super::verify::Verified;
use crate::geometry::surface_distance::{sample_points, symmetric_distance};
use crate::geometry::Pose;
use crate::onboard::ObjectModel;

/// Surface distance, as a share of the object's diameter, beyond which a hypothesis is
/// another answer rather than the same one settled a little differently.
pub const DISTINCT: f64 = 0.1;
/// A margin below this is a close call: on unseen generated HOPE scenes the answer was right
/// on 30 of 48 instances below it and on 185 of 192 above (docs/benchmarks.md, "The
/// runner-up's margin").
pub const CLOSE_CALL: f64 = 0.03;
/// Surface points compared (a strided sample of the mesh's vertices).
const POINTS: usize = 500;
/// Steps per half-turn about a continuous symmetry axis when comparing poses.
const AXIS_STEPS: usize = 36;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunnerUp {
    pub pose: Pose,
    /// Where the runner-up came from (the pipeline's pose, a flip, a template, …).
    pub source: Source,
    /// The answer's verification score minus the runner-up's (≥ 0; same scale as the
    /// per-hypothesis `score` in the diagnostics).
    pub margin: f64,
    /// How far the runner-up's surface is from the answer's (symmetry-aware), as a share of
    /// the object's diameter (> [`DISTINCT`]).
    pub distance: f64,
}

impl RunnerUp {
    /// Whether the answer won by less than [`CLOSE_CALL`]: the service sends this verdict
    /// with the margin, so that clients (Python, the console, the CLI) need not each hold
    /// the threshold.
    pub fn close_call(&self) -> bool {
        self.margin < CLOSE_CALL
    }
}

/// The runner-up of `answer` among `verified` (one mask's verified hypotheses, best first,
/// the first being the answer before any later refinement); `None` when no rendered
/// hypothesis is another answer (nothing else was judged on the photo, or all agree).
pub fn runner_up(answer: &Pose, verified: &[Verified], model: &ObjectModel) -> Option<RunnerUp> {
    let symmetries = model.symmetries.as_ref().map_or_else(|| vec![Pose::identity()], |s| crate::mesh::symmetry_finder::symmetry_poses(&s.symmetries, AXIS_STEPS));
    among(answer, verified, &symmetries, &sample_points(model.mesh.positions(), POINTS), model.diameter())
}

/// [`runner_up`] given the object's symmetry transformations (identity included), surface
/// points and diameter.
fn among(answer: &Pose, verified: &[Verified], symmetries: &[Pose], points: &[[f32; 3]], diameter: f64) -> Option<RunnerUp> {
    let best = verified.first()?;
    if diameter.is_nan() || diameter <= 0.0 {
        return None;
    }
    // Only hypotheses judged on their render compete on the same scale as the answer (an
    // unrendered one is scored on its outline alone, below every rendered one).
    let mut rivals: Vec<&Verified> = verified[1..].iter().filter(|v| v.iou.is_finite() && v.score.is_finite()).collect();
    rivals.sort_by(|a, b| b.score.total_cmp(&a.score));
    rivals.into_iter().find_map(|v| {
        let distance = symmetric_distance(answer, &v.pose, symmetries, points) / diameter;
        (distance > DISTINCT).then(|| RunnerUp { pose: v.pose, source: v.source, margin: (best.score - v.score).max(0.0), distance })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::RefineReport;
    use nalgebra::{Rotation3, Vector3};
    use std::f64::consts::PI;

    /// A 20 cm rod along z.
    const ROD: [[f32; 3]; 2] = [[0.0, 0.0, -0.1], [0.0, 0.0, 0.1]];

    fn answer() -> Pose {
        Pose::new(Rotation3::from_euler_angles(0.2, -0.1, 0.4), Vector3::new(0.0, 0.0, 0.8))
    }

    /// A hypothesis at `pose`, rendered (IoU known) or not, with `score`.
    fn judged(source: Source, pose: Pose, score: f64, rendered: bool) -> Verified {
        let nan = f64::NAN;
        Verified {
            source,
            pose,
            refinement: RefineReport::default(),
            contour: 0.9,
            iou: if rendered { 0.8 } else { nan },
            appearance: 0.5,
            edges: nan,
            colour: nan,
            features: nan,
            score,
            render: None,
        }
    }

    fn turned(by: Rotation3<f64>) -> Pose {
        answer().compose(&Pose::new(by, Vector3::zeros()))
    }

    #[test]
    fn the_best_distinct_rendered_hypothesis_is_the_runner_up() {
        let half = Rotation3::from_axis_angle(&Vector3::x_axis(), PI);
        let verified = [
            judged(Source::Pipeline, answer(), 0.80, true),
            // 2° away: the same answer settled a little differently (0.017·d), not a rival.
            judged(Source::Nudge(0), turned(Rotation3::from_axis_angle(&Vector3::x_axis(), 2f64.to_radians())), 0.79, true),
            // Scored higher than the half-turn but never rendered: not on the same scale.
            judged(Source::Flip(2), turned(Rotation3::from_axis_angle(&Vector3::y_axis(), PI / 2.0)), 0.78, false),
            judged(Source::Flip(1), turned(half), 0.77, true),
            judged(Source::Template(0), turned(Rotation3::from_axis_angle(&Vector3::y_axis(), 1.0)), 0.5, true),
        ];
        let u = among(&answer(), &verified, &[Pose::identity()], &ROD, 0.2).expect("a runner-up");
        assert_eq!(u.source, Source::Flip(1));
        assert!((u.margin - 0.03).abs() < 1e-9, "{}", u.margin);
        assert!((u.distance - 1.0).abs() < 1e-6, "a half-turned rod is its length away: {}", u.distance);
    }

    #[test]
    fn a_margin_below_the_threshold_is_a_close_call() {
        let at = |margin| RunnerUp { pose: answer(), source: Source::Flip(1), margin, distance: 0.5 };
        assert!(at(0.0).close_call() && at(CLOSE_CALL - 1e-9).close_call());
        assert!(!at(CLOSE_CALL).close_call() && !at(0.2).close_call());
    }

    #[test]
    fn a_pose_equal_up_to_a_symmetry_is_no_rival() {
        let half = Rotation3::from_axis_angle(&Vector3::x_axis(), PI);
        let verified = [judged(Source::Pipeline, answer(), 0.8, true), judged(Source::Flip(1), turned(half), 0.79, true)];
        assert!(among(&answer(), &verified, &[Pose::identity()], &ROD, 0.2).is_some());
        let symmetries = [Pose::identity(), Pose::new(half, Vector3::zeros())];
        assert_eq!(among(&answer(), &verified, &symmetries, &ROD, 0.2), None);
    }

    #[test]
    fn nothing_else_judged_means_no_runner_up() {
        assert_eq!(among(&answer(), &[], &[Pose::identity()], &ROD, 0.2), None);
        assert_eq!(among(&answer(), &[judged(Source::Pipeline, answer(), 0.8, true)], &[Pose::identity()], &ROD, 0.2), None);
        let moved = Pose::new(answer().rotation, answer().translation + Vector3::new(0.1, 0.0, 0.0));
        let verified = [judged(Source::Pipeline, answer(), 0.8, true), judged(Source::Template(0), moved, 0.7, true)];
        assert_eq!(among(&answer(), &verified, &[Pose::identity()], &ROD, 0.0), None, "no diameter, no scale");
    }
}
