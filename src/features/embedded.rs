//! The embedded weight-free backbone: per 16-px patch, a gradient-orientation histogram
//! (HOG/SIFT-like, on a 32-px support), mean chromaticity, and a silhouette context
//! (object coverage in log-polar bins around the patch, from the crop mask). The last part
//! is what crosses the render-to-real gap untouched; docs/backbone.md has the measurements
//! behind the weights.

use super::backbone::{check_sizes, l2_normalize, mean_descriptor, patch_coverage, Backbone, BackboneIdentity, FeatureError, FeatureMap};
use super::crop::CropInput;
use crate::geometry::PatchGrid;
use rayon::prelude::*;
use sha2::{Digest, Sha256};

/// Parameters of the embedded backbone. All of them enter its identity hash.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EmbeddedConfig {
    pub input_size: u32,
    pub patch_size: u32,
    /// Orientation bins of the gradient histograms.
    pub orientation_bins: usize,
    /// Signed orientations (0–360°) keep edge polarity; unsigned (0–180°) survive polarity
    /// flips between an untextured render and a photo.
    pub signed_orientation: bool,
    pub hog_weight: f32,
    pub color_weight: f32,
    pub shape_weight: f32,
    /// Binomial pre-smoothing passes (each ≈ σ 0.7 px); damps sensor noise.
    pub smoothing_passes: u32,
    /// Minimum patch coverage for the global descriptor's mean.
    pub min_coverage: f32,
}

impl Default for EmbeddedConfig {
    fn default() -> Self {
        Self { input_size: 512, patch_size: 16, orientation_bins: 8, signed_orientation: false, hog_weight: 1.0, color_weight: 0.5, shape_weight: 2.0, smoothing_passes: 2, min_coverage: 0.5 }
    }
}

/// Angular sectors and ring edges (in patches) of the silhouette context.
const SHAPE_SECTORS: usize = 8;
const SHAPE_RINGS: [f32; 3] = [2.5, 6.0, 16.0];
const COLOR_DIMS: usize = 8;

pub struct EmbeddedBackbone {
    config: EmbeddedConfig,
    grid: PatchGrid,
    /// Bin of every patch offset (di, dj) ∈ [-(n-1), n-1]², or `usize::MAX` outside the rings.
    shape_bins: Vec<usize>,
    /// Patches of the grid in each silhouette-context bin of each patch ([patch][bin]): the
    /// mean's denominators, the same for every crop.
    shape_counts: Vec<f32>,
}

impl EmbeddedBackbone {
    pub fn new(config: EmbeddedConfig) -> Result<Self, String> {
        let grid = PatchGrid::for_crop(config.input_size, config.patch_size)?;
        if !config.patch_size.is_multiple_of(2) || config.orientation_bins < 2 {
            return Err("embedded backbone needs an even patch size and at least 2 orientation bins".into());
        }
        let n = grid.n as i32;
        let side = (2 * n - 1) as usize;
        let mut shape_bins = vec![usize::MAX; side * side];
        for di in -(n - 1)..n {
            for dj in -(n - 1)..n {
                let r = ((di * di + dj * dj) as f32).sqrt();
                let Some(ring) = SHAPE_RINGS.iter().position(|&e| r < e) else { continue };
                let a = (di as f32).atan2(dj as f32).rem_euclid(std::f32::consts::TAU);
                let sector = ((a / std::f32::consts::TAU * SHAPE_SECTORS as f32) as usize).min(SHAPE_SECTORS - 1);
                shape_bins[((di + n - 1) as usize) * side + (dj + n - 1) as usize] = ring * SHAPE_SECTORS + sector;
            }
        }
        let n = n as usize;
        let every_cell: Vec<(usize, usize, f32)> = (0..n * n).map(|k| (k / n, k % n, 1.0)).collect();
        let shape_counts = shape_bin_sums(&shape_bins, n, &every_cell, &(0..n * n).collect::<Vec<_>>());
        Ok(Self { config, grid, shape_bins, shape_counts })
    }

    pub fn config(&self) -> &EmbeddedConfig {
        &self.config
    }

    fn hog_dims(&self) -> usize {
        4 * self.config.orientation_bins
    }

    pub fn local_dim(&self) -> usize {
        self.hog_dims() + COLOR_DIMS + SHAPE_RINGS.len() * SHAPE_SECTORS
    }

    /// The patch grid of a crop of side `side`: the backbone's own for `input_size`, and
    /// the same number of patches, each half as wide, for a reduced crop.
    fn grid_for(&self, side: u32) -> PatchGrid {
        if side == self.config.input_size {
            self.grid
        } else {
            PatchGrid { n: self.grid.n, patch: self.grid.patch / 2 }
        }
    }

    fn extract_one(&self, crop: &CropInput) -> FeatureMap {
        let grid = self.grid_for(crop.rgb.width());
        let n = grid.n as usize;
        let dim = self.local_dim();
        let coverage = patch_coverage(&crop.mask, &grid);
        let cells = self.cell_histograms(crop, grid);
        let shape = self.shape_context(&coverage);
        let color = self.chromaticity(crop, grid);
        let hd = self.hog_dims();
        let b = self.config.orientation_bins;
        let nc = 2 * n; // cells per side: two per patch
        let mut local = vec![0f32; n * n * dim];
        for i in 0..n {
            for j in 0..n {
                let k = i * n + j;
                // A patch the mask does not touch keeps a zero row: every reader takes
                // patches at a coverage of at least the model's `min_coverage` (0.5), and
                // a crop is mostly such background.
                if coverage[k] == 0.0 {
                    continue;
                }
                let out = &mut local[k * dim..(k + 1) * dim];
                // 4×4 cells around the patch (one-cell ring) pooled into 2×2 quadrants.
                for ci in 0..4 {
                    for cj in 0..4 {
                        let (y, x) = ((2 * i + ci) as i64 - 1, (2 * j + cj) as i64 - 1);
                        if y < 0 || x < 0 || y >= nc as i64 || x >= nc as i64 {
                            continue;
                        }
                        let q = (ci / 2) * 2 + cj / 2;
                        let src = &cells[(y as usize * nc + x as usize) * b..][..b];
                        for (o, s) in out[q * b..(q + 1) * b].iter_mut().zip(src) {
                            *o += s;
                        }
                    }
                }
                normalize_clipped(&mut out[..hd], 0.2, 2.0);
                out[..hd].iter_mut().for_each(|v| *v *= self.config.hog_weight);
                for (o, c) in out[hd..hd + COLOR_DIMS].iter_mut().zip(&color[k * COLOR_DIMS..]) {
                    *o = c * self.config.color_weight;
                }
                let sd = SHAPE_RINGS.len() * SHAPE_SECTORS;
                for (o, s) in out[hd + COLOR_DIMS..].iter_mut().zip(&shape[k * sd..(k + 1) * sd]) {
                    *o = s * self.config.shape_weight;
                }
                l2_normalize(out);
            }
        }
        let global = mean_descriptor(&local, dim, &coverage, self.config.min_coverage);
        FeatureMap { grid, local_dim: dim, local, global, coverage }
    }

    /// Orientation histograms of (patch/2)-px cells, gradient magnitude soft-assigned to the
    /// two nearest orientation bins.
    fn cell_histograms(&self, crop: &CropInput, grid: PatchGrid) -> Vec<f32> {
        let s = crop.rgb.width() as usize;
        let reduced = grid.patch != self.grid.patch;
        let mut lum: Vec<f32> = crop.rgb.pixels().map(|p| super::grey(p) / 255.0).collect();
        // A pass blurs with variance ½ px²; at half the size the same blur in the picture
        // is a quarter of that: a quarter of the passes, at least one where there are any.
        let passes = if reduced { self.config.smoothing_passes.div_ceil(4) } else { self.config.smoothing_passes };
        for _ in 0..passes {
            binomial_blur(&mut lum, s);
        }
        let cell = (grid.patch / 2) as usize;
        let nc = s / cell;
        let b = self.config.orientation_bins;
        let period = if self.config.signed_orientation { std::f32::consts::TAU } else { std::f32::consts::PI };
        let mut hist = vec![0f32; nc * nc * b];
        // Per row: magnitudes and bin positions first (a loop without branches or libm calls,
        // which the compiler vectorises), then the scatter into the histograms.
        let mut mag = vec![0f32; s];
        let mut pos = vec![0f32; s];
        let scale = b as f32 / period;
        let gain = (self.grid.patch / grid.patch) as f32;
        let column_base: Vec<usize> = (0..s).map(|x| (x / cell) * b).collect();
        // Each row's first and last lit column (the background is black): a gradient can be
        // nonzero only within a column of the lit span of the rows around it, so the rest
        // of the row (the crop's margin) is neither computed nor read.
        let lit: Vec<Option<(usize, usize)>> = lum.chunks_exact(s).map(super::crop::nonzero_span).collect();
        for y in 1..s - 1 {
            let around = || lit[y - 1..=y + 1].iter().flatten();
            let (Some(first), Some(last)) = (around().map(|span| span.0).min(), around().map(|span| span.1).max()) else { continue };
            let columns = first.saturating_sub(1).max(1)..(last + 2).min(s - 1);
            let (above, here, below) = (&lum[(y - 1) * s..y * s], &lum[y * s..(y + 1) * s], &lum[(y + 1) * s..(y + 2) * s]);
            for x in columns.clone() {
                let gx = here[x + 1] - here[x - 1];
                let gy = below[x] - above[x];
                let m = (gx * gx + gy * gy).sqrt();
                mag[x] = if m < 1e-4 { 0.0 } else { m * gain };
                pos[x] = wrap_angle(fast_atan2(gy, gx), period) * scale;
            }
            let row = &mut hist[(y / cell) * nc * b..(y / cell + 1) * nc * b];
            for x in columns {
                if mag[x] == 0.0 {
                    continue;
                }
                // pos ∈ [0, b]: truncation is its floor, and the bins wrap round.
                let whole = pos[x] as usize;
                let lo = if whole >= b { whole - b } else { whole };
                let hi = if lo + 1 == b { 0 } else { lo + 1 };
                let frac = pos[x] - whole as f32;
                let cell_bins = &mut row[column_base[x]..column_base[x] + b];
                cell_bins[lo] += mag[x] * (1.0 - frac);
                cell_bins[hi] += mag[x] * frac;
            }
        }
        hist
    }

    /// Mean opponent chromaticity of the object pixels in each quadrant of each patch.
    fn chromaticity(&self, crop: &CropInput, grid: PatchGrid) -> Vec<f32> {
        let n = grid.n as usize;
        let p = grid.patch as usize;
        let half = p / 2;
        let mut acc = vec![0f32; n * n * COLOR_DIMS];
        let mut weight = vec![0f32; n * n * 4];
        // Raw rows, and each column's patch and quadrant looked up rather than divided out
        // per pixel.
        let w = crop.rgb.width() as usize;
        let (rgb, mask) = (crop.rgb.as_raw(), crop.mask.as_raw());
        let columns: Vec<(usize, usize)> = (0..w).map(|x| (x / p, (x % p) / half)).collect();
        // Per row, every pixel's two opponent values first, in a loop without branches
        // (the divisions vectorise; background pixels' values are computed and not used),
        // then the object pixels' values added in column order.
        let mut opponent = vec![[0f32; 2]; w];
        for y in 0..crop.rgb.height() as usize {
            let (row_patch, row_quadrant) = ((y / p) * n, ((y % p) / half) * 2);
            // Only the row's run from its first to its last object pixel can add anything.
            let row_mask = &mask[y * w..(y + 1) * w];
            let Some((first, last)) = super::crop::nonzero_span(row_mask) else { continue };
            let (row_rgb, row_mask) = (&rgb[(y * w + first) * 3..(y * w + last + 1) * 3], &row_mask[first..=last]);
            let (columns, opponent) = (&columns[first..=last], &mut opponent[first..=last]);
            for ((o, px), &m) in opponent.iter_mut().zip(row_rgb.chunks_exact(3)).zip(row_mask) {
                // Undo the coverage premultiplication of edge pixels before taking ratios.
                let m = m as f32 / 255.0;
                let [r, g, bl] = [px[0], px[1], px[2]].map(|c| c as f32 / (255.0 * m));
                let sum = r + g + bl + 0.05;
                *o = [(r - g) / sum, (0.5 * (r + g) - bl) / sum];
            }
            for ((&(col_patch, col_quadrant), o), &m) in columns.iter().zip(opponent.iter()).zip(row_mask) {
                if (m as f32 / 255.0) < 0.5 {
                    continue;
                }
                let k = row_patch + col_patch;
                let q = row_quadrant + col_quadrant;
                acc[k * COLOR_DIMS + q * 2] += o[0];
                acc[k * COLOR_DIMS + q * 2 + 1] += o[1];
                weight[k * 4 + q] += 1.0;
            }
        }
        for k in 0..n * n {
            for q in 0..4 {
                let w = weight[k * 4 + q].max(1.0);
                acc[k * COLOR_DIMS + q * 2] /= w;
                acc[k * COLOR_DIMS + q * 2 + 1] /= w;
            }
        }
        acc
    }

    /// Object coverage in log-polar bins around every patch, L2-normalised per patch.
    fn shape_context(&self, coverage: &[f32]) -> Vec<f32> {
        let n = self.grid.n as usize;
        let d = SHAPE_RINGS.len() * SHAPE_SECTORS;
        // Only covered patches add to a bin; kept in grid order, so every sum is the full
        // scan's, bit for bit, at a fraction of the work (crops are mostly background).
        let covered: Vec<(usize, usize, f32)> = coverage.iter().enumerate().filter(|(_, c)| **c != 0.0).map(|(k, c)| (k / n, k % n, *c)).collect();
        // Only the covered patches' own contexts: the others' rows stay zero (`extract_one`).
        let patches: Vec<usize> = covered.iter().map(|&(i, j, _)| i * n + j).collect();
        let mut out = shape_bin_sums(&self.shape_bins, n, &covered, &patches);
        for &k in &patches {
            let o = &mut out[k * d..(k + 1) * d];
            // Bins that fall outside the crop count as background (their cells are 0).
            for (v, c) in o.iter_mut().zip(&self.shape_counts[k * d..(k + 1) * d]) {
                if *c > 0.0 {
                    *v /= *c;
                }
            }
            l2_normalize(o);
        }
        out
    }
}

/// For each of `patches` (indices into an `n`×`n` grid), the sums of `weights` (row,
/// column, weight) over each silhouette-context bin around it (`shape_bins`: the bin of
/// every offset), in the order given: `[patch][bin]` over the whole grid, zero for the
/// patches not asked for.
fn shape_bin_sums(shape_bins: &[usize], n: usize, weights: &[(usize, usize, f32)], patches: &[usize]) -> Vec<f32> {
    let (side, d) = (2 * n - 1, SHAPE_RINGS.len() * SHAPE_SECTORS);
    let mut out = vec![0f32; n * n * d];
    // Four patches at a time: neighbouring weights mostly fall in the same bin, so one
    // patch's sums are a chain of dependent additions; four patches' chains run side by
    // side. Each patch still adds its weights in the order given, so the sums are the
    // same bits as one patch at a time.
    const LANES: usize = 4;
    for group in patches.chunks(LANES) {
        // Where each patch's row of the bin table starts: patch (i, j) reads offset
        // (ii − i, jj − j), at `(ii + n − 1 − i) · side + jj + n − 1 − j`. A short last
        // group repeats its last patch in the spare lanes.
        let starts: [usize; LANES] = std::array::from_fn(|l| {
            let k = group[l.min(group.len() - 1)];
            (n - 1 - k / n) * side + n - 1 - k % n
        });
        let mut sums = [[0f32; SHAPE_RINGS.len() * SHAPE_SECTORS]; LANES];
        for &(ii, jj, w) in weights {
            let at = ii * side + jj;
            for (sum, start) in sums.iter_mut().zip(starts) {
                let bin = shape_bins[at + start];
                if bin != usize::MAX {
                    sum[bin] += w;
                }
            }
        }
        for (&k, sum) in group.iter().zip(&sums) {
            out[k * d..(k + 1) * d].copy_from_slice(sum);
        }
    }
    out
}

impl Backbone for EmbeddedBackbone {
    fn identity(&self) -> BackboneIdentity {
        let params = serde_json::to_string(&self.config).unwrap_or_default();
        let hash = Sha256::digest(format!("embedded-v1:{params}").as_bytes());
        BackboneIdentity {
            name: "embedded-hog-color-silhouette".into(),
            weights_hash: hash.iter().take(8).map(|b| format!("{b:02x}")).collect(),
            layers: "hog4x8+chroma8+silhouette24".into(),
            input_size: self.config.input_size,
            patch_size: self.config.patch_size,
            local_dim: self.local_dim() as u32,
            global_dim: self.local_dim() as u32,
        }
    }

    fn reduced_input_size(&self) -> Option<u32> {
        // Half-width patches need cells of at least a pixel (a cell is half a patch).
        (self.config.patch_size >= 4).then_some(self.config.input_size / 2)
    }

    fn extract(&self, crops: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError> {
        check_sizes(crops, self.config.input_size, self.reduced_input_size())?;
        Ok(crops.par_iter().map(|c| self.extract_one(c)).collect())
    }
}

/// atan2 within 2e-5 rad (Abramowitz & Stegun 4.4.49 on the octant, then reflected; the
/// bound is tested), without branches or a libm call per pixel, so the orientation pass
/// vectorises. Finite inputs, not both zero.
fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let a = ax.min(ay) / ax.max(ay).max(f32::MIN_POSITIVE);
    let s = a * a;
    let r = a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    let r = if ay > ax { FRAC_PI_2 - r } else { r };
    let r = if x < 0.0 { PI - r } else { r };
    if y < 0.0 {
        -r
    } else {
        r
    }
}

/// An angle in [-π, π] into [0, period) for a period of π or 2π, as `rem_euclid` does but
/// without its `fmod` call.
fn wrap_angle(a: f32, period: f32) -> f32 {
    let a = if a < 0.0 { a + period } else { a };
    if a >= period {
        a - period
    } else {
        a
    }
}

/// L2-normalise with a floor on the norm (so flat patches stay small instead of turning
/// noise into a unit vector), clip large components, renormalise (as SIFT does).
fn normalize_clipped(v: &mut [f32], clip: f32, floor: f32) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    let scale = 1.0 / n.max(floor);
    v.iter_mut().for_each(|x| *x = (*x * scale).min(clip));
    let n2 = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n2 > 1e-12 {
        let keep = (n / floor).min(1.0); // flat patches keep a proportionally small norm
        v.iter_mut().for_each(|x| *x *= keep / n2);
    }
}

/// One pass of the separable [1 2 1]/4 filter with clamped borders.
fn binomial_blur(img: &mut [f32], s: usize) {
    if s == 0 {
        return;
    }
    let mut tmp = vec![0f32; img.len()];
    for y in 0..s {
        let r = &img[y * s..(y + 1) * s];
        let t = &mut tmp[y * s..(y + 1) * s];
        // The two ends clamp; between them, three shifted slices (a loop that vectorises).
        for x in [0, s - 1] {
            t[x] = 0.25 * r[x.saturating_sub(1)] + 0.5 * r[x] + 0.25 * r[(x + 1).min(s - 1)];
        }
        if s > 2 {
            for (((t, a), b), c) in t[1..s - 1].iter_mut().zip(&r[..s - 2]).zip(&r[1..s - 1]).zip(&r[2..]) {
                *t = 0.25 * a + 0.5 * b + 0.25 * c;
            }
        }
    }
    for y in 0..s {
        let (up, dn) = (y.saturating_sub(1), (y + 1).min(s - 1));
        let (a, b, c) = (&tmp[up * s..(up + 1) * s], &tmp[y * s..(y + 1) * s], &tmp[dn * s..(dn + 1) * s]);
        for (((o, a), b), c) in img[y * s..(y + 1) * s].iter_mut().zip(a).zip(b).zip(c) {
            *o = 0.25 * a + 0.5 * b + 0.25 * c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{GrayImage, RgbImage};

    fn disc_crop(size: u32, color: [u8; 3]) -> CropInput {
        let mut rgb = RgbImage::new(size, size);
        let mut mask = GrayImage::new(size, size);
        let c = size as f32 / 2.0;
        for (x, y, p) in rgb.enumerate_pixels_mut() {
            let (dx, dy) = (x as f32 - c, y as f32 - c);
            if dx * dx + dy * dy < (size as f32 * 0.3).powi(2) {
                // Stripes give the inside some gradient texture.
                *p = if (x / 8) % 2 == 0 { image::Rgb(color) } else { image::Rgb([color[0] / 2, color[1] / 2, color[2] / 2]) };
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        CropInput { rgb, mask }
    }

    #[test]
    fn shape_bin_sums_are_each_patchs_sums_in_the_order_given() {
        // Grids whose patch count is and is not a multiple of the four patches summed
        // together; uneven weights, so that another order of addition would show in the bits.
        for n in [5usize, 8] {
            let backbone = EmbeddedBackbone::new(EmbeddedConfig { input_size: 16 * n as u32, ..EmbeddedConfig::default() }).unwrap();
            let weights: Vec<(usize, usize, f32)> = (0..n * n).filter(|k| k % 3 != 1).map(|k| (k / n, k % n, 1.0 / (1.0 + k as f32 * 0.37))).collect();
            let (side, d) = (2 * n - 1, SHAPE_RINGS.len() * SHAPE_SECTORS);
            let mut expected = vec![0f32; n * n * d];
            for (k, o) in expected.chunks_exact_mut(d).enumerate() {
                for &(ii, jj, w) in &weights {
                    let bin = backbone.shape_bins[(ii + n - 1 - k / n) * side + jj + n - 1 - k % n];
                    if bin != usize::MAX {
                        o[bin] += w;
                    }
                }
            }
            let every: Vec<usize> = (0..n * n).collect();
            let got = shape_bin_sums(&backbone.shape_bins, n, &weights, &every);
            assert_eq!(got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), expected.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "n = {n}");
            // A subset (seven patches: a group of four and a short one) gets the same rows,
            // and the rest zeros.
            let some: Vec<usize> = every.iter().copied().filter(|k| k % 4 == 2).take(7).collect();
            let got = shape_bin_sums(&backbone.shape_bins, n, &weights, &some);
            for (k, (g, e)) in got.chunks_exact(d).zip(expected.chunks_exact(d)).enumerate() {
                let want: Vec<u32> = if some.contains(&k) { e.iter().map(|v| v.to_bits()).collect() } else { vec![0; d] };
                assert_eq!(g.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want, "n = {n}, patch {k}");
            }
        }
    }

    #[test]
    fn gradients_are_read_only_where_the_rows_around_are_lit_and_give_the_full_rows_histograms() {
        // A disc with a wide black margin, and one lit pixel alone in a far row and column:
        // the histograms must be those of every column of every row.
        let backbone = EmbeddedBackbone::new(EmbeddedConfig { input_size: 64, ..EmbeddedConfig::default() }).unwrap();
        let mut crop = disc_crop(64, [200, 120, 40]);
        crop.rgb.put_pixel(60, 3, image::Rgb([255, 255, 255]));
        let got = backbone.cell_histograms(&crop, backbone.grid);
        let (s, cell, b) = (64usize, (backbone.config.patch_size / 2) as usize, backbone.config.orientation_bins);
        let mut lum: Vec<f32> = crop.rgb.pixels().map(|p| crate::features::grey(p) / 255.0).collect();
        for _ in 0..backbone.config.smoothing_passes {
            binomial_blur(&mut lum, s);
        }
        let period = if backbone.config.signed_orientation { std::f32::consts::TAU } else { std::f32::consts::PI };
        let mut expected = vec![0f32; (s / cell) * (s / cell) * b];
        for y in 1..s - 1 {
            for x in 1..s - 1 {
                let (gx, gy) = (lum[y * s + x + 1] - lum[y * s + x - 1], lum[(y + 1) * s + x] - lum[(y - 1) * s + x]);
                let m = (gx * gx + gy * gy).sqrt();
                if m < 1e-4 {
                    continue;
                }
                let pos = wrap_angle(fast_atan2(gy, gx), period) * (b as f32 / period);
                let lo = (pos as usize) % b;
                let frac = pos - (pos as usize) as f32;
                let bins = &mut expected[((y / cell) * (s / cell) + x / cell) * b..][..b];
                bins[lo] += m * (1.0 - frac);
                bins[(lo + 1) % b] += m * frac;
            }
        }
        assert!(expected.iter().filter(|&&v| v > 0.0).count() > 20);
        assert_eq!(got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), expected.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    }

    /// A photo of a textured object (an ellipse with colour regions, stripes and a
    /// gradient) 140 px across on a 320×240 frame, and its mask.
    fn textured_photo() -> (RgbImage, GrayImage) {
        let (mut rgb, mut mask) = (RgbImage::new(320, 240), GrayImage::new(320, 240));
        for (x, y, p) in rgb.enumerate_pixels_mut() {
            let (u, v) = ((x as f32 - 160.0) / 70.0, (y as f32 - 120.0) / 50.0);
            if u * u + v * v >= 1.0 {
                continue;
            }
            mask.put_pixel(x, y, image::Luma([255]));
            let stripe = ((u * 3.0 + v * 2.0).sin() > 0.3) as u8;
            let base = if u < -0.2 {
                [180u8, 60, 40]
            } else if v > 0.3 {
                [40, 90, 170]
            } else {
                [200, 190, 60]
            };
            let shade = (0.6 + 0.4 * (1.0 - v.abs())) * if stripe == 1 { 0.55 } else { 1.0 };
            *p = image::Rgb(base.map(|c| (c as f32 * shade) as u8));
        }
        (rgb, mask)
    }

    #[test]
    fn a_reduced_crop_gives_the_full_crops_descriptors_patch_for_patch() {
        // What a turned query encoded small relies on: its rows meet the rows of the same
        // patches encoded at full size (the templates') as their nearest neighbours.
        let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
        let reduced = backbone.reduced_input_size().unwrap();
        assert_eq!(reduced * 2, backbone.config.input_size);
        let (photo, mask) = textured_photo();
        let crop_at = |size| {
            let b = crate::geometry::CropBox::around_edges(90.0, 70.0, 230.0, 170.0, 0.1, size);
            crate::features::sample_crop(&photo, &mask, &b, crate::features::ToSource::Shift(0.0, 0.0))
        };
        let maps = backbone.extract(&[crop_at(backbone.config.input_size), crop_at(reduced)]).unwrap();
        let (full, small) = (&maps[0], &maps[1]);
        assert_eq!((small.grid.n, small.grid.patch * 2), (full.grid.n, full.grid.patch));
        let foreground = full.foreground(0.5);
        assert!(foreground.len() > 200, "{} foreground patches", foreground.len());
        let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        let (mut same, mut cosines) = (0, Vec::new());
        for &k in &foreground {
            let row = small.descriptor(k);
            cosines.push(dot(row, full.descriptor(k)));
            let nearest = foreground.iter().copied().max_by(|&a, &b| dot(row, full.descriptor(a)).total_cmp(&dot(row, full.descriptor(b)))).unwrap();
            same += (nearest == k) as usize;
        }
        cosines.sort_by(f32::total_cmp);
        let median = cosines[cosines.len() / 2];
        let share = same as f32 / foreground.len() as f32;
        // Measured 0.9999 and 0.99; without the gradients' gain (the norm floor meaning
        // something else at half size) 0.994 and 0.88.
        assert!(median > 0.999 && share > 0.95, "median cosine {median}, nearest the same patch for {share} of the patches");
    }

    #[test]
    fn blurring_clamps_at_the_borders_and_averages_121_between() {
        let s = 5;
        let img: Vec<f32> = (0..s * s).map(|i| ((i * 7) % 11) as f32).collect();
        let mut blurred = img.clone();
        binomial_blur(&mut blurred, s);
        let at = |x: i64, y: i64| img[(y.clamp(0, s as i64 - 1) as usize) * s + x.clamp(0, s as i64 - 1) as usize];
        for y in 0..s as i64 {
            for x in 0..s as i64 {
                let row = |y| 0.25 * at(x - 1, y) + 0.5 * at(x, y) + 0.25 * at(x + 1, y);
                let expected = 0.25 * row(y - 1) + 0.5 * row(y) + 0.25 * row(y + 1);
                assert_eq!(blurred[y as usize * s + x as usize].to_bits(), expected.to_bits(), "({x}, {y})");
            }
        }
    }

    #[test]
    fn fast_atan2_is_within_its_bound_all_round() {
        let mut worst = 0f32;
        for i in 0..3600 {
            let t = i as f32 * std::f32::consts::TAU / 3600.0;
            for r in [1e-4f32, 0.01, 1.0, 300.0] {
                let (y, x) = (r * t.sin(), r * t.cos());
                worst = worst.max((fast_atan2(y, x) - y.atan2(x)).abs());
            }
        }
        // Axis directions exactly, where the octant reflections meet.
        for (y, x) in [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (1.0, 1.0), (-1.0, -1.0)] {
            worst = worst.max((fast_atan2(y, x) - f32::atan2(y, x)).abs());
        }
        assert!(worst < 2e-5, "largest error {worst} rad");
    }

    #[test]
    fn wrapped_angles_fall_in_the_period_as_rem_euclid_puts_them() {
        use std::f32::consts::{PI, TAU};
        for period in [PI, TAU] {
            for a in [-PI, -PI / 2.0, -1e-7, 0.0, 1.0, PI / 2.0, PI - 1e-6, PI] {
                let w = wrap_angle(a, period);
                assert!((0.0..period).contains(&w), "{a} mod {period} gave {w}");
                assert!((w - a.rem_euclid(period)).abs() < 1e-6 || (w - a.rem_euclid(period)).abs() > period - 1e-6, "{a} mod {period}: {w}");
            }
        }
    }

    #[test]
    fn descriptors_are_normalised_and_deterministic() {
        let bb = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
        let crops = vec![disc_crop(512, [200, 50, 50]), disc_crop(512, [50, 50, 200])];
        let a = bb.extract(&crops).unwrap();
        let b = bb.extract(&crops).unwrap();
        assert_eq!(a[0].local, b[0].local);
        assert_eq!(a[0].local_dim, bb.local_dim());
        let fg = a[0].foreground(0.5);
        assert!(fg.len() > 200 && fg.len() < 400, "{} foreground patches", fg.len());
        for &k in &fg {
            let n: f32 = a[0].descriptor(k).iter().map(|x| x * x).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
        // Patches the mask touches at all are described; the rest keep zero rows (no
        // reader takes them).
        for (k, &c) in a[0].coverage.iter().enumerate() {
            let n: f32 = a[0].descriptor(k).iter().map(|x| x * x).sum();
            assert!(if c > 0.0 { (n - 1.0).abs() < 1e-4 } else { n == 0.0 }, "patch {k}, coverage {c}: |row|² {n}");
        }
        let g: f32 = a[0].global.iter().map(|x| x * x).sum();
        assert!((g - 1.0).abs() < 1e-4);
        // Different colours change the descriptors of the same shape.
        assert_ne!(a[0].global, a[1].global);
    }

    #[test]
    fn wrong_crop_size_is_an_error() {
        let bb = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
        // The reduced size passes; others, and a non-square crop, are refused by name.
        assert_eq!(bb.extract(&[disc_crop(256, [1, 2, 3])]).unwrap()[0].grid.n, 32);
        let err = bb.extract(&[disc_crop(512, [1, 2, 3]), disc_crop(300, [1, 2, 3])]).unwrap_err();
        assert!(err.to_string().contains("crop 1 is 300×300"), "{err}");
        let mut wide = disc_crop(512, [1, 2, 3]);
        wide.rgb = RgbImage::new(512, 256);
        assert!(matches!(bb.extract(&[wide]), Err(FeatureError::WrongSize { width: 512, height: 256, .. })));
    }

    #[test]
    fn identity_changes_with_parameters() {
        let a = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap().identity();
        let b = EmbeddedBackbone::new(EmbeddedConfig { color_weight: 0.0, ..Default::default() }).unwrap().identity();
        assert_ne!(a.weights_hash, b.weights_hash);
        assert_eq!(a.local_dim, 64);
    }
}
