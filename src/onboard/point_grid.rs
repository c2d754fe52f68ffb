//! Object-frame points stored as 16-bit steps of a grid spanning their bounding box: 6
//! bytes a point instead of 12. The step is the box's side over 65 535, so a point moves by
//! at most half a step (1.2 µm on a 15 cm object, 15 µm on a 2 m one): far below what a
//! patch centre or a contour sample can be placed to, so estimates do not change.

/// Where grid step 0 lies and how far one step goes, per axis (metres). Stored as its
/// bytes: two rows of three f32, origin then step.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct PointGrid {
    pub origin: [f32; 3],
    pub step: [f32; 3],
}

const STEPS: f32 = u16::MAX as f32;

impl PointGrid {
    /// The grid over the bounding box of `points` (an empty or flat side gets step 0).
    pub fn covering(points: &[[f32; 3]]) -> Self {
        if points.is_empty() {
            return Self { origin: [0.0; 3], step: [0.0; 3] };
        }
        let (lo, hi) = crate::mesh::bounding_box(points);
        Self::spanning(lo, hi)
    }

    /// The grid from corner `lo` to corner `hi`.
    pub fn spanning(lo: [f32; 3], hi: [f32; 3]) -> Self {
        Self { origin: lo, step: [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0.0) / STEPS) }
    }

    /// A grid over the box `lo`–`hi` grown by `margin` of its longest side on every side:
    /// made again from the same box (a mesh's, stored exactly), it is the same grid, so
    /// points already on it are stored and loaded without change.
    pub fn around_box(lo: [f32; 3], hi: [f32; 3], margin: f32) -> Self {
        let m = margin * (0..3).map(|a| hi[a] - lo[a]).fold(0.0f32, f32::max);
        Self::spanning(lo.map(|v| v - m), hi.map(|v| v + m))
    }

    /// `p` moved to the nearest grid point (what storing it keeps).
    pub fn snap(&self, p: [f32; 3]) -> [f32; 3] {
        self.decode(self.encode(p))
    }

    pub fn encode(&self, p: [f32; 3]) -> [u16; 3] {
        [0, 1, 2].map(|a| if self.step[a] > 0.0 { ((p[a] - self.origin[a]) / self.step[a]).round().clamp(0.0, STEPS) as u16 } else { 0 })
    }

    pub fn decode(&self, q: [u16; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| self.origin[a] + q[a] as f32 * self.step[a])
    }

    /// The grid two stored rows describe; refused when a value is not finite or a step is
    /// negative (a damaged file must not place points at infinity).
    pub fn from_rows(rows: &[[f32; 3]]) -> Result<Self, String> {
        let [origin, step] = rows else {
            return Err(format!("a point grid is 2 rows (origin, step), not {}", rows.len()));
        };
        if origin.iter().chain(step).any(|v| !v.is_finite()) || step.iter().any(|&s| s < 0.0) {
            return Err(format!("point grid origin {origin:?} step {step:?} is not finite and non-negative"));
        }
        Ok(Self { origin: *origin, step: *step })
    }
}

/// A unit vector as three signed 16-bit values (components × 32 767): within 2·10⁻⁵ of
/// each component.
pub fn unit_to_i16(v: [f32; 3]) -> [i16; 3] {
    v.map(|x| (x.clamp(-1.0, 1.0) * 32767.0).round() as i16)
}

pub fn i16_to_unit(q: [i16; 3]) -> [f32; 3] {
    q.map(|x| x as f32 / 32767.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_come_back_within_half_a_step() {
        let points: Vec<[f32; 3]> = (0..500)
            .map(|i| {
                let t = i as f32 * 0.37;
                [0.08 * t.sin() - 0.01, 0.05 * (1.3 * t).cos(), 0.002]
            })
            .collect();
        let grid = PointGrid::covering(&points);
        assert_eq!(grid.step[2], 0.0, "a flat side has no steps");
        for p in &points {
            let back = grid.decode(grid.encode(*p));
            for a in 0..3 {
                assert!((back[a] - p[a]).abs() <= grid.step[a] * 0.5 + 1e-7, "{p:?} → {back:?}");
            }
        }
        // The box's corners are grid points: nothing is clamped away.
        let hi = [0, 1, 2].map(|a| points.iter().map(|p| p[a]).fold(f32::MIN, f32::max));
        assert_eq!(grid.encode(hi), [u16::MAX, u16::MAX, 0]);
        assert_eq!(PointGrid::from_rows(bytemuck::cast_slice(bytemuck::bytes_of(&grid))).unwrap(), grid);
        assert_eq!(PointGrid::covering(&[]).decode([7, 7, 7]), [0.0; 3]);
    }

    #[test]
    fn snapped_points_and_unit_vectors_store_without_change() {
        let grid = PointGrid::around_box([-0.05, -0.02, 0.0], [0.05, 0.03, 0.1], 0.02);
        assert_eq!(grid, PointGrid::around_box([-0.05, -0.02, 0.0], [0.05, 0.03, 0.1], 0.02), "the same box gives the same grid");
        // A point a little outside the box (a rim sample's depth error) is not clamped.
        let p = [0.0507, -0.0201, 0.0999];
        let s = grid.snap(p);
        assert!((0..3).all(|a| (s[a] - p[a]).abs() <= grid.step[a] * 0.5 + 1e-7), "{p:?} → {s:?}");
        assert_eq!(grid.snap(s), s, "snapping again keeps the point");
        let n = [0.6, -0.8, 0.0];
        let q = unit_to_i16(n);
        let back = i16_to_unit(q);
        assert!((0..3).all(|a| (back[a] - n[a]).abs() < 2e-5), "{back:?}");
        assert_eq!(unit_to_i16(back), q, "a stored vector stores the same again");
    }

    #[test]
    fn damaged_grids_are_refused() {
        assert!(PointGrid::from_rows(&[[0.0; 3]]).unwrap_err().contains("2 rows"));
        assert!(PointGrid::from_rows(&[[0.0; 3], [f32::NAN, 0.0, 0.0]]).is_err());
        assert!(PointGrid::from_rows(&[[0.0; 3], [-1e-6, 0.0, 0.0]]).is_err());
        assert!(PointGrid::from_rows(&[[f32::INFINITY, 0.0, 0.0], [0.0; 3]]).is_err());
    }
}
