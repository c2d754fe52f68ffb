//! A turn of the image plane about a point: how onboarding makes its in-plane templates from
//! one render, and how estimation turns a query to meet the templates that share rows.

/// `p ↦ centre + R(angle)·(p − centre)` in pixel coordinates (y down, so a positive angle
/// turns clockwise on screen).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Turn {
    pub angle: f64,
    pub centre: [f64; 2],
    /// The angle's sine and cosine, once: crops call `apply` for every sample.
    sin_cos: (f64, f64),
}

impl Turn {
    pub fn new(angle: f64, centre: [f64; 2]) -> Self {
        Self { angle, centre, sin_cos: angle.sin_cos() }
    }

    pub fn apply(&self, u: f64, v: f64) -> (f64, f64) {
        let (s, c) = self.sin_cos;
        let (x, y) = (u - self.centre[0], v - self.centre[1]);
        (self.centre[0] + c * x - s * y, self.centre[1] + s * x + c * y)
    }

    /// The turn back.
    pub fn inverse(&self) -> Turn {
        Turn::new(-self.angle, self.centre)
    }

    /// Left, top, right and bottom of `points` once turned; `None` for no points.
    pub fn extents(&self, points: impl IntoIterator<Item = (f64, f64)>) -> Option<[f64; 4]> {
        let mut e = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for (u, v) in points {
            let (x, y) = self.apply(u, v);
            e = [e[0].min(x), e[1].min(y), e[2].max(x), e[3].max(y)];
        }
        e[0].is_finite().then_some(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quarter_turn_about_a_point_and_back() {
        let t = Turn::new(std::f64::consts::FRAC_PI_2, [10.0, 20.0]);
        let (u, v) = t.apply(12.0, 20.0);
        assert!((u - 10.0).abs() < 1e-12 && (v - 22.0).abs() < 1e-12, "({u}, {v})");
        let (u, v) = t.inverse().apply(u, v);
        assert!((u - 12.0).abs() < 1e-12 && (v - 20.0).abs() < 1e-12);
        assert_eq!(t.apply(10.0, 20.0), (10.0, 20.0));
        let e = t.extents([(12.0, 20.0), (10.0, 17.0)]).unwrap();
        for (got, want) in e.iter().zip([10.0, 20.0, 13.0, 22.0]) {
            assert!((got - want).abs() < 1e-12, "{e:?}");
        }
        assert!(t.extents(std::iter::empty()).is_none());
    }
}
