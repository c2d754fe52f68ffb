//! Product quantisation of patch descriptors: each descriptor is cut into `subspaces`
//! equal slices and each slice stored as the index (one byte) of its nearest of 256
//! centroids learnt on the object's own patches (Jégou et al., 2011). A 64-value f16
//! descriptor (128 bytes) becomes 16 bytes. Matching decodes the few templates it compares
//! back to f32 (centroids concatenated) and compares the query's exact descriptors with
//! them: the asymmetric distance, with no change to the matcher.

use half::f16;
use rayon::prelude::*;

/// Centroids per subspace: one byte per code.
pub const CENTROIDS: usize = 256;

/// Rows the centroids are learnt from at most (evenly strided): 256 centroids of a few
/// dimensions settle long before the hundreds of thousands of patches an object has.
const MAX_FIT_ROWS: usize = 32_768;

/// Lloyd iterations of the k-means; the assignment changes little after these.
const ITERATIONS: usize = 12;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProductQuantizer {
    pub dim: usize,
    pub subspaces: usize,
    /// `subspaces × CENTROIDS × (dim / subspaces)`, row-major.
    pub centroids: Vec<f32>,
}

impl ProductQuantizer {
    pub fn sub_dim(&self) -> usize {
        self.dim / self.subspaces
    }

    /// Learns the centroids from `rows` (`n × dim`, row-major).
    pub fn fit(rows: &[f16], dim: usize, subspaces: usize) -> Result<Self, String> {
        if dim == 0 || subspaces == 0 || !dim.is_multiple_of(subspaces) {
            return Err(format!("product quantisation: {dim} dimensions do not split into {subspaces} equal subspaces"));
        }
        if !rows.len().is_multiple_of(dim) {
            return Err(format!("product quantisation: {} values are not rows of {dim}", rows.len()));
        }
        let n = rows.len() / dim;
        if n == 0 {
            return Err("product quantisation: no descriptors to learn from".into());
        }
        let stride = n.div_ceil(MAX_FIT_ROWS);
        let picked: Vec<&[f16]> = rows.chunks_exact(dim).step_by(stride).collect();
        let sub = dim / subspaces;
        let centroids: Vec<Vec<f32>> = (0..subspaces)
            .into_par_iter()
            .map(|s| {
                let data: Vec<f32> = picked.iter().flat_map(|r| r[s * sub..(s + 1) * sub].iter().map(|v| v.to_f32())).collect();
                kmeans(&data, sub)
            })
            .collect();
        Ok(Self { dim, subspaces, centroids: centroids.concat() })
    }

    fn centroid(&self, s: usize, c: usize) -> &[f32] {
        let sub = self.sub_dim();
        let at = (s * CENTROIDS + c) * sub;
        &self.centroids[at..at + sub]
    }

    /// One code byte per subspace for every row of `rows` (`n × dim`).
    pub fn encode(&self, rows: &[f16]) -> Vec<u8> {
        let sub = self.sub_dim();
        rows.par_chunks_exact(self.dim)
            .flat_map_iter(|row| {
                // Widened once per row, not once per subspace.
                let x: Vec<f32> = row.iter().map(|v| v.to_f32()).collect();
                (0..self.subspaces).map(move |s| nearest(&self.centroids[s * CENTROIDS * sub..(s + 1) * CENTROIDS * sub], sub, &x[s * sub..(s + 1) * sub]).0 as u8)
            })
            .collect()
    }

    /// Appends the rows `codes` stand for (`subspaces` bytes each), as f32.
    pub fn decode_into(&self, codes: &[u8], out: &mut Vec<f32>) {
        out.reserve(codes.len() / self.subspaces * self.dim);
        for row in codes.chunks_exact(self.subspaces) {
            for (s, &c) in row.iter().enumerate() {
                out.extend_from_slice(self.centroid(s, c as usize));
            }
        }
    }

    /// Checks the shapes a stored quantiser must have (a damaged file must not panic).
    pub fn validate(&self) -> Result<(), String> {
        if self.dim == 0 || self.subspaces == 0 || !self.dim.is_multiple_of(self.subspaces) {
            return Err(format!("{} dimensions in {} subspaces", self.dim, self.subspaces));
        }
        if self.centroids.len() != self.subspaces * CENTROIDS * self.sub_dim() {
            return Err(format!("{} centroid values, expected {}", self.centroids.len(), self.subspaces * CENTROIDS * self.sub_dim()));
        }
        if self.centroids.iter().any(|v| !v.is_finite()) {
            return Err("a centroid is not finite".into());
        }
        Ok(())
    }
}

/// Index and squared distance of the centroid (rows of `centroids`, `dim` each) nearest `x`.
fn nearest(centroids: &[f32], dim: usize, x: &[f32]) -> (usize, f32) {
    let mut best = (0, f32::INFINITY);
    for (i, c) in centroids.chunks_exact(dim).enumerate() {
        let d: f32 = c.iter().zip(x).map(|(a, b)| (a - b) * (a - b)).sum();
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// `CENTROIDS` centroids of `data` (`n × dim`) by Lloyd's k-means, started from evenly
/// strided rows; a cluster left empty takes the row farthest from its centroid. With
/// fewer rows than centroids, the rows themselves (repeated) are the centroids.
fn kmeans(data: &[f32], dim: usize) -> Vec<f32> {
    let n = data.len() / dim;
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centroids: Vec<f32> = (0..CENTROIDS).flat_map(|c| row(c * n / CENTROIDS.max(1) % n).to_vec()).collect();
    if n <= CENTROIDS {
        return centroids;
    }
    let mut assign = vec![(0usize, 0f32); n];
    for _ in 0..ITERATIONS {
        for (i, a) in assign.iter_mut().enumerate() {
            *a = nearest(&centroids, dim, row(i));
        }
        let mut sums = vec![0f64; CENTROIDS * dim];
        let mut counts = vec![0usize; CENTROIDS];
        for (i, &(c, _)) in assign.iter().enumerate() {
            counts[c] += 1;
            for (s, &v) in sums[c * dim..(c + 1) * dim].iter_mut().zip(row(i)) {
                *s += v as f64;
            }
        }
        for c in 0..CENTROIDS {
            if counts[c] > 0 {
                for k in 0..dim {
                    centroids[c * dim + k] = (sums[c * dim + k] / counts[c] as f64) as f32;
                }
            } else if let Some((far, _)) = assign.iter().enumerate().max_by(|a, b| a.1 .1.total_cmp(&b.1 .1)) {
                centroids[c * dim..(c + 1) * dim].copy_from_slice(row(far));
                assign[far].1 = 0.0;
            }
        }
    }
    centroids
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit rows of `dim` values, deterministic.
    fn rows(n: usize, dim: usize) -> Vec<f16> {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        (0..n)
            .flat_map(|_| {
                let r: Vec<f32> = (0..dim).map(|_| next()).collect();
                let norm = r.iter().map(|x| x * x).sum::<f32>().sqrt();
                r.into_iter().map(move |x| f16::from_f32(x / norm))
            })
            .collect()
    }

    #[test]
    fn codes_decode_close_to_the_rows_and_keep_the_nearest_neighbour() {
        let (n, dim) = (4000, 16);
        let data = rows(n, dim);
        let pq = ProductQuantizer::fit(&data, dim, 4).unwrap();
        pq.validate().unwrap();
        let codes = pq.encode(&data);
        assert_eq!(codes.len(), n * 4);
        let mut back = Vec::new();
        pq.decode_into(&codes, &mut back);
        assert_eq!(back.len(), n * dim);
        let err: f32 = data.iter().zip(&back).map(|(a, b)| (a.to_f32() - b) * (a.to_f32() - b)).sum::<f32>() / n as f32;
        // Unit rows: a squared error of 1 is no information at all.
        assert!(err < 0.25, "mean squared reconstruction error {err}");
        // A row's own reconstruction is, most of the time, the nearest to it by cosine.
        let row = |i: usize| data[i * dim..(i + 1) * dim].iter().map(|v| v.to_f32()).collect::<Vec<f32>>();
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        let hits = (0..200).filter(|&i| (0..n).max_by(|&a, &b| dot(&row(i), &back[a * dim..(a + 1) * dim]).total_cmp(&dot(&row(i), &back[b * dim..(b + 1) * dim]))) == Some(i)).count();
        assert!(hits > 120, "own reconstruction nearest for {hits} of 200");
    }

    #[test]
    fn bad_shapes_are_refused() {
        assert!(ProductQuantizer::fit(&rows(10, 16), 16, 3).is_err());
        assert!(ProductQuantizer::fit(&rows(10, 16)[..15], 16, 4).is_err());
        assert!(ProductQuantizer::fit(&[], 16, 4).is_err());
        let mut pq = ProductQuantizer::fit(&rows(10, 16), 16, 4).unwrap();
        pq.centroids.pop();
        assert!(pq.validate().is_err());
    }
}
