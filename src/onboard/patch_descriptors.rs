//! An object's stored patch descriptors, in one of two codings: f16 rows (the default, and
//! every object before format 6), or product-quantised codes (pq.rs; `--descriptors pq4` /
//! `pq2`: an eighth / a quarter of the bytes). Matching reads them only through
//! `widen_into`, a few templates at a time.

use super::pq::ProductQuantizer;
use super::stored_rows::{HalfRows, StoredRows};
use half::f16;
use std::ops::Range;

#[derive(Clone, Debug, PartialEq)]
pub enum PatchDescriptors {
    /// `patches × dim` f16, L2-normalised rows (memory-mapped when loaded from `dir://`).
    Half(HalfRows),
    /// `patches × subspaces` code bytes and the centroids they index.
    Quantized { quantizer: ProductQuantizer, codes: StoredRows<u8> },
    /// `patches × dim` int8 values and one scale per row (value = code × scale).
    Int8 { codes: StoredRows<i8>, scales: StoredRows<f32> },
}

impl Default for PatchDescriptors {
    fn default() -> Self {
        PatchDescriptors::Half(Vec::new().into())
    }
}

impl PatchDescriptors {
    /// Rows held, for descriptors of `dim` values.
    pub fn rows(&self, dim: usize) -> usize {
        match self {
            PatchDescriptors::Half(v) => v.len().checked_div(dim).unwrap_or(0),
            PatchDescriptors::Quantized { quantizer, codes } => codes.len() / quantizer.subspaces.max(1),
            PatchDescriptors::Int8 { scales, .. } => scales.len(),
        }
    }

    /// Whether every row is whole (the values fill rows of `dim`, the codes rows of the
    /// quantiser's subspaces, whose dimension is `dim`).
    pub fn shape_ok(&self, dim: usize) -> bool {
        match self {
            PatchDescriptors::Half(v) => dim > 0 && v.len().is_multiple_of(dim),
            PatchDescriptors::Quantized { quantizer, codes } => quantizer.dim == dim && quantizer.validate().is_ok() && codes.len().is_multiple_of(quantizer.subspaces),
            PatchDescriptors::Int8 { codes, scales } => dim > 0 && codes.len() == scales.len() * dim && scales.iter().all(|s| s.is_finite()),
        }
    }

    /// Appends the rows of `patches` as f32 (`dim` values each): widened by half's slice
    /// conversion (the CPU's f16 instructions where it has them), or decoded from codes.
    pub fn widen_into(&self, dim: usize, patches: Range<usize>, out: &mut Vec<f32>) {
        match self {
            PatchDescriptors::Half(v) => widen_half(&v[patches.start * dim..patches.end * dim], out),
            PatchDescriptors::Quantized { quantizer, codes } => {
                let (m, start) = (quantizer.subspaces, out.len());
                quantizer.decode_into(&codes[patches.start * m..patches.end * m], out);
                normalise_rows(&mut out[start..], dim);
            }
            PatchDescriptors::Int8 { codes, scales } => {
                let start = out.len();
                for (row, &scale) in codes[patches.start * dim..patches.end * dim].chunks_exact(dim).zip(&scales[patches.clone()]) {
                    out.extend(row.iter().map(|&c| c as f32 * scale));
                }
                normalise_rows(&mut out[start..], dim);
            }
        }
    }

    /// Heap bytes held (mapped rows: none).
    pub fn memory_bytes(&self) -> usize {
        match self {
            PatchDescriptors::Half(v) => v.heap_bytes(),
            PatchDescriptors::Quantized { quantizer, codes } => codes.heap_bytes() + quantizer.centroids.len() * 4,
            PatchDescriptors::Int8 { codes, scales } => codes.heap_bytes() + scales.heap_bytes(),
        }
    }

    /// Only the rows in `rows` (of `dim` values), in that order, in the same coding.
    pub fn gather(&self, dim: usize, rows: &[Range<usize>]) -> Self {
        match self {
            PatchDescriptors::Half(v) => PatchDescriptors::Half(v.gather(rows, dim)),
            PatchDescriptors::Quantized { quantizer, codes } => PatchDescriptors::Quantized { quantizer: quantizer.clone(), codes: codes.gather(rows, quantizer.subspaces) },
            PatchDescriptors::Int8 { codes, scales } => PatchDescriptors::Int8 { codes: codes.gather(rows, dim), scales: scales.gather(rows, 1) },
        }
    }

    /// The f16 rows, when that is the coding (PCA fits and projects on them).
    pub fn as_half(&self) -> Option<&[f16]> {
        match self {
            PatchDescriptors::Half(v) => Some(&**v),
            PatchDescriptors::Quantized { .. } | PatchDescriptors::Int8 { .. } => None,
        }
    }

    /// Replaces f16 rows of `dim` values by int8 values and a scale per row (the row's
    /// largest magnitude over 127).
    pub fn to_int8(&mut self, dim: usize) -> Result<(), String> {
        let PatchDescriptors::Half(rows) = self else {
            return Err("the patch descriptors are already coded".into());
        };
        if dim == 0 || !rows.len().is_multiple_of(dim) {
            return Err(format!("{} values are not rows of {dim}", rows.len()));
        }
        let mut codes = Vec::with_capacity(rows.len());
        let mut scales = Vec::with_capacity(rows.len() / dim);
        for row in rows.chunks_exact(dim) {
            let max = row.iter().map(|v| v.to_f32().abs()).fold(0.0f32, f32::max);
            let scale = if max > 0.0 { max / 127.0 } else { 1.0 };
            codes.extend(row.iter().map(|v| (v.to_f32() / scale).round().clamp(-127.0, 127.0) as i8));
            scales.push(scale);
        }
        *self = PatchDescriptors::Int8 { codes: codes.into(), scales: scales.into() };
        Ok(())
    }

    /// Replaces f16 rows of `dim` values by `subspaces` code bytes each, learnt on them.
    pub fn quantize(&mut self, dim: usize, subspaces: usize) -> Result<(), String> {
        let PatchDescriptors::Half(rows) = self else {
            return Err("the patch descriptors are already quantised".into());
        };
        let quantizer = ProductQuantizer::fit(rows, dim, subspaces)?;
        let codes = quantizer.encode(rows);
        *self = PatchDescriptors::Quantized { quantizer, codes: codes.into() };
        Ok(())
    }
}

/// Scales each row of `dim` values to unit length: the matcher compares by dot product as
/// cosine, and a decoded row (a sum of centroids, or rounded values) is a little off unit
/// length, which would otherwise weigh in.
fn normalise_rows(rows: &mut [f32], dim: usize) {
    for row in rows.chunks_exact_mut(dim) {
        let norm = row.iter().map(|x| x * x).sum::<f32>().sqrt();
        if norm > 0.0 {
            row.iter_mut().for_each(|x| *x /= norm);
        }
    }
}

/// Appends `stored` widened to f32 by half's slice conversion, which uses the CPU's f16
/// instructions where it has them (`bench matching`: 5–10× the per-value conversion).
pub fn widen_half(stored: &[f16], out: &mut Vec<f32>) {
    use half::slice::HalfFloatSliceExt;
    let start = out.len();
    out.resize(start + stored.len(), 0.0);
    stored.convert_to_f32_slice(&mut out[start..]);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_rows(n: usize, dim: usize) -> Vec<f16> {
        (0..n)
            .flat_map(|i| {
                let r: Vec<f32> = (0..dim).map(|k| ((i * 7 + k * 13) % 11) as f32 - 5.0).collect();
                let norm = r.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-6);
                r.into_iter().map(move |x| f16::from_f32(x / norm))
            })
            .collect()
    }

    #[test]
    fn both_codings_hand_out_unit_rows_of_the_asked_patches() {
        let (n, dim) = (600, 8);
        let rows = unit_rows(n, dim);
        let half = PatchDescriptors::Half(rows.clone().into());
        assert!(half.shape_ok(dim) && !half.shape_ok(7));
        assert_eq!((half.rows(dim), half.memory_bytes()), (n, n * dim * 2));
        let mut out = vec![1.0];
        half.widen_into(dim, 3..5, &mut out);
        assert_eq!(out.len(), 1 + 2 * dim);
        assert_eq!(out[1..], rows[3 * dim..5 * dim].iter().map(|v| v.to_f32()).collect::<Vec<_>>()[..]);

        let mut coded = half.clone();
        coded.quantize(dim, 2).unwrap();
        assert!(coded.shape_ok(dim) && coded.as_half().is_none());
        assert_eq!(coded.rows(dim), n);
        // Two code bytes per row, and the centroids: 2 subspaces × 256 × 4 values.
        assert_eq!(coded.memory_bytes(), n * 2 + 2 * crate::onboard::pq::CENTROIDS * 4 * 4);
        let mut out = Vec::new();
        coded.widen_into(dim, 10..20, &mut out);
        assert_eq!(out.len(), 10 * dim);
        for (row, exact) in out.chunks(dim).zip(rows[10 * dim..20 * dim].chunks(dim)) {
            let norm: f32 = row.iter().map(|x| x * x).sum::<f32>().sqrt();
            let cos: f32 = row.iter().zip(exact).map(|(a, b)| a * b.to_f32()).sum();
            assert!((norm - 1.0).abs() < 1e-5 && cos > 0.8, "norm {norm}, cosine to the exact row {cos}");
        }
        assert!(coded.quantize(dim, 2).is_err(), "codes are not quantised again");

        let mut int8 = half.clone();
        int8.to_int8(dim).unwrap();
        assert!(int8.shape_ok(dim) && int8.as_half().is_none());
        assert_eq!((int8.rows(dim), int8.memory_bytes()), (n, n * dim + n * 4));
        let mut out = Vec::new();
        int8.widen_into(dim, 10..20, &mut out);
        for (row, exact) in out.chunks(dim).zip(rows[10 * dim..20 * dim].chunks(dim)) {
            let cos: f32 = row.iter().zip(exact).map(|(a, b)| a * b.to_f32()).sum();
            assert!(cos > 0.999, "int8 keeps the row: cosine {cos}");
        }
        assert!(int8.to_int8(dim).is_err() && int8.quantize(dim, 2).is_err());
    }
}
