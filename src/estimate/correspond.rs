//! 2D–3D correspondences: a pool of patches with 3D object points (from retrieved templates
//! or from RRC renders), matched against the query's foreground patches.

use super::matching::mutual_matches;
use super::query::QueryView;
use crate::onboard::ObjectModel;

/// Patch descriptors (`len × dim`, L2-normalised) with the object point behind each.
#[derive(Default)]
pub struct PatchPool {
    pub dim: usize,
    pub descriptors: Vec<f32>,
    pub points: Vec<[f32; 3]>,
    /// Per patch, the template it comes from and its cell in that template's crop grid
    /// (for pools built from templates; empty for RRC's renders).
    pub origins: Vec<(u32, u16)>,
}

impl PatchPool {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// All patches of the given templates of `model` (descriptors widened or decoded to f32).
    pub fn from_templates(model: &ObjectModel, templates: impl IntoIterator<Item = usize>) -> Self {
        let mut pool = PatchPool { dim: model.local_dim, ..Default::default() };
        for t in templates {
            let tp = &model.templates[t];
            let range = tp.patch_start as usize..(tp.patch_start + tp.patch_count) as usize;
            model.patch_points.extend_range(range.clone(), &mut pool.points);
            model.patch_descriptors.widen_into(model.local_dim, range.clone(), &mut pool.descriptors);
            pool.origins.extend(model.patch_cells[range].iter().map(|&cell| (t as u32, cell)));
        }
        pool
    }
}

/// Matched pairs ready for PnP.
#[derive(Default, Clone)]
pub struct Correspondences {
    /// Query patch centres in image pixels.
    pub image_points: Vec<[f64; 2]>,
    /// Object points in metres.
    pub object_points: Vec<[f64; 3]>,
    pub similarities: Vec<f32>,
    /// The pool patch of each pair.
    pub pool_index: Vec<usize>,
}

impl Correspondences {
    pub fn len(&self) -> usize {
        self.image_points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.image_points.is_empty()
    }

    /// Adds the pair of image pixel `uv` and object point `p` (pool patch `pool`).
    pub fn push(&mut self, uv: (f64, f64), p: [f32; 3], similarity: f32, pool: usize) {
        self.image_points.push([uv.0, uv.1]);
        self.object_points.push([p[0] as f64, p[1] as f64, p[2] as f64]);
        self.similarities.push(similarity);
        self.pool_index.push(pool);
    }
}

/// Mutual nearest neighbours (each query patch's `k_nn` best) between query and pool.
pub fn correspond(query: &QueryView, descriptors: &[f32], pool: &PatchPool, k_nn: usize) -> Correspondences {
    let mut c = Correspondences::default();
    if pool.dim == 0 || descriptors.len() != query.foreground.len() * pool.dim {
        return c;
    }
    for m in mutual_matches(descriptors, &pool.descriptors, pool.dim, k_nn) {
        c.push(query.patch_centre(m.query), pool.points[m.pool], m.similarity, m.pool);
    }
    c
}
