//! The object point behind each template patch: f32 rows (objects before format 7), or
//! 16-bit steps of a grid over their bounding box (point_grid.rs; every object onboarded
//! since). Matching reads them only through `extend_range`, a few templates at a time,
//! like the descriptors.

use super::point_grid::PointGrid;
use super::stored_rows::StoredRows;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq)]
pub enum PatchPoints {
    Exact(StoredRows<[f32; 3]>),
    Grid { grid: PointGrid, steps: StoredRows<[u16; 3]> },
}

impl Default for PatchPoints {
    fn default() -> Self {
        PatchPoints::Exact(Vec::new().into())
    }
}

impl PatchPoints {
    pub fn len(&self) -> usize {
        match self {
            PatchPoints::Exact(p) => p.len(),
            PatchPoints::Grid { steps, .. } => steps.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn is_grid(&self) -> bool {
        matches!(self, PatchPoints::Grid { .. })
    }

    /// Whether the rows are read in place from a mapped file (see `StoredRows`).
    pub fn is_mapped(&self) -> bool {
        match self {
            PatchPoints::Exact(p) => p.is_mapped(),
            PatchPoints::Grid { steps, .. } => steps.is_mapped(),
        }
    }

    /// The point of patch `i` (metres, object frame); `i` must be below `len()`.
    pub fn point(&self, i: usize) -> [f32; 3] {
        match self {
            PatchPoints::Exact(p) => p[i],
            PatchPoints::Grid { grid, steps } => grid.decode(steps[i]),
        }
    }

    /// Appends the points of `patches` (metres, object frame).
    pub fn extend_range(&self, patches: Range<usize>, out: &mut Vec<[f32; 3]>) {
        match self {
            PatchPoints::Exact(p) => out.extend_from_slice(&p[patches]),
            PatchPoints::Grid { grid, steps } => out.extend(steps[patches].iter().map(|&q| grid.decode(q))),
        }
    }

    /// Heap bytes held (mapped rows: none).
    pub fn heap_bytes(&self) -> usize {
        match self {
            PatchPoints::Exact(p) => p.heap_bytes(),
            PatchPoints::Grid { steps, .. } => steps.heap_bytes(),
        }
    }

    /// Only the points of the patches in `rows`, in that order, coded as they are.
    pub fn gather(&self, rows: &[Range<usize>]) -> Self {
        match self {
            PatchPoints::Exact(p) => PatchPoints::Exact(p.gather(rows, 1)),
            PatchPoints::Grid { grid, steps } => PatchPoints::Grid { grid: *grid, steps: steps.gather(rows, 1) },
        }
    }

    /// Replaces f32 rows by grid steps over their bounding box (a no-op when they are).
    pub fn to_grid(&mut self) {
        if let PatchPoints::Exact(p) = self {
            let grid = PointGrid::covering(p);
            let steps: Vec<[u16; 3]> = p.iter().map(|&x| grid.encode(x)).collect();
            *self = PatchPoints::Grid { grid, steps: steps.into() };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_steps_hand_out_the_points_of_the_asked_patches() {
        let exact: Vec<[f32; 3]> = (0..50).map(|i| [i as f32 * 0.002 - 0.04, (i % 7) as f32 * 0.01, -0.03]).collect();
        let mut points = PatchPoints::Exact(exact.clone().into());
        let mut out = vec![[9.0; 3]];
        points.extend_range(10..12, &mut out);
        assert_eq!(out, vec![[9.0; 3], exact[10], exact[11]]);
        points.to_grid();
        assert!(points.is_grid() && points.len() == 50 && points.heap_bytes() == 50 * 6);
        let mut back = Vec::new();
        points.extend_range(0..50, &mut back);
        let worst = back.iter().zip(&exact).flat_map(|(b, e)| (0..3).map(move |a| (b[a] - e[a]).abs())).fold(0.0, f32::max);
        // 0.098 m across 65 535 steps: half a step is 0.75 µm.
        assert!(worst < 1e-6, "{worst} m");
        let before = points.clone();
        points.to_grid();
        assert_eq!(points, before, "grid steps stay as they are");
    }
}
