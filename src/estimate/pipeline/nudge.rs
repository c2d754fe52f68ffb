//! Verification's nudge: the winner turned a little each way, refined and judged.
//!
//! A small object's outline hardly changes under a turn of a few degrees, so the refiner
//! can settle a pose turned 5–10° off with its depth pulled a few per cent to fit the
//! outline, and nothing among the flips, spins and templates lies nearer. The same pose
//! turned a little about each object axis starts the refiner in the right pose's basin,
//! and the render (IoU, print, features) tells which way is right.

use super::{Estimator, EstimateConfig, EstimateError, QueryView, RefineContext, Verified};
use crate::estimate::hypotheses::{turned_about, Source};
use crate::geometry::Pose;
use nalgebra::Vector3;

impl Estimator {
    /// Adds the winner of `verified` (sorted best first) turned by ±`nudge_degrees` about
    /// each object axis ([`nudges`]), refined and rendered; sorted best first again.
    pub(super) fn nudge(&self, ctx: &RefineContext<'_>, verified: &mut Vec<Verified>, window: (u32, u32, u32, u32), query: &QueryView, cfg: &EstimateConfig) -> Result<(), EstimateError> {
        let Some(winner) = verified.first() else { return Ok(()) };
        let candidates = nudges(&winner.pose, &Vector3::from(ctx.model.mesh.bbox_center()), cfg.verify.nudge_degrees);
        let mut more = self.refine_hypotheses(ctx, &candidates, cfg);
        let all: Vec<usize> = (0..more.len()).collect();
        self.judge(ctx, &mut more, &all, window, query, cfg)?;
        verified.extend(more);
        verified.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(())
    }
}

/// `pose` turned by +`degrees` and −`degrees` about each object axis through `centre`:
/// `Nudge(2·axis)` one way, `Nudge(2·axis + 1)` the other.
fn nudges(pose: &Pose, centre: &Vector3<f64>, degrees: f64) -> Vec<(Source, Pose)> {
    (0..6).map(|i| (Source::Nudge(i), turned_about(pose, centre, i / 2, if i % 2 == 0 { degrees } else { -degrees }))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn nudges_turn_each_way_about_each_axis_and_keep_the_centre() {
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.01, 0.02, 0.5));
        let centre = Vector3::new(0.01, -0.02, 0.03);
        let n = nudges(&pose, &centre, 8.0);
        assert_eq!(n.len(), 6);
        for (i, (s, p)) in n.iter().enumerate() {
            assert_eq!(*s, Source::Nudge(i));
            assert!(((p.rotation * centre + p.translation) - (pose.rotation * centre + pose.translation)).norm() < 1e-12);
            let turn = pose.rotation.inverse() * p.rotation;
            assert!((turn.angle().to_degrees() - 8.0).abs() < 1e-9, "{s}");
            // About the object axis the index names, the sign alternating.
            let axis = turn.axis().expect("a turn of 8°").into_inner();
            assert!((axis[i / 2].abs() - 1.0).abs() < 1e-9 && (axis[i / 2] > 0.0) == (i % 2 == 0), "{s}: {axis:?}");
        }
        assert_eq!(n[5].0.to_string(), "nudge-5");
    }
}
