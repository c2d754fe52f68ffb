//! Levenberg–Marquardt on the pixel reprojection error of a set of matches, over the six
//! pose parameters, analytic Jacobian, optional Huber loss (by reweighting).
//!
//! Parameterisation: `p = exp(ω)·R·(X − c) + m`, with `c` the centroid of the object points
//! and `m` its camera-frame position. Rotating about the object rather than the camera keeps
//! rotation and translation nearly decoupled, so the damped steps behave at any distance.

use nalgebra::{Matrix6, Rotation3, Vector3, Vector6};

use super::matches::Matches;
use crate::geometry::Pose;

#[derive(Clone, Copy, Debug)]
pub(crate) struct LmOptions {
    pub(crate) max_iterations: usize,
    /// Huber threshold in pixels; `None` is plain least squares.
    pub(crate) huber_px: Option<f64>,
}

/// Damping bounds: below, plain Gauss–Newton; above, the step is nothing and we stop.
const DAMPING_MIN: f64 = 1e-12;
const DAMPING_MAX: f64 = 1e8;
/// Relative cost decrease below which another iteration is not worth its cost.
const CONVERGED: f64 = 1e-12;

#[derive(Clone, Copy)]
struct State {
    rotation: Rotation3<f64>,
    centre_cam: Vector3<f64>,
}

/// Refined pose, never worse than `init` on the chosen loss (it is returned as is when no
/// step improves, or when fewer than three matches are given).
pub(crate) fn levenberg_marquardt(m: &Matches, idx: &[usize], init: &Pose, opt: &LmOptions) -> Pose {
    if idx.len() < 3 {
        return *init;
    }
    let centroid = idx.iter().map(|&i| m.point(i)).sum::<Vector3<f64>>() / idx.len() as f64;
    let mut state = State { rotation: init.rotation, centre_cam: init.rotation * centroid + init.translation };
    let problem = Problem { m, idx, centroid, huber: opt.huber_px };
    let Some(mut cost) = problem.cost(&state) else { return *init };
    let mut damping = 1e-4;
    for _ in 0..opt.max_iterations {
        if cost <= 0.0 {
            break;
        }
        let Some((h, g)) = problem.normal_equations(&state) else { break };
        let mut improved = None;
        while damping <= DAMPING_MAX {
            if let Some(step) = damped_step(&h, &g, damping) {
                let trial = State { rotation: Rotation3::new(step.fixed_rows::<3>(0).into_owned()) * state.rotation, centre_cam: state.centre_cam + step.fixed_rows::<3>(3) };
                if let Some(c) = problem.cost(&trial).filter(|&c| c < cost) {
                    improved = Some((trial, c));
                    damping = (damping * 0.1).max(DAMPING_MIN);
                    break;
                }
            }
            damping *= 10.0;
        }
        let Some((next, next_cost)) = improved else { break };
        let gain = (cost - next_cost) / cost;
        state = next;
        cost = next_cost;
        if gain < CONVERGED {
            break;
        }
    }
    let mut rotation = state.rotation;
    rotation.renormalize();
    Pose::new(rotation, state.centre_cam - rotation * centroid)
}

/// Solves (H + μ·diag H)·δ = −g; `None` if not positive definite.
fn damped_step(h: &Matrix6<f64>, g: &Vector6<f64>, damping: f64) -> Option<Vector6<f64>> {
    let mut a = *h;
    // The floor keeps an unobservable direction (e.g. few, near-degenerate inliers) damped.
    let floor = 1e-12 * h.diagonal().max();
    for i in 0..6 {
        a[(i, i)] += damping * h[(i, i)].max(floor);
    }
    a.cholesky().map(|c| -c.solve(g))
}

struct Problem<'a, 'm> {
    m: &'a Matches<'m>,
    idx: &'a [usize],
    centroid: Vector3<f64>,
    huber: Option<f64>,
}

impl Problem<'_, '_> {
    /// Camera-frame point of match `i` with its lever arm `q = R·(X − c)`.
    fn camera_point(&self, s: &State, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let q = s.rotation * (self.m.point(i) - self.centroid);
        (q + s.centre_cam, q)
    }

    /// Pixel residual of match `i` at camera-frame point `p` (z > 0).
    fn residual(&self, i: usize, p: &Vector3<f64>) -> [f64; 2] {
        let [x, y] = self.m.normalised[i];
        [self.m.fx * (p.x / p.z - x), self.m.fy * (p.y / p.z - y)]
    }

    /// ρ(|r|): r² inside the Huber threshold, linear outside; `None` with a point behind the
    /// camera, so that no step is ever accepted into that region.
    fn cost(&self, s: &State) -> Option<f64> {
        let mut total = 0.0;
        for &i in self.idx {
            let (p, _) = self.camera_point(s, i);
            if p.z <= 0.0 {
                return None;
            }
            let [ru, rv] = self.residual(i, &p);
            let sq = ru * ru + rv * rv;
            total += match self.huber {
                Some(d) if sq > d * d => 2.0 * d * sq.sqrt() - d * d,
                _ => sq,
            };
        }
        Some(total)
    }

    /// Rows ∂r_u/∂(ω, m) and ∂r_v/∂(ω, m) at camera point `p` with lever arm `q`:
    /// ∂r/∂p · [∂p/∂ω = −[q]ₓ | ∂p/∂m = I].
    fn jacobian(&self, p: &Vector3<f64>, q: &Vector3<f64>) -> [Vector6<f64>; 2] {
        let iz = 1.0 / p.z;
        let (px, py) = (p.x * iz, p.y * iz);
        [Vector6::new(-px * q.y, q.z + px * q.x, -q.y, 1.0, 0.0, -px) * (self.m.fx * iz), Vector6::new(-q.z - py * q.y, py * q.x, q.x, 0.0, 1.0, -py) * (self.m.fy * iz)]
    }

    /// Gauss–Newton H = Σ wJᵀJ and g = Σ wJᵀr, with Huber's IRLS weights.
    fn normal_equations(&self, s: &State) -> Option<(Matrix6<f64>, Vector6<f64>)> {
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        for &i in self.idx {
            let (p, q) = self.camera_point(s, i);
            if p.z <= 0.0 {
                return None;
            }
            let [ru, rv] = self.residual(i, &p);
            let w = match self.huber {
                Some(d) => {
                    let norm = (ru * ru + rv * rv).sqrt();
                    if norm > d {
                        d / norm
                    } else {
                        1.0
                    }
                }
                None => 1.0,
            };
            let [ju, jv] = self.jacobian(&p, &q);
            h += (ju * ju.transpose() + jv * jv.transpose()) * w;
            g += (ju * ru + jv * rv) * w;
        }
        Some((h, g))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;

    /// The analytic Jacobian against central differences of the residuals.
    #[test]
    fn jacobian_matches_finite_differences() {
        let k = Intrinsics::new(600.0, 620.0, 320.0, 240.0, 640, 480).unwrap();
        let object = [[0.05, -0.02, 0.03]];
        let image = [[350.0, 200.0]];
        let m = Matches::new(&image, &object, &k, 4.0);
        let problem = Problem { m: &m, idx: &[0], centroid: Vector3::new(0.01, 0.02, -0.01), huber: None };
        let s = State { rotation: Rotation3::from_euler_angles(0.3, -0.2, 0.5), centre_cam: Vector3::new(0.05, -0.03, 0.6) };
        let (p, q) = problem.camera_point(&s, 0);
        let [ju, jv] = problem.jacobian(&p, &q);
        let eps = 1e-6;
        for j in 0..6 {
            let mut d = Vector6::zeros();
            d[j] = eps;
            let shift = |d: Vector6<f64>| {
                let t = State { rotation: Rotation3::new(d.fixed_rows::<3>(0).into_owned()) * s.rotation, centre_cam: s.centre_cam + d.fixed_rows::<3>(3) };
                problem.residual(0, &problem.camera_point(&t, 0).0)
            };
            let (plus, minus) = (shift(d), shift(-d));
            for (r, analytic) in [(0, ju[j]), (1, jv[j])] {
                let numeric = (plus[r] - minus[r]) / (2.0 * eps);
                assert!((numeric - analytic).abs() < 1e-5 * analytic.abs().max(1.0), "d r{r}/d x{j}");
            }
        }
    }
}
