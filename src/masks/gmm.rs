//! Colour models for box segmentation: Gaussian mixtures over RGB with full covariances,
//! as in GrabCut (Rother et al. 2004). A scene's background and an object's surface are
//! both several colours, which one Gaussian or a coarse histogram blurs together.

use nalgebra::{Matrix3, Vector3};
use std::borrow::Cow;

pub type Colour = [f64; 3];

/// Added to every covariance diagonal (in 8-bit levels²): a flat rendered face has
/// near-zero variance, whose density would be so peaked that a little noise or JPEG
/// ringing makes its own pixels look foreign.
const VARIANCE_FLOOR: f64 = 4.0;
/// Components fitted on fewer samples are dropped: their covariance means nothing.
const MIN_COMPONENT_SAMPLES: usize = 4;
const KMEANS_ROUNDS: usize = 8;
/// Mixtures are fitted from at most about this many samples: a wide ring's background
/// has up to 170 000 cells, and a few colours are told as well from a fifth of them for a
/// third less of that cut's time (docs/estimation.md, "Where a box's time goes").
const MAX_FIT_SAMPLES: usize = 32_768;

/// About `MAX_FIT_SAMPLES` of the samples (all of them, borrowed, when fewer), chosen by a
/// hash of their index rather than every n-th: a grid's cells taken at a stride keep whole
/// columns and miss a pattern of the same period.
fn thinned(samples: &[Colour]) -> Cow<'_, [Colour]> {
    if samples.len() <= MAX_FIT_SAMPLES {
        return Cow::Borrowed(samples);
    }
    let threshold = (MAX_FIT_SAMPLES as f64 / samples.len() as f64 * u32::MAX as f64) as u32;
    Cow::Owned(samples.iter().enumerate().filter(|(i, _)| (*i as u32).wrapping_mul(2_654_435_761) <= threshold).map(|(_, z)| *z).collect())
}

struct Component {
    mean: Vector3<f64>,
    inv_cov: Matrix3<f64>,
    /// ln(weight) − ½ ln det(2π Σ).
    log_norm: f64,
}

pub struct Gmm {
    components: Vec<Component>,
}

impl Gmm {
    /// k-means (seeded by luminance quantiles, so deterministic) then one estimate of
    /// each cluster's Gaussian. `None` when there are too few samples.
    pub fn fit(samples: &[Colour], k: usize) -> Option<Gmm> {
        let samples = thinned(samples);
        let assign = kmeans(&samples, k.max(1));
        Gmm::from_assignment(&samples, &assign)
    }

    /// GrabCut's re-estimation: each sample joins its most likely component, then every
    /// component is estimated again from its samples.
    pub fn refit(&self, samples: &[Colour]) -> Option<Gmm> {
        let samples = thinned(samples);
        let assign: Vec<usize> = samples.iter().map(|z| self.most_likely(z)).collect();
        Gmm::from_assignment(&samples, &assign)
    }

    /// −ln p(z), the data cost of giving colour `z` this model's label.
    pub fn neg_log_likelihood(&self, z: &Colour) -> f64 {
        // Called for every cell and round: the log-sum-exp in one pass, without a buffer
        // (the sum is rescaled whenever a larger term comes).
        let (mut max, mut sum) = (f64::NEG_INFINITY, 0.0);
        for j in 0..self.components.len() {
            let l = self.log_density(j, z);
            if l > max {
                sum = sum * (max - l).exp() + 1.0;
                max = l;
            } else {
                sum += (l - max).exp();
            }
        }
        -(max + sum.ln())
    }

    fn log_density(&self, j: usize, z: &Colour) -> f64 {
        let c = &self.components[j];
        let d = Vector3::from(*z) - c.mean;
        c.log_norm - 0.5 * d.dot(&(c.inv_cov * d))
    }

    fn most_likely(&self, z: &Colour) -> usize {
        (0..self.components.len()).map(|j| (j, self.log_density(j, z))).max_by(|a, b| a.1.total_cmp(&b.1)).map_or(0, |(j, _)| j)
    }

    fn from_assignment(samples: &[Colour], assign: &[usize]) -> Option<Gmm> {
        let k = assign.iter().copied().max()? + 1;
        let mut count = vec![0usize; k];
        let mut sum = vec![Vector3::zeros(); k];
        let mut outer = vec![Matrix3::zeros(); k];
        for (z, &j) in samples.iter().zip(assign) {
            let v = Vector3::from(*z);
            count[j] += 1;
            sum[j] += v;
            outer[j] += v * v.transpose();
        }
        let total = samples.len() as f64;
        let components: Vec<Component> = (0..k)
            .filter(|&j| count[j] >= MIN_COMPONENT_SAMPLES)
            .filter_map(|j| {
                let n = count[j] as f64;
                let mean = sum[j] / n;
                let cov = outer[j] / n - mean * mean.transpose() + Matrix3::identity() * VARIANCE_FLOOR;
                let det = cov.determinant();
                let inv_cov = cov.try_inverse().filter(|_| det > 0.0)?;
                let log_norm = (n / total).ln() - 0.5 * (det.ln() + 3.0 * (2.0 * std::f64::consts::PI).ln());
                Some(Component { mean, inv_cov, log_norm })
            })
            .collect();
        (!components.is_empty()).then_some(Gmm { components })
    }
}

/// Cluster index per sample after Lloyd's iterations from luminance-quantile seeds.
fn kmeans(samples: &[Colour], k: usize) -> Vec<usize> {
    if samples.is_empty() {
        return Vec::new();
    }
    let luma = |z: &Colour| 0.299 * z[0] + 0.587 * z[1] + 0.114 * z[2];
    let mut order: Vec<usize> = (0..samples.len()).collect();
    order.sort_by(|&a, &b| luma(&samples[a]).total_cmp(&luma(&samples[b])));
    let k = k.min(samples.len());
    let mut centres: Vec<Colour> = (0..k).map(|j| samples[order[(2 * j + 1) * samples.len() / (2 * k)]]).collect();
    let dist2 = |a: &Colour, b: &Colour| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>();
    let nearest = |z: &Colour, centres: &[Colour]| (0..centres.len()).min_by(|&a, &b| dist2(z, &centres[a]).total_cmp(&dist2(z, &centres[b]))).unwrap_or(0);
    let mut assign = vec![0; samples.len()];
    for _ in 0..KMEANS_ROUNDS {
        for (slot, z) in assign.iter_mut().zip(samples) {
            *slot = nearest(z, &centres);
        }
        let mut sums = vec![([0.0; 3], 0usize); k];
        for (z, &j) in samples.iter().zip(&assign) {
            (0..3).for_each(|i| sums[j].0[i] += z[i]);
            sums[j].1 += 1;
        }
        for (centre, (s, n)) in centres.iter_mut().zip(sums) {
            if n > 0 {
                *centre = s.map(|v| v / n as f64);
            }
        }
    }
    assign
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separates_two_colour_clusters() {
        let red: Vec<Colour> = (0..50).map(|i| [200.0 + (i % 5) as f64, 20.0 + (i % 3) as f64, 30.0]).collect();
        let blue: Vec<Colour> = (0..50).map(|i| [10.0, 40.0 + (i % 4) as f64, 220.0 - (i % 7) as f64]).collect();
        let both: Vec<Colour> = red.iter().chain(&blue).copied().collect();
        let g = Gmm::fit(&both, 2).unwrap();
        assert_eq!(g.components.len(), 2);
        let reds = Gmm::fit(&red, 3).unwrap();
        assert!(reds.neg_log_likelihood(&[202.0, 21.0, 30.0]) + 10.0 < reds.neg_log_likelihood(&[10.0, 40.0, 220.0]));
        let again = g.refit(&both).unwrap();
        assert!((again.neg_log_likelihood(&red[0]) - g.neg_log_likelihood(&red[0])).abs() < 1e-6);
        assert!(Gmm::fit(&[], 5).is_none());
        assert!(Gmm::fit(&red[..2], 5).is_none(), "two samples cannot make a component");
    }

    #[test]
    fn a_wide_rings_many_samples_are_fitted_from_an_even_thinning() {
        // 100 000 samples, one in ten blue: thinned to a third, the mixture still holds both
        // colours at about their shares.
        let many: Vec<Colour> = (0..100_000).map(|i| if i % 10 == 3 { [10.0, 40.0 + (i % 4) as f64, 220.0] } else { [200.0 + (i % 5) as f64, 20.0, 30.0] }).collect();
        assert!(thinned(&many).len() < MAX_FIT_SAMPLES * 11 / 10);
        let g = Gmm::fit(&many, 2).unwrap();
        let p = |z: &Colour| (-g.neg_log_likelihood(z)).exp();
        assert!(p(&[10.0, 41.0, 220.0]) > 0.0 && p(&[202.0, 20.0, 30.0]) > 3.0 * p(&[10.0, 41.0, 220.0]));
        let refitted = g.refit(&many).unwrap();
        assert_eq!(refitted.components.len(), 2);
    }
}
