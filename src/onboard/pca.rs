//! Optional PCA compression of patch descriptors, fitted at onboarding on the object's own
//! template patches (as FoundPose does for DINOv2 features) and recorded in the model, so
//! queries are projected the same way before matching. Rows are re-normalised after the
//! projection because matching compares by cosine.

use nalgebra::{DMatrix, SymmetricEigen};

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pca {
    pub input_dim: usize,
    pub output_dim: usize,
    pub mean: Vec<f32>,
    /// `output_dim × input_dim`, row-major: the leading eigenvectors of the covariance.
    pub components: Vec<f32>,
}

/// Rows used for the fit at most (evenly strided): the covariance of 64-d descriptors is
/// settled long before the hundreds of thousands of patches an object has.
const MAX_FIT_ROWS: usize = 50_000;

impl Pca {
    /// Fits on `rows` (`n × dim`, row-major) keeping `k` components.
    pub fn fit(rows: &[f32], dim: usize, k: usize) -> Result<Self, String> {
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
        let picked: Vec<&[f32]> = rows.chunks_exact(dim).step_by(stride).collect();
        let mut mean = vec![0f64; dim];
        for r in &picked {
            for (m, &v) in mean.iter_mut().zip(r.iter()) {
                *m += v as f64;
            }
        }
        mean.iter_mut().for_each(|m| *m /= picked.len() as f64);
        let mut cov = DMatrix::<f64>::zeros(dim, dim);
        for r in &picked {
            let c: Vec<f64> = r.iter().zip(&mean).map(|(&v, m)| v as f64 - m).collect();
            for i in 0..dim {
                for j in i..dim {
                    cov[(i, j)] += c[i] * c[j];
                }
            }
        }
        for i in 0..dim {
            for j in 0..i {
                cov[(i, j)] = cov[(j, i)];
            }
        }
        let eig = SymmetricEigen::new(cov);
        let mut order: Vec<usize> = (0..dim).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let components = order[..k].iter().flat_map(|&c| eig.eigenvectors.column(c).iter().map(|&v| v as f32).collect::<Vec<_>>()).collect();
        Ok(Self { input_dim: dim, output_dim: k, mean: mean.iter().map(|&m| m as f32).collect(), components })
    }

    /// Projects `rows` (`n × input_dim`) to `n × output_dim`, each row L2-normalised.
    pub fn project(&self, rows: &[f32]) -> Vec<f32> {
        let mut out = Vec::with_capacity(rows.len() / self.input_dim * self.output_dim);
        let mut centred = vec![0f32; self.input_dim];
        for r in rows.chunks_exact(self.input_dim) {
            for ((c, &v), &m) in centred.iter_mut().zip(r).zip(&self.mean) {
                *c = v - m;
            }
            let start = out.len();
            out.extend(self.components.chunks_exact(self.input_dim).map(|w| w.iter().zip(&centred).map(|(a, b)| a * b).sum::<f32>()));
            let norm = out[start..].iter().map(|v| v * v).sum::<f32>().sqrt();
            if norm > 0.0 {
                out[start..].iter_mut().for_each(|v| *v /= norm);
            }
        }
        out
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
}
