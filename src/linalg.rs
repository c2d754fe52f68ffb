//! Dense f32 matrix products on the `gemm` crate (SIMD kernels, multi-threaded on rayon):
//! the descriptor similarities of matching and the covariance and projection of the PCA.
//! All matrices are row-major slices.

/// `out (m × n) = a (m × dim) · b (n × dim)ᵀ`: every row of `a` dotted with every row of `b`.
pub fn mul_transposed(a: &[f32], b: &[f32], m: usize, n: usize, dim: usize, out: &mut [f32]) {
    assert!(a.len() >= m * dim && b.len() >= n * dim && out.len() >= m * n, "mul_transposed: slices shorter than {m}×{dim}, {n}×{dim}, {m}×{n}");
    // SAFETY: the asserts above keep every index the strides below describe in bounds:
    // a is read as m × dim (row stride dim), b as dim × n (element (k, j) = b[j·dim + k]),
    // out written as m × n (row stride n).
    unsafe {
        gemm::gemm(m, n, dim, out.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, dim as isize, b.as_ptr(), dim as isize, 1, 0.0, 1.0, false, false, false, gemm::Parallelism::Rayon(0));
    }
}

/// `out (dim × dim) += aᵀ · a` for `a` (n × dim): the scatter matrix of `a`'s rows.
pub fn add_gram(a: &[f32], n: usize, dim: usize, out: &mut [f32]) {
    assert!(a.len() >= n * dim && out.len() >= dim * dim, "add_gram: slices shorter than {n}×{dim}, {dim}×{dim}");
    // SAFETY: as above; aᵀ is a read with swapped strides (element (i, k) = a[k·dim + i]).
    unsafe {
        gemm::gemm(dim, dim, n, out.as_mut_ptr(), 1, dim as isize, true, a.as_ptr(), dim as isize, 1, a.as_ptr(), 1, dim as isize, 1.0, 1.0, false, false, false, gemm::Parallelism::Rayon(0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(n: usize, seed: usize) -> Vec<f32> {
        (0..n).map(|i| (((i * 37 + seed) % 11) as f32) - 5.0).collect()
    }

    #[test]
    fn products_equal_naive_sums() {
        let (m, n, d) = (5, 9, 7);
        let (a, b) = (values(m * d, 1), values(n * d, 4));
        let mut out = vec![0f32; m * n];
        mul_transposed(&a, &b, m, n, d, &mut out);
        for i in 0..m {
            for j in 0..n {
                let naive: f32 = (0..d).map(|k| a[i * d + k] * b[j * d + k]).sum();
                assert!((out[i * n + j] - naive).abs() < 1e-4);
            }
        }
        // The gram matrix accumulates: twice the same rows give twice the sums.
        let mut g = vec![0f32; d * d];
        add_gram(&a, m, d, &mut g);
        add_gram(&a, m, d, &mut g);
        for i in 0..d {
            for j in 0..d {
                let naive: f32 = (0..m).map(|r| a[r * d + i] * a[r * d + j]).sum();
                assert!((g[i * d + j] - 2.0 * naive).abs() < 1e-3, "({i},{j}) {} vs {}", g[i * d + j], 2.0 * naive);
            }
        }
    }
}
