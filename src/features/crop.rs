//! Resampling an image window into a square crop with its mask, background blacked out:
//! templates and queries go through the same function so they look alike to a backbone.

use crate::geometry::pixel::floor_i64;
use crate::geometry::{CropBox, Turn};
use image::{GrayImage, RgbImage};
use rayon::prelude::*;

/// A square crop ready for a backbone: RGB with the background set to black, and the
/// mask (255 = object) at the same resolution.
#[derive(Clone, Debug)]
pub struct CropInput {
    pub rgb: RgbImage,
    pub mask: GrayImage,
}

impl CropInput {
    pub fn size(&self) -> u32 {
        self.rgb.width()
    }
}

/// Bounding box (min_u, min_v, max_u, max_v) of the nonzero mask pixels; `None` if empty.
pub fn mask_bbox(mask: &GrayImage) -> Option<(u32, u32, u32, u32)> {
    let (w, h) = mask.dimensions();
    let (mut lo_u, mut lo_v, mut hi_u, mut hi_v) = (u32::MAX, u32::MAX, 0, 0);
    let raw = mask.as_raw();
    for v in 0..h {
        let row = &raw[(v * w) as usize..((v + 1) * w) as usize];
        if let Some((first, last)) = nonzero_span(row) {
            lo_u = lo_u.min(first as u32);
            hi_u = hi_u.max(last as u32);
            lo_v = lo_v.min(v);
            hi_v = v;
        }
    }
    (lo_u != u32::MAX).then_some((lo_u, lo_v, hi_u, hi_v))
}

/// The first and last nonzero value of `row` (a mask's or a black-backed image's row);
/// `None` when all are zero.
pub fn nonzero_span<T: Copy + PartialEq + Default>(row: &[T]) -> Option<(usize, usize)> {
    let first = row.iter().position(|&v| v != T::default())?;
    let last = row.iter().rposition(|&v| v != T::default())?;
    Some((first, last))
}

/// Grey level (0–255) of an sRGB pixel, Rec. 601 weights: what every image comparison
/// here (verification's edges, the tracker's photometric term, the embedded descriptor,
/// the contour refiner's photo edges) reads of a colour.
pub fn grey(p: &image::Rgb<u8>) -> f32 {
    0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32
}

/// The first and last nonzero pixel of each row of `mask` (x, y): a turned mask's extents
/// are those of these points, since a pixel between two others of its row is never
/// extreme in any direction. Empty for an empty mask.
pub fn mask_row_ends(mask: &GrayImage) -> Vec<(f64, f64)> {
    let w = mask.width() as usize;
    mask.as_raw()
        .chunks_exact(w.max(1))
        .enumerate()
        .filter_map(|(v, row)| {
            let (first, last) = nonzero_span(row)?;
            Some([(first as f64, v as f64), (last as f64, v as f64)])
        })
        .flatten()
        .collect()
}

/// Where a crop's sample points fall in the source image.
#[derive(Clone, Copy)]
pub enum ToSource {
    /// Source = image coordinates − (dx, dy): a query (0, 0) or a render of a window.
    Shift(f64, f64),
    /// Source = the image coordinates turned (an in-plane-turned template, a query turned
    /// to meet one).
    Turned(Turn),
}

/// Samples the crop `b` of `rgb`/`mask`. `to_source` maps image coordinates of the crop's
/// frame to source pixel coordinates. When the crop shrinks the source, each crop pixel
/// averages a grid of sub-samples so that thin edges are not aliased.
pub fn sample_crop(rgb: &RgbImage, mask: &GrayImage, b: &CropBox, to_source: ToSource) -> CropInput {
    let (mut out_rgb, mut out_mask) = (RgbImage::new(b.size, b.size), GrayImage::new(b.size, b.size));
    // No object pixel in the source: every tap is mask-weighted, so the crop stays black
    // and empty, and nothing needs sampling.
    let Some(drawn) = mask_bbox(mask) else {
        return CropInput { rgb: out_rgb, mask: out_mask };
    };
    let size = b.size as usize;
    let sub = b.scale().ceil().clamp(1.0, 4.0) as usize;
    let source = Source { rgb: rgb.as_raw(), mask: mask.as_raw(), w: rgb.width() as i64, h: rgb.height() as i64 };
    let offsets: Vec<f64> = (0..sub).map(|k| (k as f64 + 0.5) / sub as f64 - 0.5).collect();
    // A shift moves columns and rows independently: each column's and each row's taps are
    // found once (the same arithmetic as `to_image`, so the same points).
    let taps = |origin: f64, shift: f64| -> Vec<(i64, f32)> {
        let s = b.scale();
        (0..size).flat_map(|c| offsets.iter().map(move |&d| Source::tap(origin + ((c as f64 + d) + 0.5) * s - shift))).collect()
    };
    let plan = match to_source {
        ToSource::Shift(dx, dy) => Plan::Separable { columns: taps(b.origin_u, dx), rows: taps(b.origin_v, dy) },
        ToSource::Turned(turn) => Plan::Turned(turn),
    };
    let inv = 1.0 / (sub * sub) as f32;
    // Bands of crop rows on all cores: every output pixel depends on the source alone.
    let band = (size * CROP_ROWS_PER_BAND).max(1);
    let bands = out_rgb.par_chunks_mut(3 * band).zip(out_mask.par_chunks_mut(band)).enumerate();
    bands.for_each(|(i, (band_rgb, band_mask))| {
        let crop_rows = i * CROP_ROWS_PER_BAND..i * CROP_ROWS_PER_BAND + band_mask.len() / size.max(1);
        let sums = match &plan {
            Plan::Separable { columns, rows } => source.separable_sums(size, sub, columns, &rows[crop_rows.start * sub..crop_rows.end * sub], drawn),
            // Where the source has no object pixel, nothing is sampled (`mapped_sums`).
            Plan::Turned(turn) => source.mapped_sums(size, crop_rows, &offsets, (b, drawn), |u, v| turn.apply(u, v)),
        };
        for ((acc, px), m) in sums.iter().zip(band_rgb.chunks_exact_mut(3)).zip(band_mask.iter_mut()) {
            // No coverage: every tap added 0 (they are mask-weighted), and the output
            // starts black and empty.
            if acc[3] == 0.0 {
                continue;
            }
            // Premultiplied: background black, edge pixels darkened by their coverage.
            // Values are ≥ 0, so adding ½ and truncating rounds as `round` does (the
            // saturating cast clamps), without a libm call per channel. The four at once,
            // so that they convert as one vector.
            let levels = [acc[0] * inv + 0.5, acc[1] * inv + 0.5, acc[2] * inv + 0.5, acc[3] * inv * 255.0 + 0.5].map(|x| x as u8);
            px.copy_from_slice(&levels[..3]);
            *m = levels[3];
        }
    });
    CropInput { rgb: out_rgb, mask: out_mask }
}

/// How `sample_crop` finds its taps: per column and per row, or per sample point.
enum Plan {
    Separable { columns: Vec<(i64, f32)>, rows: Vec<(i64, f32)> },
    Turned(Turn),
}

/// Crop rows per band of `sample_crop`: a band's source rows are interpolated once for
/// all its crop rows (`Source::separable_sums`), and a row two bands read is interpolated
/// by both.
const CROP_ROWS_PER_BAND: usize = 32;

/// The source image's raw rows, read by index (no `get_pixel` with its own checks per tap).
struct Source<'a> {
    rgb: &'a [u8],
    mask: &'a [u8],
    w: i64,
    h: i64,
}

impl Source<'_> {
    /// A coordinate's first bilinear tap and its weight towards the second.
    #[inline]
    fn tap(x: f64) -> (i64, f32) {
        let x0 = floor_i64(x);
        (x0, (x - x0 as f64) as f32)
    }

    /// The sums (mask-weighted RGB and mask coverage) of each pixel of crop rows
    /// `crop_rows` over its `offsets`² sample points, each point mapped to the source on
    /// its own: crop to image by `b`, image to source by `map` (a type, not a `dyn`, so
    /// that it is inlined: onboarding crops 1944 turned templates of some 200 000 sample
    /// points each). `map` is affine (a turn), so each crop row meets the source's `drawn`
    /// box (its object pixels' bounds) in one run of columns: only those are sampled, since
    /// every tap of the others reads background (a template's crop is mostly margin).
    fn mapped_sums(&self, size: usize, crop_rows: std::ops::Range<usize>, offsets: &[f64], (b, drawn): (&CropBox, (u32, u32, u32, u32)), map: impl Fn(f64, f64) -> (f64, f64)) -> Vec<[f32; 4]> {
        let mut sums = vec![[0f32; 4]; crop_rows.len() * size];
        // A sample point within half a crop pixel of a pixel's centre per axis lands within
        // 0.71 × scale source pixels of the centre's point (turned), and its taps read the
        // box only from within one pixel of it; one more pixel for rounding.
        let reach = 0.71 * b.scale() + 2.0;
        let (lo, hi) = ((drawn.0 as f64 - reach, drawn.1 as f64 - reach), (drawn.2 as f64 + reach, drawn.3 as f64 + reach));
        let mut taps = Vec::with_capacity(size);
        for (cv, row) in crop_rows.zip(sums.chunks_mut(size.max(1))) {
            let point = |cu: f64| {
                let (iu, iv) = b.to_image(cu, cv as f64);
                map(iu, iv)
            };
            let (start, end) = columns_within(point(0.0), point(1.0), lo, hi, size);
            if let [0.0] = offsets {
                // One sample per crop pixel (every template: their crops enlarge their
                // source): the row's taps first, in a loop of arithmetic alone, then the
                // reads. The map is affine, so the points step along the row; they differ
                // from the general loop's by rounding (~1e-13 px), far below what moves a
                // tap or its f32 weight (the tests compare bytes with the reference, and
                // onboarding stored the same tensors).
                taps.clear();
                let ((u0, v0), (u1, v1)) = (point(start as f64), point(start as f64 + 1.0));
                let (du, dv) = (u1 - u0, v1 - v0);
                taps.extend((0..end - start).map(|k| (Self::tap(u0 + k as f64 * du), Self::tap(v0 + k as f64 * dv))));
                for (acc, &((u0, fu), (v0, fv))) in row[start..end].iter_mut().zip(&taps) {
                    self.add_taps(u0, fu, v0, fv, acc);
                }
                continue;
            }
            for (cu, acc) in row.iter_mut().enumerate().take(end).skip(start) {
                for &dv in offsets {
                    for &du in offsets {
                        let (iu, iv) = b.to_image(cu as f64 + du, cv as f64 + dv);
                        let (su, sv) = map(iu, iv);
                        let ((u0, fu), (v0, fv)) = (Self::tap(su), Self::tap(sv));
                        self.add_taps(u0, fu, v0, fv, acc);
                    }
                }
            }
        }
        sums
    }

    /// The same sums for the crop rows whose row taps are `rows` (`sub` per crop row),
    /// each crop column sampling the source at its own `sub` column taps: bilinear
    /// interpolation is separable, so every source row the rows read is first interpolated
    /// at the column taps (once, however many crop rows read it), and each crop pixel then
    /// blends those rows: about a third of the per-tap work of `mapped_sums` for a crop
    /// that enlarges its source. Equal to it up to float rounding (`tests`: within one
    /// level of 255). Only the source rows read are interpolated, so memory stays a few
    /// rows per band however large the source and its window; and only the rows and the
    /// crop columns whose taps reach `drawn` (the source mask's bounds, inclusive): every
    /// other tap reads background and adds nothing, and a render judged in verification
    /// is mostly background around the object (the sums are the same to the bit).
    fn separable_sums(&self, size: usize, sub: usize, columns: &[(i64, f32)], rows: &[(i64, f32)], drawn: (u32, u32, u32, u32)) -> Vec<[f32; 4]> {
        let mut sums = vec![[0f32; 4]; rows.len() / sub * size];
        let (x0, y0, x1, y1) = (drawn.0 as i64, drawn.1 as i64, drawn.2 as i64, drawn.3 as i64);
        // The source rows read (each tap reads v0 and v0 + 1) where the object is.
        let mut read: Vec<i64> = rows.iter().flat_map(|&(v0, _)| [v0, v0.saturating_add(1)]).filter(|&y| y >= y0.max(0) && y <= y1.min(self.h - 1)).collect();
        read.sort_unstable();
        read.dedup();
        // The crop columns one of whose taps (u0 or u0 + 1) lands in the object's columns;
        // the taps move one way along the row, so those columns are one run.
        let reaches = |cu: usize| columns[cu * sub..(cu + 1) * sub].iter().any(|&(u0, _)| u0.saturating_add(1) >= x0 && u0 <= x1);
        let from = (0..size).find(|&cu| reaches(cu)).unwrap_or(size);
        let to = (from..size).rfind(|&cu| reaches(cu)).map_or(from, |cu| cu + 1);
        let mut across = vec![[0f32; 4]; read.len() * size];
        for (&y, row) in read.iter().zip(across.chunks_mut(size.max(1))) {
            for (cu, acc) in row.iter_mut().enumerate().take(to).skip(from) {
                for &(u0, fu) in &columns[cu * sub..(cu + 1) * sub] {
                    self.add_pixel(u0, y, 1.0 - fu, acc);
                    self.add_pixel(u0.saturating_add(1), y, fu, acc);
                }
            }
        }
        for (crop_row, out) in rows.chunks(sub).zip(sums.chunks_mut(size.max(1))) {
            for &(v0, fv) in crop_row {
                for (y, wgt) in [(v0, 1.0 - fv), (v0.saturating_add(1), fv)] {
                    let Some(r) = read.binary_search(&y).ok().filter(|_| wgt != 0.0) else { continue };
                    for (acc, a) in out[from..to].iter_mut().zip(&across[r * size + from..r * size + to]) {
                        for k in 0..4 {
                            acc[k] += a[k] * wgt;
                        }
                    }
                }
            }
        }
        sums
    }

    /// Adds source pixel (x, y)'s mask-weighted RGB and coverage, times `wgt`; nothing
    /// outside the image or on background (0 × anything, to sums that are ≥ 0).
    #[inline]
    fn add_pixel(&self, x: i64, y: i64, wgt: f32, acc: &mut [f32; 4]) {
        if wgt == 0.0 || x < 0 || y < 0 || x >= self.w || y >= self.h {
            return;
        }
        let i = (y * self.w + x) as usize;
        if self.mask[i] != 0 {
            self.add_at(i, wgt, acc);
        }
    }

    /// Adds the bilinear sample at (u0 + fu, v0 + fv) of mask-weighted RGB (0..255) and mask
    /// coverage (0..1) to `acc`; taps outside the image count as background.
    #[inline(always)]
    fn add_taps(&self, u0: i64, fu: f32, v0: i64, fv: f32, acc: &mut [f32; 4]) {
        let taps = [(0, 0, (1.0 - fu) * (1.0 - fv)), (1, 0, fu * (1.0 - fv)), (0, 1, (1.0 - fu) * fv), (1, 1, fu * fv)];
        if u0 >= 0 && v0 >= 0 && u0 + 1 < self.w && v0 + 1 < self.h {
            // All four inside: one index, and a sample of background (most of a crop's
            // margin) ends at four mask bytes. The taps that remain add in the same order
            // as `add_pixel`'s, so the sums are the same bits.
            let i = (v0 * self.w + u0) as usize;
            let at = [i, i + 1, i + self.w as usize, i + self.w as usize + 1];
            let coverage = at.map(|j| self.mask[j]);
            if coverage == [0; 4] {
                return;
            }
            if coverage == [255; 4] {
                // Inside the object (most of a template's sampled pixels): each tap's
                // coverage weight is `255 / 255 · wgt = wgt` exactly, and a tap of weight
                // 0 adds 0 to sums that are ≥ 0, so these are `add_at`'s bits without its
                // per-tap tests and conversions.
                for (j, (_, _, wgt)) in at.into_iter().zip(taps) {
                    acc[0] += self.rgb[3 * j] as f32 * wgt;
                    acc[1] += self.rgb[3 * j + 1] as f32 * wgt;
                    acc[2] += self.rgb[3 * j + 2] as f32 * wgt;
                    acc[3] += wgt;
                }
                return;
            }
            for (j, (_, _, wgt)) in at.into_iter().zip(taps) {
                if wgt != 0.0 && self.mask[j] != 0 {
                    self.add_at(j, wgt, acc);
                }
            }
            return;
        }
        for (du, dv, wgt) in taps {
            self.add_pixel(u0.saturating_add(du), v0.saturating_add(dv), wgt, acc);
        }
    }

    /// Adds raw pixel `i`'s mask-weighted RGB and coverage, times `wgt`.
    #[inline]
    fn add_at(&self, i: usize, wgt: f32, acc: &mut [f32; 4]) {
        let m = self.mask[i] as f32 / 255.0 * wgt;
        acc[0] += self.rgb[3 * i] as f32 * m;
        acc[1] += self.rgb[3 * i + 1] as f32 * m;
        acc[2] += self.rgb[3 * i + 2] as f32 * m;
        acc[3] += m;
    }
}

/// The columns `start..end` of `0..size` whose points `p0 + cu · (p1 − p0)` (an affine
/// row of sample points) lie within the box `lo`–`hi`, one column wider each side for
/// rounding; empty when none does.
fn columns_within(p0: (f64, f64), p1: (f64, f64), lo: (f64, f64), hi: (f64, f64), size: usize) -> (usize, usize) {
    let (mut from, mut to) = (f64::NEG_INFINITY, f64::INFINITY);
    for (start, step, lo, hi) in [(p0.0, p1.0 - p0.0, lo.0, hi.0), (p0.1, p1.1 - p0.1, lo.1, hi.1)] {
        if step.abs() < 1e-12 {
            if start < lo || start > hi {
                return (0, 0);
            }
            continue;
        }
        let (a, b) = ((lo - start) / step, (hi - start) / step);
        from = from.max(a.min(b));
        to = to.min(a.max(b));
    }
    if from > to {
        return (0, 0);
    }
    let start = (from.floor() - 1.0).clamp(0.0, size as f64) as usize;
    let end = (to.ceil() + 2.0).clamp(0.0, size as f64) as usize;
    (start, end.max(start))
}

/// Crop of a query image around its mask, with `padding` (fraction of the box side).
pub fn crop_query(rgb: &RgbImage, mask: &GrayImage, padding: f64, size: u32) -> Option<(CropInput, CropBox)> {
    let (a, b, c, d) = mask_bbox(mask)?;
    let bx = CropBox::around(a, b, c, d, padding, size);
    Some((sample_crop(rgb, mask, &bx, ToSource::Shift(0.0, 0.0)), bx))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first form of `sample_crop` (per-pixel `get_pixel`, libm rounding), kept to
    /// check that the faster one gives the same bytes.
    fn reference_crop(rgb: &RgbImage, mask: &GrayImage, b: &CropBox, to_source: &dyn Fn(f64, f64) -> (f64, f64)) -> CropInput {
        let sub = b.scale().ceil().clamp(1.0, 4.0) as u32;
        let (mut out_rgb, mut out_mask) = (RgbImage::new(b.size, b.size), GrayImage::new(b.size, b.size));
        let inv = 1.0 / (sub * sub) as f32;
        let (w, h) = (rgb.width() as i64, rgb.height() as i64);
        for cv in 0..b.size {
            for cu in 0..b.size {
                let mut acc = [0f32; 4];
                for sy in 0..sub {
                    for sx in 0..sub {
                        let (du, dv) = ((sx as f64 + 0.5) / sub as f64 - 0.5, (sy as f64 + 0.5) / sub as f64 - 0.5);
                        let (iu, iv) = b.to_image(cu as f64 + du, cv as f64 + dv);
                        let (u, v) = to_source(iu, iv);
                        let (u0, v0) = (u.floor() as i64, v.floor() as i64);
                        let (fu, fv) = ((u - u0 as f64) as f32, (v - v0 as f64) as f32);
                        for (dx, dy, wgt) in [(0, 0, (1.0 - fu) * (1.0 - fv)), (1, 0, fu * (1.0 - fv)), (0, 1, (1.0 - fu) * fv), (1, 1, fu * fv)] {
                            let (x, y) = (u0 + dx, v0 + dy);
                            if wgt == 0.0 || x < 0 || y < 0 || x >= w || y >= h {
                                continue;
                            }
                            let m = mask.get_pixel(x as u32, y as u32)[0] as f32 / 255.0 * wgt;
                            let p = rgb.get_pixel(x as u32, y as u32);
                            for k in 0..3 {
                                acc[k] += p[k] as f32 * m;
                            }
                            acc[3] += m;
                        }
                    }
                }
                out_rgb.put_pixel(cu, cv, image::Rgb([acc[0] * inv, acc[1] * inv, acc[2] * inv].map(|c| c.round().clamp(0.0, 255.0) as u8)));
                out_mask.put_pixel(cu, cv, image::Luma([(acc[3] * inv * 255.0).round() as u8]));
            }
        }
        CropInput { rgb: out_rgb, mask: out_mask }
    }

    #[test]
    fn fast_crop_gives_the_reference_bytes() {
        // A textured image with a soft-edged mask, cropped at shrinking and enlarging
        // scales, partly outside the image, straight and rotated; the last two crops span
        // several bands of the separable path.
        let (w, h) = (97u32, 71u32);
        let rgb = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7 + y * 3) as u8, (x * y) as u8, (255 - x * 2) as u8]));
        let mask = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if (x as i64 - 40).pow(2) + (y as i64 - 30).pow(2) < 600 {
                255
            } else if x % 5 == 0 {
                90
            } else {
                0
            }])
        });
        for (a, b, c, d, pad, size) in [(10, 5, 80, 60, 0.2, 24), (30, 20, 50, 40, 0.1, 64), (0, 0, 96, 70, 0.5, 16), (60, 40, 96, 70, 0.3, 20), (0, 0, 96, 70, 0.1, 40), (20, 10, 70, 60, 0.1, 100)] {
            let bx = CropBox::around(a, b, c, d, pad, size);
            for angle in [0.0, 0.4, -2.0] {
                let turn = Turn::new(angle, [48.0, 35.0]);
                let (fast, slow) = (sample_crop(&rgb, &mask, &bx, ToSource::Turned(turn)), reference_crop(&rgb, &mask, &bx, &|u, v| turn.apply(u, v)));
                assert_eq!((fast.rgb.as_raw(), fast.mask.as_raw()), (slow.rgb.as_raw(), slow.mask.as_raw()), "box {:?}, angle {angle}", (a, b, c, d, pad, size));
            }
            // The separable path of a shift, against the same shift as a map: the same
            // sums in another order, so a level apart at most where one lands on a half.
            for (dx, dy) in [(0.0, 0.0), (3.0, -7.0), (-0.25, 12.5)] {
                let f = move |u: f64, v: f64| (u - dx, v - dy);
                let (fast, slow) = (sample_crop(&rgb, &mask, &bx, ToSource::Shift(dx, dy)), reference_crop(&rgb, &mask, &bx, &f));
                let pairs = fast.rgb.as_raw().iter().zip(slow.rgb.as_raw()).chain(fast.mask.as_raw().iter().zip(slow.mask.as_raw()));
                let (worst, differ) = pairs.fold((0, 0), |(w, n), (x, y)| (w.max(x.abs_diff(*y)), n + (x != y) as usize));
                assert!(worst <= 1 && differ * 100 <= fast.mask.len(), "box {:?}, shift {:?}: {differ} values differ, by up to {worst}", (a, b, c, d, pad, size), (dx, dy));
            }
        }
    }

    #[test]
    fn crops_sample_only_where_the_object_can_be_and_give_the_reference_bytes() {
        // An object (a soft-edged disc) in a corner of its source, as a template's render
        // has it in its middle: the turned crops skip the columns that miss its box and
        // must still be the reference's bytes, shrinking, enlarging, turned every way, the
        // disc near the source's edge, and an empty mask.
        let (w, h) = (120u32, 90u32);
        let rgb = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 7 + y * 3) as u8, (x * y) as u8, (255 - x * 2) as u8]));
        let disc = |cx: i64, cy: i64, r2: i64| {
            GrayImage::from_fn(w, h, move |x, y| {
                let d = (x as i64 - cx).pow(2) + (y as i64 - cy).pow(2);
                image::Luma([if d < r2 {
                    255
                } else if d < r2 + 60 {
                    120
                } else {
                    0
                }])
            })
        };
        for mask in [disc(35, 30, 150), disc(110, 80, 200), disc(2, 45, 90), GrayImage::new(w, h)] {
            for (a, b, c, d, pad, size) in [(20, 15, 50, 45, 0.2, 64), (0, 0, 119, 89, 0.1, 32), (25, 20, 45, 40, 0.5, 100), (90, 60, 119, 89, 0.3, 24)] {
                let bx = CropBox::around(a, b, c, d, pad, size);
                for angle in [0.0, 0.3, 1.2, -2.5, std::f64::consts::PI] {
                    let turn = Turn::new(angle, [60.0, 45.0]);
                    let (fast, slow) = (sample_crop(&rgb, &mask, &bx, ToSource::Turned(turn)), reference_crop(&rgb, &mask, &bx, &|u, v| turn.apply(u, v)));
                    assert_eq!((fast.rgb.as_raw(), fast.mask.as_raw()), (slow.rgb.as_raw(), slow.mask.as_raw()), "box {:?}, angle {angle}", (a, b, c, d, pad, size));
                }
                // Shifted (a render judged against the photo's crop): the separable path
                // reads only the rows and columns that reach the disc, and must lose none of
                // its pixels (a level apart at most, as its sums run in another order).
                for (dx, dy) in [(0.0, 0.0), (-4.5, 3.25), (20.0, -15.0)] {
                    let f = move |u: f64, v: f64| (u - dx, v - dy);
                    let (fast, slow) = (sample_crop(&rgb, &mask, &bx, ToSource::Shift(dx, dy)), reference_crop(&rgb, &mask, &bx, &f));
                    let pairs = fast.rgb.as_raw().iter().zip(slow.rgb.as_raw()).chain(fast.mask.as_raw().iter().zip(slow.mask.as_raw()));
                    let worst = pairs.fold(0, |w, (x, y)| w.max(x.abs_diff(*y)));
                    assert!(worst <= 1, "box {:?}, shift {:?}: values differ by up to {worst}", (a, b, c, d, pad, size), (dx, dy));
                }
            }
        }
    }

    #[test]
    fn a_row_meets_a_box_in_one_run_of_columns() {
        // Points x = 10 + 2·cu along y = 5: x within 20..=30 for cu 5..=10, widened by one
        // column each side (and the end exclusive).
        assert_eq!(columns_within((10.0, 5.0), (12.0, 5.0), (20.0, 0.0), (30.0, 10.0), 100), (4, 12));
        // Going the other way, and clipped to the row.
        assert_eq!(columns_within((30.0, 5.0), (28.0, 5.0), (20.0, 0.0), (30.0, 10.0), 100), (0, 7));
        // A row beside the box, and one along it.
        assert_eq!(columns_within((10.0, 50.0), (12.0, 50.0), (20.0, 0.0), (30.0, 10.0), 100), (0, 0));
        assert_eq!(columns_within((25.0, 5.0), (25.0, 5.0), (20.0, 0.0), (30.0, 10.0), 8), (0, 8));
        // Past the row's end.
        let (start, end) = columns_within((10.0, 5.0), (10.1, 5.0), (20.0, 0.0), (30.0, 10.0), 50);
        assert_eq!(start, end);
    }

    /// Each row's first and last object pixel, and nothing for rows without one.
    #[test]
    fn row_ends_of_mask() {
        let mut m = GrayImage::new(6, 4);
        assert!(mask_row_ends(&m).is_empty());
        for (x, y) in [(1, 1), (2, 1), (4, 1), (3, 3)] {
            m.put_pixel(x, y, image::Luma([255]));
        }
        assert_eq!(mask_row_ends(&m), vec![(1.0, 1.0), (4.0, 1.0), (3.0, 3.0), (3.0, 3.0)]);
    }

    #[test]
    fn bbox_of_mask() {
        let mut m = GrayImage::new(10, 8);
        assert_eq!(mask_bbox(&m), None);
        m.put_pixel(3, 2, image::Luma([255]));
        m.put_pixel(7, 5, image::Luma([1]));
        assert_eq!(mask_bbox(&m), Some((3, 2, 7, 5)));
    }

    #[test]
    fn crop_blacks_out_background_and_keeps_object_colour() {
        let rgb = RgbImage::from_pixel(64, 64, image::Rgb([200, 100, 50]));
        let mut mask = GrayImage::new(64, 64);
        for v in 20..40 {
            for u in 10..30 {
                mask.put_pixel(u, v, image::Luma([255]));
            }
        }
        let (c, b) = crop_query(&rgb, &mask, 0.5, 32).unwrap();
        assert_eq!(c.size(), 32);
        // Centre is object, corners background.
        assert_eq!(c.rgb.get_pixel(16, 16).0, [200, 100, 50]);
        assert_eq!(c.mask.get_pixel(16, 16)[0], 255);
        assert_eq!(c.rgb.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(c.mask.get_pixel(0, 0)[0], 0);
        // The mask box (20 px) with 50 % padding spans 30 image px over 32 crop px.
        assert!((b.side - 30.0).abs() < 1e-9);
    }
}
