//! Verification's nudge: the winner tilted a little each way, refined and judged.
//!
//! A small object's outline hardly changes under a tilt of a few degrees out of the image
//! plane, so the refiner can settle a pose tilted 5–10° off with its depth pulled a few
//! per cent to fit the outline, and nothing among the flips, spins and templates lies
//! nearer. The same pose tilted a little about the two axes across the line of sight
//! starts the refiner in the right pose's basin, and the render (IoU, print, features)
//! tells which way is right. Turns about the line of sight itself turn the outline in the
//! image, which the refiner fits well already.

use super::{EstimateConfig, EstimateError, Estimator, QueryView, RefineContext, Verified};
use crate::estimate::hypotheses::Source;
use crate::geometry::{geodesic_distance, Pose};
use nalgebra::{Unit, Vector3};

/// A nudge the refiner brings back within this of the winner (rotation, degrees; and a
/// hundredth of the diameter in translation) shows the winner's image again: it is not
/// rendered, and stays among the hypotheses with its outline's score alone (which ranks
/// below every rendered one).
const SAME_POSE_DEGREES: f64 = 1.0;

impl Estimator {
    /// Adds the winner of `verified` (sorted best first) tilted by ±`nudge_degrees` about
    /// the two axes across its line of sight ([`nudges`]), refined, and rendered where the
    /// refiner did not bring them back to the winner ([`same_pose`]); sorted best first
    /// again.
    pub(super) fn nudge(&self, ctx: &RefineContext<'_>, verified: &mut Vec<Verified>, window: (u32, u32, u32, u32), query: &QueryView, cfg: &EstimateConfig) -> Result<(), EstimateError> {
        let Some(winner) = verified.first() else { return Ok(()) };
        let candidates = nudges(&winner.pose, &Vector3::from(ctx.model.mesh.bbox_center()), cfg.verify.nudge_degrees);
        let mut more = self.refine_hypotheses(ctx, &candidates, cfg);
        let fresh = to_judge(&more, winner, ctx.model.diameter(), cfg.verify.contour_tie);
        self.judge(ctx, &mut more, &fresh, window, query, cfg)?;
        verified.extend(more);
        verified.sort_by(|a, b| b.score.total_cmp(&a.score));
        Ok(())
    }
}

/// `pose` tilted by +`degrees` and −`degrees` about the two axes across the line of sight
/// through `centre` (the object's, in its own frame): `Nudge(0)`, `Nudge(1)` about the
/// one nearest the camera's x axis, `Nudge(2)`, `Nudge(3)` about the other.
fn nudges(pose: &Pose, centre: &Vector3<f64>, degrees: f64) -> Vec<(Source, Pose)> {
    let sight = pose.rotation * centre + pose.translation;
    let Some(sight) = Unit::try_new(sight, 1e-12) else { return vec![] };
    // Across the line of sight: the camera's x axis with its part along the sight removed,
    // and the axis across both. An object straight ahead is tilted about x and y; one on
    // the camera's y axis itself (a pose no camera sees) about z and x.
    let across = Unit::try_new(Vector3::y().cross(&sight), 1e-9).unwrap_or_else(|| Unit::new_normalize(sight.cross(&Vector3::x())));
    let axes = [across, Unit::new_normalize(sight.cross(&across))];
    (0..4)
        .map(|i| {
            let angle = if i % 2 == 0 { degrees } else { -degrees }.to_radians();
            (Source::Nudge(i), pose.turned_in_camera(centre, &axes[i / 2], angle))
        })
        .collect()
}

/// Which refined nudges to render and judge: those the refiner did not bring back to the
/// winner ([`same_pose`]) and whose outline agrees with the mask within `contour_tie` of
/// the winner's, as verification renders its ties (`verify::to_render`). Leaving the
/// others unrendered changed no answer on 1 020 generated rows and the 70 real-frame
/// instances (docs/benchmarks/estimation-occlusion-and-speed.md, "Nudges judged only where
/// their outline ties"), and each of their renders costs as much as any other.
fn to_judge(nudged: &[Verified], winner: &Verified, diameter: f64, contour_tie: f64) -> Vec<usize> {
    let tie = winner.contour - contour_tie;
    (0..nudged.len()).filter(|&i| !same_pose(&nudged[i].pose, &winner.pose, diameter) && nudged[i].contour >= tie).collect()
}

/// Whether `a` and `b` are the same pose within [`SAME_POSE_DEGREES`] and a hundredth of
/// `diameter`.
fn same_pose(a: &Pose, b: &Pose, diameter: f64) -> bool {
    geodesic_distance(&a.rotation, &b.rotation).to_degrees() < SAME_POSE_DEGREES && (a.translation - b.translation).norm() < 0.01 * diameter
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn nudges_tilt_each_way_across_the_line_of_sight_and_keep_the_centre() {
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.05, 0.02, 0.5));
        let centre = Vector3::new(0.01, -0.02, 0.03);
        let at = pose.rotation * centre + pose.translation;
        let n = nudges(&pose, &centre, 8.0);
        assert_eq!(n.len(), 4);
        let mut axes = vec![];
        for (i, (s, p)) in n.iter().enumerate() {
            assert_eq!(*s, Source::Nudge(i));
            assert!(((p.rotation * centre + p.translation) - at).norm() < 1e-12, "{s} moved the centre");
            // In the camera's frame: a turn of 8° about an axis across the line of sight.
            let turn = p.rotation * pose.rotation.inverse();
            assert!((turn.angle().to_degrees() - 8.0).abs() < 1e-9, "{s}");
            let axis = turn.axis().expect("a turn of 8°").into_inner();
            assert!(axis.dot(&at.normalize()).abs() < 1e-9, "{s}: {axis:?} not across the sight");
            axes.push(axis);
        }
        // The two ways about one axis, and two axes at right angles.
        assert!((axes[0] + axes[1]).norm() < 1e-9 && (axes[2] + axes[3]).norm() < 1e-9);
        assert!(axes[0].dot(&axes[2]).abs() < 1e-9);
        assert!(axes[0].x.abs() > 0.9, "the first axis is nearest the camera's x: {:?}", axes[0]);
        assert_eq!(n[3].0.to_string(), "nudge-3");
        // Along the camera's y axis: still four tilts of 8°, none of them NaN.
        let above = Pose::new(Rotation3::identity(), Vector3::new(0.0, 0.5, 0.0));
        let n = nudges(&above, &Vector3::zeros(), 8.0);
        assert!(n.len() == 4 && n.iter().all(|(_, p)| ((p.rotation * above.rotation.inverse()).angle().to_degrees() - 8.0).abs() < 1e-9));
    }

    #[test]
    fn only_nudges_that_moved_and_tie_the_winners_outline_are_judged() {
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.05, 0.02, 0.5));
        let tilted = Pose::new(pose.rotation * Rotation3::from_euler_angles(0.1, 0.0, 0.0), pose.translation);
        let at = |p: Pose, contour: f64| Verified::unscored(Source::Nudge(0), p, Default::default(), contour);
        let winner = at(pose, 0.8);
        // Back at the winner; moved and tying; moved, a little better; moved, fitting worse.
        let nudged = [at(pose, 0.8), at(tilted, 0.76), at(tilted, 0.85), at(tilted, 0.7)];
        assert_eq!(to_judge(&nudged, &winner, 0.1, 0.05), [1, 2]);
        assert_eq!(to_judge(&nudged, &winner, 0.1, 0.2), [1, 2, 3]);
    }

    #[test]
    fn a_nudge_brought_back_is_the_same_pose() {
        let pose = Pose::new(Rotation3::from_euler_angles(0.3, -0.2, 1.0), Vector3::new(0.05, 0.02, 0.5));
        let turned = |deg: f64| Pose::new(pose.rotation * Rotation3::from_euler_angles(deg.to_radians(), 0.0, 0.0), pose.translation);
        assert!(same_pose(&turned(0.5), &pose, 0.1));
        assert!(!same_pose(&turned(2.0), &pose, 0.1), "turned");
        let moved = Pose::new(pose.rotation, pose.translation + Vector3::new(0.0, 0.0, 0.002));
        assert!(!same_pose(&moved, &pose, 0.1), "2 mm off an object of 100 mm");
        assert!(same_pose(&moved, &pose, 0.3), "2 mm off an object of 300 mm");
    }
}
