//! Principal spread of a point set: the mean and the covariance's eigen-decomposition, for
//! the degeneracy checks and for the plane of a flat inlier set.

use nalgebra::{Matrix3, Vector3};

pub(crate) struct Spread {
    pub(crate) mean: Vector3<f64>,
    /// Principal variances, largest first.
    pub(crate) variances: [f64; 3],
    /// Unit principal axes, in the order of `variances`.
    pub(crate) axes: [Vector3<f64>; 3],
}

/// `None` for an empty set.
pub(crate) fn spread(points: impl Iterator<Item = Vector3<f64>> + Clone) -> Option<Spread> {
    let n = points.clone().count();
    if n == 0 {
        return None;
    }
    let mean = points.clone().sum::<Vector3<f64>>() / n as f64;
    let cov = points.map(|p| (p - mean) * (p - mean).transpose()).sum::<Matrix3<f64>>() / n as f64;
    let eig = cov.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    Some(Spread { mean, variances: order.map(|i| eig.eigenvalues[i]), axes: order.map(|i| eig.eigenvectors.column(i).into_owned()) })
}
