//! Which correspondence lines see the object's own outline and which an occluder's.
//!
//! A mask of a partly hidden object is its silhouette minus whatever is in front, so its
//! outline is the object's where the object is visible and an occluder's elsewhere. An
//! occluder's edge can only lie *inside* the model's projected outline: a line whose mask
//! edge is outside the model's (residual > 0) always tells the truth about the pose, one
//! whose mask edge is inside may be cut by something in front. So each line's residual is
//! explained by a mixture: the object's own edge, normal about zero with the pose error's
//! spread plus the line's own variance; or an occluder's edge, anywhere between the model's
//! outline and as far inside as the line reaches (uniform, inside only). EM estimates the
//! share of visible lines, the spread and, per line, the probability that its edge is the
//! object's: the refiner weighs each line by it, so depth and position follow the visible
//! outline instead of being pulled onto the occluder's. A uniform error in depth moves every
//! line alike by a few pixels, which the normal explains better than the wide uniform, so
//! the lines of an unoccluded object keep their weight.

/// One line's measurement as the mixture sees it.
#[derive(Clone, Copy, Debug)]
pub struct LineResidual {
    /// The mask's outline minus the model's along the outward normal, px (< 0: the mask
    /// ends inside the model's outline).
    pub residual: f64,
    /// The line's own offset variance, px².
    pub variance: f64,
    /// How far inside the model's outline the line reaches, px: the range an occluder's
    /// edge seen by this line can lie in.
    pub inside_px: f64,
}

/// What EM found.
#[derive(Clone, Debug)]
pub struct Visibility {
    /// Per line, the probability that its edge is the object's own.
    pub own_edge: Vec<f64>,
    /// Standard deviation of the own edges' residuals beyond their own variance (the pose
    /// error's spread), px.
    pub spread_px: f64,
}

const ITERATIONS: usize = 12;
/// The visible share never drops below this: a pose whose lines all look occluded is
/// better judged wrong by the refiner's agreement check than explained away.
const MIN_VISIBLE_SHARE: f64 = 0.2;

/// Runs EM over the lines' residuals. `floor_px` bounds the spread from below (the
/// segment length at the line scale: no pose is placed more finely than that).
pub fn visibility(lines: &[LineResidual], floor_px: f64) -> Visibility {
    let n = lines.len();
    if n == 0 {
        return Visibility { own_edge: Vec::new(), spread_px: floor_px };
    }
    // Start from the lines outside the model's outline (never occluded): their residuals
    // are the pose error alone. With none, from all lines.
    let outside: Vec<f64> = lines.iter().filter(|l| l.residual >= 0.0).map(|l| l.residual).collect();
    let start = if outside.len() >= 3 { outside } else { lines.iter().map(|l| l.residual.abs()).collect() };
    let mut spread2 = (1.4826 * median(start)).max(floor_px).powi(2);
    let mut share: f64 = 0.7;
    let mut own = vec![1.0; n];
    for _ in 0..ITERATIONS {
        for (p, l) in own.iter_mut().zip(lines) {
            *p = own_edge_probability(l, spread2, share);
        }
        let total: f64 = own.iter().sum();
        share = (total / n as f64).clamp(MIN_VISIBLE_SHARE, 1.0);
        let weighted: f64 = own.iter().zip(lines).map(|(p, l)| p * l.residual * l.residual).sum();
        spread2 = (weighted / total.max(1e-9)).max(floor_px * floor_px);
    }
    Visibility { own_edge: own, spread_px: spread2.sqrt() }
}

impl Visibility {
    /// The expected number of lines that see the object's own edge.
    pub fn own_edges(&self) -> f64 {
        self.own_edge.iter().sum()
    }

    /// The share of own edges among the lines (1 without lines).
    pub fn visible_share(&self) -> f64 {
        if self.own_edge.is_empty() {
            1.0
        } else {
            self.own_edges() / self.own_edge.len() as f64
        }
    }
}

/// Posterior that line `l`'s edge is the object's, given the spread² and visible share.
fn own_edge_probability(l: &LineResidual, spread2: f64, share: f64) -> f64 {
    if l.residual >= 0.0 || l.inside_px <= 0.0 || -l.residual > l.inside_px {
        return 1.0;
    }
    let var = spread2 + l.variance;
    let own = share * (-0.5 * l.residual * l.residual / var).exp() / (std::f64::consts::TAU * var).sqrt();
    let occluded = (1.0 - share) / l.inside_px;
    own / (own + occluded)
}

pub(super) fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(residual: f64) -> LineResidual {
        LineResidual { residual, variance: 1.0, inside_px: 60.0 }
    }

    /// Half the outline cut by an occluder 25 px inside: those lines lose their weight,
    /// the rest keep it, and the visible share is about a half.
    #[test]
    fn an_occluders_edge_is_told_from_the_objects() {
        let mut lines: Vec<LineResidual> = (0..40).map(|i| line(((i as f64) * 0.7).sin() * 1.5)).collect();
        lines.extend((0..40).map(|i| line(-25.0 + ((i as f64) * 1.3).cos() * 8.0)));
        let v = visibility(&lines, 1.0);
        assert!(v.own_edge[..40].iter().all(|&p| p > 0.9), "{:?}", &v.own_edge[..40]);
        assert!(v.own_edge[40..].iter().all(|&p| p < 0.05), "{:?}", &v.own_edge[40..]);
        assert!((v.visible_share() - 0.5).abs() < 0.05, "visible share {}", v.visible_share());
        assert!(v.spread_px < 3.0, "spread {}", v.spread_px);
    }

    /// A pose too close shrinks every line alike: nothing there looks occluded.
    #[test]
    fn a_uniform_shrink_is_not_occlusion() {
        let lines: Vec<LineResidual> = (0..60).map(|i| line(-4.0 + ((i as f64) * 0.9).sin())).collect();
        let v = visibility(&lines, 1.0);
        assert!(v.own_edge.iter().all(|&p| p > 0.8), "{:?}", v.own_edge);
        assert!(v.visible_share() > 0.9);
    }

    /// A shifted pose: residuals of both signs in proportion, all the object's own.
    #[test]
    fn a_shift_is_not_occlusion() {
        let lines: Vec<LineResidual> = (0..72).map(|i| line(6.0 * (i as f64 * 5f64.to_radians()).cos())).collect();
        let v = visibility(&lines, 1.0);
        assert!(v.visible_share() > 0.9, "visible share {}", v.visible_share());
    }

    /// Edges outside the model's outline, or beyond what the line reaches inside, are
    /// never taken for an occluder's.
    #[test]
    fn edges_outside_are_always_the_objects() {
        let l = LineResidual { residual: 30.0, variance: 1.0, inside_px: 20.0 };
        assert_eq!(own_edge_probability(&l, 1.0, 0.3), 1.0);
        let deep = LineResidual { residual: -30.0, ..l };
        assert_eq!(own_edge_probability(&deep, 1.0, 0.3), 1.0);
        assert!(visibility(&[], 1.0).visible_share() == 1.0);
    }
}
