//! Optional PCA compression of patch descriptors, fitted at onboarding on the object's own
//! template patches (as FoundPose does for DINOv2 features) and recorded in the model, so
//! queries are projected the same way before matching. Rows are re-normalised after the
//! projection because matching compares by cosine.

use half::f16;
use nalgebra::{DMatrix, SymmetricEigen};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pca {
    pub input_dim: usize,
    pub output_dim: usize,
    pub mean: Vec<f32>,
    /// `output_dim × input_dim`, row-major: the leading eigenvectors of the covariance.
    pub components: Vec<f32>,
}

/// Rows used for the fit at most (evenly strided): the covariance is settled long before the
/// hundreds of thousands of patches an object has.
const MAX_FIT_ROWS: usize = 50_000;

/// Rows centred and multiplied at once: bounds the f32 scratch (rows × input dims).
const CHUNK_ROWS: usize = 4096;

impl Pca {
    /// Fits on `rows` (`n × dim`, row-major, f32 or f16) keeping `k` components.
    pub fn fit<T: Copy + Into<f32>>(rows: &[T], dim: usize, k: usize) -> Result<Self, String> {
        if dim == 0 || !rows.len().is_multiple_of(dim) {
            return Err(format!("PCA: {} values are not rows of {dim}", rows.len()));
        }
        let n = rows.len() / dim;
        if k == 0 || k > dim {
            return Err(format!("PCA: cannot keep {k} of {dim} dimensions"));
        }
        if n < 2 {
            return Err("PCA: needs at least 2 descriptors".into());
        }
        let stride = n.div_ceil(MAX_FIT_ROWS);
        let picked: Vec<&[T]> = rows.chunks_exact(dim).step_by(stride).collect();
        let mut mean = vec![0f64; dim];
        for r in &picked {
            for (m, &v) in mean.iter_mut().zip(r.iter()) {
                *m += v.into() as f64;
            }
        }
        mean.iter_mut().for_each(|m| *m /= picked.len() as f64);
        let mean: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
        // Scatter matrix of the centred rows by GEMM, a chunk at a time (the mean removed
        // first, so f32 accumulation loses nothing that matters to the leading components).
        let mut scatter = vec![0f32; dim * dim];
        let mut centred = Vec::with_capacity(CHUNK_ROWS * dim);
        for chunk in picked.chunks(CHUNK_ROWS) {
            centred.clear();
            centred.extend(chunk.iter().flat_map(|r| r.iter().zip(&mean).map(|(&v, m)| v.into() - m)));
            crate::linalg::add_gram(&centred, chunk.len(), dim, &mut scatter);
        }
        let cov = DMatrix::<f64>::from_fn(dim, dim, |i, j| 0.5 * (scatter[i * dim + j] as f64 + scatter[j * dim + i] as f64));
        let eig = SymmetricEigen::new(cov);
        let mut order: Vec<usize> = (0..dim).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let components = order[..k].iter().flat_map(|&c| eig.eigenvectors.column(c).iter().map(|&v| v as f32).collect::<Vec<_>>()).collect();
        Ok(Self { input_dim: dim, output_dim: k, mean, components })
    }

    /// Projects `rows` (`n × input_dim`) to `n × output_dim`, each row L2-normalised.
    pub fn project(&self, rows: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(rows.len() / self.input_dim * self.output_dim);
        self.project_chunks(rows, |projected| out.extend_from_slice(projected));
        out
    }

    /// `project` for stored f16 descriptors, to f16, without widening all rows at once.
    pub fn project_f16(&self, rows: &[f16]) -> Vec<f16> {
        let mut out = Vec::with_capacity(rows.len() / self.input_dim * self.output_dim);
        self.project_chunks(rows, |projected| out.extend(projected.iter().map(|&v| f16::from_f32(v))));
        out
    }

    /// Centres, projects (GEMM) and normalises `rows` a chunk at a time, handing each
    /// projected chunk to `sink`.
    fn project_chunks<T: Copy + Into<f32>>(&self, rows: &[T], mut sink: impl FnMut(&[f32])) {
        let (d, k) = (self.input_dim, self.output_dim);
        let mut centred = Vec::with_capacity(CHUNK_ROWS * d);
        let mut projected = vec![0f32; CHUNK_ROWS * k];
        for chunk in rows.chunks(CHUNK_ROWS * d) {
            let n = chunk.len() / d;
            centred.clear();
            centred.extend(chunk[..n * d].chunks_exact(d).flat_map(|r| r.iter().zip(&self.mean).map(|(&v, m)| v.into() - m)));
            let out = &mut projected[..n * k];
            crate::linalg::mul_transposed(&centred, &self.components, n, k, d, out);
            for r in out.chunks_exact_mut(k) {
                let norm = r.iter().map(|v| v * v).sum::<f32>().sqrt();
                if norm > 0.0 {
                    r.iter_mut().for_each(|v| *v /= norm);
                }
            }
            sink(out);
        }
    }

    pub fn validate(&self) -> Result<(), String> {
        if self.output_dim == 0 || self.output_dim > self.input_dim || self.mean.len() != self.input_dim || self.components.len() != self.output_dim * self.input_dim {
            return Err(format!("PCA arrays do not match {} → {} dimensions", self.input_dim, self.output_dim));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_dominant_directions_and_refuses_bad_sizes() {
        // Points spread along x (σ 3) and y (σ 1), flat in z: the first component is ±x.
        let mut rng = crate::mesh::procedural::Rng::new(3);
        let mut rows = Vec::new();
        for _ in 0..2000 {
            rows.extend([3.0 * rng.normal() as f32 + 5.0, rng.normal() as f32, 0.0]);
        }
        let p = Pca::fit(&rows, 3, 2).unwrap();
        assert!((p.components[0].abs() - 1.0).abs() < 1e-2, "{:?}", p.components);
        assert!((p.mean[0] - 5.0).abs() < 0.3);
        let y = p.project(&rows[..6]);
        assert_eq!(y.len(), 4);
        assert!((y[0] * y[0] + y[1] * y[1] - 1.0).abs() < 1e-5);
        p.validate().unwrap();
        assert!(Pca::fit(&rows, 3, 4).is_err());
        assert!(Pca::fit(&rows[..4], 3, 2).is_err());
        assert!(Pca::fit(&rows[..3], 3, 2).is_err());
    }

    #[test]
    fn f16_projection_in_chunks_equals_the_f32_one() {
        // More rows than one chunk, so the chunk boundary is crossed.
        let (n, dim, k) = (CHUNK_ROWS + 37, 24, 8);
        let mut rng = crate::mesh::procedural::Rng::new(5);
        let rows: Vec<f32> = (0..n * dim).map(|i| rng.normal() as f32 * (1.0 + (i % dim) as f32)).collect();
        let halves: Vec<f16> = rows.iter().map(|&v| f16::from_f32(v)).collect();
        let p = Pca::fit(&halves, dim, k).unwrap();
        let wide = p.project(&halves.iter().map(|h| h.to_f32()).collect::<Vec<_>>());
        let narrow = p.project_f16(&halves);
        assert_eq!((wide.len(), narrow.len()), (n * k, n * k));
        let worst = wide.iter().zip(&narrow).map(|(a, b)| (a - b.to_f32()).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-3, "f16 projection differs by {worst}");
        // The leading component carries the widest input dimension (σ grows with the index).
        let lead = &p.components[..dim];
        let widest = (0..dim).max_by(|&a, &b| lead[a].abs().total_cmp(&lead[b].abs())).unwrap();
        assert_eq!(widest, dim - 1, "{lead:?}");
    }
}
