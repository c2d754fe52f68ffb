//! Run-length encoded binary masks, as written by pycocotools and by the BOP
//! toolkit (`bop_toolkit_lib/pycoco_utils.py`, `binary_mask_to_rle`).
//!
//! Conventions (they are easy to get wrong, so they are pinned by tests):
//! * runs are taken over the pixels in **column-major** order: x outer, y
//!   inner, i.e. the Fortran order of an `h × w` array (pixel `(x, y)` has
//!   linear index `x·h + y`);
//! * the first run counts background pixels and may be 0 (mask starting with
//!   an object pixel); runs then alternate object / background;
//! * `size` is `[height, width]`, as in COCO.
//!
//! Besides the plain list of counts, COCO defines a compressed string form
//! (`rleToString` / `rleFrString` in cocoapi's `common/maskApi.c`), which
//! CNOS and pycocotools emit; both forms are read, the list form is written.

use crate::limits;
use image::{GrayImage, Luma};
use serde_json::Value;

/// Value of an object pixel in decoded masks.
const OBJECT: u8 = 255;

/// Offset added to each 6-bit chunk of the compressed string, so that every
/// chunk is a printable character (`'0'` ..= `'o'`).
const CHAR_OFFSET: u8 = 48;
/// A compressed chunk holds 5 payload bits, a "more chunks follow" bit (0x20)
/// and, in the last chunk, a sign bit (0x10).
const PAYLOAD_BITS: u32 = 5;
const PAYLOAD_MASK: i64 = 0x1f;
const SIGN_BIT: i64 = 0x10;
const MORE_BIT: i64 = 0x20;
/// The largest delta between two u32 counts needs 34 signed bits: 7 chunks.
const MAX_CHUNKS_PER_COUNT: u32 = 7;

/// Why an RLE could not be read or is inconsistent.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RleError {
    #[error("size is {height}×{width}: both must be positive")]
    ZeroSize { height: u32, width: u32 },
    #[error("size is {height}×{width}: over the limit of {max_side} pixels a side and {max_pixels} pixels in all")]
    TooLarge { height: u32, width: u32, max_side: u32, max_pixels: u64 },
    #[error("more than {max} runs: over the limit")]
    TooManyRuns { max: usize },
    #[error("counts sum to {sum} but size is {height}×{width} ({} pixels)", *.height as u64 * *.width as u64)]
    CountSumMismatch { sum: u64, height: u32, width: u32 },
    #[error("compressed counts: invalid character {ch:?} at byte {pos} (expected '0'..='o')")]
    InvalidChar { pos: usize, ch: char },
    #[error("compressed counts: string ends inside count {index} (truncated?)")]
    Truncated { index: usize },
    #[error("compressed counts: count {index} uses more than {MAX_CHUNKS_PER_COUNT} characters")]
    CountTooLong { index: usize },
    #[error("compressed counts: count {index} decodes to {value}, outside 0..=4294967295")]
    CountOutOfRange { index: usize, value: i64 },
    #[error("expected an object with \"counts\" and \"size\", got {found}")]
    NotAnObject { found: &'static str },
    #[error("{field}: {reason}")]
    BadField { field: &'static str, reason: String },
}

/// A binary mask as runs of alternating background / object pixels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rle {
    /// `[height, width]`, COCO order.
    pub size: [u32; 2],
    /// Run lengths in column-major order, starting with background.
    pub counts: Vec<u32>,
}

impl Rle {
    /// Builds an RLE and checks it is consistent (see [`Rle::validate`]).
    pub fn new(size: [u32; 2], counts: Vec<u32>) -> Result<Rle, RleError> {
        let rle = Rle { size, counts };
        rle.validate()?;
        Ok(rle)
    }

    pub fn height(&self) -> u32 {
        self.size[0]
    }

    pub fn width(&self) -> u32 {
        self.size[1]
    }

    fn pixel_count(&self) -> u64 {
        self.height() as u64 * self.width() as u64
    }

    /// The size must be non-zero and within [`limits::REQUEST_IMAGE`] (a mask is
    /// decoded to that many bytes), there must be at most [`limits::MAX_RLE_RUNS`] runs,
    /// and they must cover every pixel exactly once; zero-length runs inside the list are
    /// tolerated, as pycocotools does.
    pub fn validate(&self) -> Result<(), RleError> {
        let (height, width) = (self.height(), self.width());
        if height == 0 || width == 0 {
            return Err(RleError::ZeroSize { height, width });
        }
        let max = limits::REQUEST_IMAGE;
        if max.check(width, height).is_err() {
            return Err(RleError::TooLarge { height, width, max_side: max.max_side, max_pixels: max.max_pixels });
        }
        check_runs(self.counts.len())?;
        let sum: u64 = self.counts.iter().map(|&c| c as u64).sum();
        if sum != self.pixel_count() {
            return Err(RleError::CountSumMismatch { sum, height: self.height(), width: self.width() });
        }
        Ok(())
    }

    /// Encodes a mask; any nonzero pixel is object. A 0-pixel image gives an
    /// RLE with no counts, which [`Rle::validate`] rejects (zero size).
    pub fn encode(mask: &GrayImage) -> Rle {
        let (width, height) = mask.dimensions();
        let mut counts = Vec::new();
        let mut current_is_object = false;
        let mut run: u32 = 0;
        for x in 0..width {
            for y in 0..height {
                let is_object = mask.get_pixel(x, y)[0] != 0;
                if is_object != current_is_object {
                    counts.push(run);
                    run = 0;
                    current_is_object = is_object;
                }
                run += 1;
            }
        }
        if width > 0 && height > 0 {
            counts.push(run);
        }
        Rle { size: [height, width], counts }
    }

    /// Decodes to a `width × height` image with object pixels at 255.
    pub fn decode(&self) -> Result<GrayImage, RleError> {
        self.validate()?;
        let height = self.height() as u64;
        let mut mask = GrayImage::new(self.width(), self.height());
        for (start, end) in self.object_runs() {
            for index in start..end {
                let (x, y) = ((index / height) as u32, (index % height) as u32);
                mask.put_pixel(x, y, Luma([OBJECT]));
            }
        }
        Ok(mask)
    }

    /// Half-open column-major index ranges of the object runs, clipped to
    /// the image so that an invalid RLE cannot index outside it.
    fn object_runs(&self) -> impl Iterator<Item = (u64, u64)> + '_ {
        let total = self.pixel_count();
        let mut start = 0u64;
        self.counts.iter().enumerate().filter_map(move |(i, &count)| {
            let run_start = start.min(total);
            start += count as u64;
            let run_end = start.min(total);
            let is_object = i % 2 == 1;
            (is_object && run_end > run_start).then_some((run_start, run_end))
        })
    }

    /// Number of object pixels.
    pub fn area(&self) -> u64 {
        self.object_runs().map(|(start, end)| end - start).sum()
    }

    /// Tight box `[x, y, w, h]` around the object pixels, `None` when there
    /// are none. Computed from the runs: a run within one column spans rows
    /// `start % h ..= (end-1) % h`; a run crossing a column boundary touches
    /// both the last row and the first row, so it spans all rows.
    pub fn bbox(&self) -> Option<[u32; 4]> {
        let height = self.height() as u64;
        if height == 0 || self.width() == 0 {
            return None;
        }
        let mut bounds: Option<(u64, u64, u64, u64)> = None; // x0, x1, y0, y1 inclusive
        for (start, end) in self.object_runs() {
            let last = end - 1;
            let (x0, x1) = (start / height, last / height);
            let (y0, y1) = if x0 == x1 { (start % height, last % height) } else { (0, height - 1) };
            bounds = Some(match bounds {
                None => (x0, x1, y0, y1),
                Some((bx0, bx1, by0, by1)) => (bx0.min(x0), bx1.max(x1), by0.min(y0), by1.max(y1)),
            });
        }
        bounds.map(|(x0, x1, y0, y1)| [x0 as u32, y0 as u32, (x1 - x0 + 1) as u32, (y1 - y0 + 1) as u32])
    }

    /// COCO compressed counts string (cocoapi `rleToString`): each count,
    /// or for index > 2 its difference with the count two places before,
    /// is written as little-endian 5-bit chunks; 0x20 marks "more chunks
    /// follow", 0x10 in the last chunk is the sign, and 48 is added to make
    /// it printable.
    pub fn to_coco_string(&self) -> String {
        let mut out = String::new();
        for (i, &count) in self.counts.iter().enumerate() {
            let mut x = count as i64;
            if i > 2 {
                x -= self.counts[i - 2] as i64;
            }
            loop {
                let mut chunk = x & PAYLOAD_MASK;
                x >>= PAYLOAD_BITS; // arithmetic shift keeps the sign
                let more = if chunk & SIGN_BIT != 0 { x != -1 } else { x != 0 };
                if more {
                    chunk |= MORE_BIT;
                }
                out.push(char::from(chunk as u8 + CHAR_OFFSET));
                if !more {
                    break;
                }
            }
        }
        out
    }

    /// Parses a COCO compressed counts string (cocoapi `rleFrString`) and
    /// validates the result against `size` (`[height, width]`).
    pub fn from_coco_string(s: &str, size: [u32; 2]) -> Result<Rle, RleError> {
        Rle::new(size, coco_counts(s)?)
    }

    /// Reads `{"counts": [ints] | "compressed string", "size": [h, w]}`.
    pub fn from_json(v: &Value) -> Result<Rle, RleError> {
        let object = v.as_object().ok_or(RleError::NotAnObject { found: json_kind(v) })?;
        let size = parse_size(object.get("size"))?;
        match object.get("counts") {
            Some(Value::String(s)) => Rle::from_coco_string(s, size),
            Some(Value::Array(items)) => {
                check_runs(items.len())?;
                let counts = items
                    .iter()
                    .enumerate()
                    .map(|(i, item)| {
                        item.as_u64()
                            .and_then(|c| u32::try_from(c).ok())
                            .ok_or_else(|| RleError::BadField { field: "counts", reason: format!("item {i} is {item}, expected an integer in 0..=4294967295") })
                    })
                    .collect::<Result<Vec<u32>, RleError>>()?;
                Rle::new(size, counts)
            }
            Some(other) => Err(RleError::BadField { field: "counts", reason: format!("expected a list of integers or a string, got {}", json_kind(other)) }),
            None => Err(RleError::BadField { field: "counts", reason: "missing".into() }),
        }
    }

    /// The uncompressed list form, as the BOP toolkit writes it.
    pub fn to_json_uncompressed(&self) -> Value {
        serde_json::json!({ "counts": self.counts, "size": self.size })
    }
}

/// The counts of a COCO compressed string, checked only for their encoding.
fn coco_counts(s: &str) -> Result<Vec<u32>, RleError> {
    let bytes = s.as_bytes();
    let mut counts: Vec<u32> = Vec::new();
    let mut pos = 0;
    while pos < bytes.len() {
        let index = counts.len();
        check_runs(index + 1)?;
        let mut x: i64 = 0;
        let mut chunks = 0;
        loop {
            let Some(&byte) = bytes.get(pos) else {
                return Err(RleError::Truncated { index });
            };
            if !(CHAR_OFFSET..=CHAR_OFFSET + 63).contains(&byte) {
                let ch = s[pos..].chars().next().unwrap_or(char::REPLACEMENT_CHARACTER);
                return Err(RleError::InvalidChar { pos, ch });
            }
            if chunks == MAX_CHUNKS_PER_COUNT {
                return Err(RleError::CountTooLong { index });
            }
            let chunk = (byte - CHAR_OFFSET) as i64;
            x |= (chunk & PAYLOAD_MASK) << (PAYLOAD_BITS * chunks);
            pos += 1;
            chunks += 1;
            if chunk & MORE_BIT == 0 {
                if chunk & SIGN_BIT != 0 {
                    x |= -1i64 << (PAYLOAD_BITS * chunks);
                }
                break;
            }
        }
        if index > 2 {
            x += counts[index - 2] as i64;
        }
        let count = u32::try_from(x).map_err(|_| RleError::CountOutOfRange { index, value: x })?;
        counts.push(count);
    }
    Ok(counts)
}

/// Refuses more than [`limits::MAX_RLE_RUNS`] runs.
fn check_runs(runs: usize) -> Result<(), RleError> {
    match runs > limits::MAX_RLE_RUNS {
        true => Err(RleError::TooManyRuns { max: limits::MAX_RLE_RUNS }),
        false => Ok(()),
    }
}

fn parse_size(v: Option<&Value>) -> Result<[u32; 2], RleError> {
    let bad = |reason: String| RleError::BadField { field: "size", reason };
    let v = v.ok_or_else(|| bad("missing".into()))?;
    let items = v.as_array().ok_or_else(|| bad(format!("expected [height, width], got {}", json_kind(v))))?;
    if items.len() != 2 {
        return Err(bad(format!("expected [height, width], got {} values", items.len())));
    }
    let dim = |item: &Value| item.as_u64().and_then(|d| u32::try_from(d).ok());
    match (dim(&items[0]), dim(&items[1])) {
        (Some(height), Some(width)) => Ok([height, width]),
        _ => Err(bad(format!("expected two non-negative integers, got {v}"))),
    }
}

/// Short name of a JSON value's type, for error messages.
pub(crate) fn json_kind(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "a list",
        Value::Object(_) => "an object",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// Tiny deterministic xorshift64 so the tests need no `rand` crate.
    struct XorShift(u64);

    impl XorShift {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
    }

    /// Builds a mask from rows of 0/1, written top to bottom as one sees it.
    fn mask_from_rows(rows: &[&[u8]]) -> GrayImage {
        let height = rows.len() as u32;
        let width = rows[0].len() as u32;
        GrayImage::from_fn(width, height, |x, y| Luma([rows[y as usize][x as usize] * OBJECT]))
    }

    /// Random mask made of runs of random length, with a per-mask density
    /// so that empty, full, sparse and dense masks all occur.
    fn random_mask(rng: &mut XorShift) -> GrayImage {
        let width = 1 + rng.below(40) as u32;
        let height = 1 + rng.below(40) as u32;
        let density = rng.below(101);
        let max_run = 1 + rng.below(60);
        let mut mask = GrayImage::new(width, height);
        let mut value = rng.below(100) < density;
        let mut left = 1 + rng.below(max_run);
        for y in 0..height {
            for x in 0..width {
                if left == 0 {
                    value = rng.below(100) < density;
                    left = 1 + rng.below(max_run);
                }
                left -= 1;
                // Non-255 object values check that any nonzero counts.
                mask.put_pixel(x, y, Luma([if value { 1 + rng.below(255) as u8 } else { 0 }]));
            }
        }
        mask
    }

    fn binarised(mask: &GrayImage) -> GrayImage {
        GrayImage::from_fn(mask.width(), mask.height(), |x, y| Luma([if mask.get_pixel(x, y)[0] != 0 { OBJECT } else { 0 }]))
    }

    fn brute_force_bbox(mask: &GrayImage) -> Option<[u32; 4]> {
        let on: Vec<(u32, u32)> = mask.enumerate_pixels().filter(|(_, _, p)| p[0] != 0).map(|(x, y, _)| (x, y)).collect();
        let x0 = on.iter().map(|p| p.0).min()?;
        let x1 = on.iter().map(|p| p.0).max()?;
        let y0 = on.iter().map(|p| p.1).min()?;
        let y1 = on.iter().map(|p| p.1).max()?;
        Some([x0, y0, x1 - x0 + 1, y1 - y0 + 1])
    }

    #[test]
    fn hand_worked_example_pins_column_major_and_leading_background() {
        // 3 rows × 2 columns:   column-major walk (x outer, y inner):
        //   1 1                  col 0: 1 0 0, col 1: 1 0 1
        //   0 0               -> 1 0 0 1 0 1
        //   0 1               -> bg 0, obj 1, bg 2, obj 1, bg 1, obj 1
        // (row-major would give 1 1 0 0 0 1 -> [0, 2, 3, 1]).
        let mask = mask_from_rows(&[&[1, 1], &[0, 0], &[0, 1]]);
        let rle = Rle::encode(&mask);
        assert_eq!(rle.size, [3, 2]);
        assert_eq!(rle.counts, vec![0, 1, 2, 1, 1, 1]);
        assert_eq!(rle.area(), 3);
        assert_eq!(rle.bbox(), Some([0, 0, 2, 3]));
        assert_eq!(rle.decode().unwrap(), binarised(&mask));
    }

    #[test]
    fn mask_starting_with_background_has_nonzero_first_run() {
        let mask = mask_from_rows(&[&[0, 0], &[0, 1]]);
        let rle = Rle::encode(&mask);
        assert_eq!(rle.counts, vec![3, 1]);
        assert_eq!(rle.bbox(), Some([1, 1, 1, 1]));
    }

    #[test]
    fn empty_and_full_masks() {
        let empty = Rle::encode(&GrayImage::new(4, 3));
        assert_eq!(empty.counts, vec![12]);
        assert_eq!(empty.area(), 0);
        assert_eq!(empty.bbox(), None);
        let full = Rle::encode(&GrayImage::from_pixel(4, 3, Luma([7])));
        assert_eq!(full.counts, vec![0, 12]);
        assert_eq!(full.bbox(), Some([0, 0, 4, 3]));
    }

    #[test]
    fn known_coco_string_for_a_square() {
        // 8×8 image, object = 4×4 square at x 2..=5, y 2..=5.
        // Column-major runs: bg 2 columns + 2 rows = 18, then per column
        // obj 4 / bg 4 (2 rows below + 2 rows above in the next column),
        // and finally bg 2 + 2 columns = 18:
        //   counts = [18, 4, 4, 4, 4, 4, 4, 4, 18]          (sum 64)
        // rleToString writes counts[0..=2] as they are and, for i > 2,
        // counts[i] - counts[i-2]:  18, 4, 4, 0, 0, 0, 0, 0, 14.
        //   18 = 0b10010: chunk 18 has the sign bit 0x10 set while the rest
        //        (0) is not -1, so another chunk follows: 18|0x20 = 50 -> 'b',
        //        then chunk 0 -> '0'.                      => "b0"
        //   4 -> '4', 4 -> '4', 0 -> '0' (×5), 14 -> 48+14 = '>'.
        let mask = GrayImage::from_fn(8, 8, |x, y| Luma([if (2..=5).contains(&x) && (2..=5).contains(&y) { 1 } else { 0 }]));
        let rle = Rle::encode(&mask);
        assert_eq!(rle.counts, vec![18, 4, 4, 4, 4, 4, 4, 4, 18]);
        assert_eq!(rle.to_coco_string(), "b04400000>");
        assert_eq!(Rle::from_coco_string("b04400000>", [8, 8]).unwrap(), rle);
        assert_eq!(rle.bbox(), Some([2, 2, 4, 4]));
    }

    #[test]
    fn known_coco_string_with_multi_chunk_and_negative_delta() {
        // size [40, 1]; counts [2, 35, 1, 2] (sum 40).
        //   2  -> '2'
        //   35 = 0b1_00011: chunk 3, rest 1 -> 3|0x20 = 35 -> 'S'; chunk 1 -> '1'
        //   1  -> '1'
        //   2 - counts[1] = -33: chunk (-33 & 31) = 31, rest (-33 >> 5) = -2,
        //        not -1 -> 31|0x20 = 63 -> 'o'; chunk (-2 & 31) = 30, rest -1
        //        and 30 has the sign bit -> last: 48+30 = 'N'
        let rle = Rle::new([40, 1], vec![2, 35, 1, 2]).unwrap();
        assert_eq!(rle.to_coco_string(), "2S11oN");
        assert_eq!(Rle::from_coco_string("2S11oN", [40, 1]).unwrap(), rle);
        assert_eq!(rle.bbox(), Some([0, 2, 1, 38]));
    }

    #[test]
    fn random_masks_round_trip_through_every_form() {
        let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
        for _ in 0..500 {
            let mask = random_mask(&mut rng);
            let rle = Rle::encode(&mask);
            rle.validate().unwrap();
            assert_eq!(rle.decode().unwrap(), binarised(&mask));
            let area = mask.pixels().filter(|p| p[0] != 0).count() as u64;
            assert_eq!(rle.area(), area);
            assert_eq!(rle.bbox(), brute_force_bbox(&mask));

            let s = rle.to_coco_string();
            assert_eq!(Rle::from_coco_string(&s, rle.size).unwrap(), rle);
            let json_string = json!({"counts": s, "size": rle.size});
            assert_eq!(Rle::from_json(&json_string).unwrap(), rle);
            assert_eq!(Rle::from_json(&rle.to_json_uncompressed()).unwrap(), rle);
        }
    }

    #[test]
    fn large_counts_round_trip_through_string() {
        // Extreme deltas: u32::MAX next to 0 needs all 7 chunks.
        let rle = Rle { size: [u32::MAX, 3], counts: vec![u32::MAX, 0, u32::MAX, 0, 0, u32::MAX] };
        let s = rle.to_coco_string();
        // (Counts only: a mask this large is over the size limit.)
        assert_eq!(coco_counts(&s).unwrap(), rle.counts);
    }

    #[test]
    fn bbox_of_run_crossing_columns_spans_all_rows() {
        // h=4, w=3: object from (x0,y3) to (x1,y0): two pixels, rows 0 and 3.
        let rle = Rle::new([4, 3], vec![3, 2, 7]).unwrap();
        assert_eq!(rle.bbox(), Some([0, 0, 2, 4]));
        assert_eq!(brute_force_bbox(&rle.decode().unwrap()), rle.bbox());
    }

    #[test]
    fn sum_mismatch_is_rejected() {
        let err = Rle::new([20, 20], vec![100, 200]).unwrap_err();
        assert_eq!(err, RleError::CountSumMismatch { sum: 300, height: 20, width: 20 });
        assert_eq!(err.to_string(), "counts sum to 300 but size is 20×20 (400 pixels)");
        let too_long = Rle { size: [2, 2], counts: vec![1, 2, 3] };
        assert!(too_long.decode().is_err());
        // bbox and area stay inside the image even for an invalid RLE.
        assert_eq!(too_long.area(), 2);
        assert_eq!(too_long.bbox(), Some([0, 0, 2, 2]));
    }

    #[test]
    fn sizes_and_run_counts_over_the_limits_are_rejected() {
        // 65536 × 65536 would decode to 4 GiB: refused before decoding.
        let huge = Rle::new([65_536, 65_536], vec![u32::MAX, 1]).unwrap_err();
        assert!(matches!(huge, RleError::TooLarge { height: 65_536, width: 65_536, .. }));
        assert!(huge.to_string().contains("over the limit of 16384 pixels a side"), "{huge}");
        assert!(matches!(Rle::from_coco_string("0", [10_000, 10_000]), Err(RleError::TooLarge { .. })));
        let runs = limits::MAX_RLE_RUNS;
        let many = Rle { size: [1, 1], counts: vec![0; runs + 1] };
        assert_eq!(many.validate().unwrap_err(), RleError::TooManyRuns { max: runs });
        // The string is refused at the run past the limit, not after reading it all.
        assert_eq!(Rle::from_coco_string(&"0".repeat(runs + 10), [1, 1]).unwrap_err(), RleError::TooManyRuns { max: runs });
        let e = Rle::from_json(&json!({"counts": vec![0; runs + 1], "size": [1, 1]})).unwrap_err();
        assert_eq!(e.to_string(), format!("more than {runs} runs: over the limit"));
    }

    #[test]
    fn zero_size_is_rejected() {
        assert!(matches!(Rle::new([0, 5], vec![]), Err(RleError::ZeroSize { .. })));
        assert!(matches!(Rle::new([5, 0], vec![0]), Err(RleError::ZeroSize { .. })));
        assert_eq!(Rle { size: [0, 0], counts: vec![] }.bbox(), None);
        let empty_image = Rle::encode(&GrayImage::new(0, 0));
        assert!(empty_image.validate().is_err());
    }

    #[test]
    fn invalid_characters_are_rejected() {
        let err = Rle::from_coco_string("b0 4", [8, 8]).unwrap_err();
        assert_eq!(err, RleError::InvalidChar { pos: 2, ch: ' ' });
        assert!(err.to_string().contains("byte 2"));
        // 'p' is 48 + 64, one past the alphabet.
        assert!(matches!(Rle::from_coco_string("p", [1, 1]), Err(RleError::InvalidChar { pos: 0, .. })));
        assert!(matches!(Rle::from_coco_string("4é", [2, 2]), Err(RleError::InvalidChar { pos: 1, ch: 'é' })));
    }

    #[test]
    fn truncated_string_is_rejected() {
        // 'b' announces another chunk that never comes.
        assert_eq!(Rle::from_coco_string("b", [8, 8]).unwrap_err(), RleError::Truncated { index: 0 });
        assert_eq!(Rle::from_coco_string("44b", [8, 8]).unwrap_err(), RleError::Truncated { index: 2 });
    }

    #[test]
    fn string_counts_out_of_range_are_rejected() {
        // 8 continuation chunks: longer than any u32 delta needs.
        assert_eq!(Rle::from_coco_string("PPPPPPPP0", [1, 1]).unwrap_err(), RleError::CountTooLong { index: 0 });
        // A lone negative first count: chunk 0x1f with the sign bit = -1.
        assert_eq!(Rle::from_coco_string("O", [1, 1]).unwrap_err(), RleError::CountOutOfRange { index: 0, value: -1 });
        // A valid string whose counts do not match the size.
        assert!(matches!(Rle::from_coco_string("b04400000>", [8, 9]), Err(RleError::CountSumMismatch { sum: 64, height: 8, width: 9 })));
        assert!(matches!(Rle::from_coco_string("", [2, 2]), Err(RleError::CountSumMismatch { sum: 0, .. })));
    }

    #[test]
    fn malformed_json_is_rejected() {
        let cases = [
            (json!([1, 2]), "expected an object with \"counts\" and \"size\", got a list"),
            (json!({"size": [2, 2]}), "counts: missing"),
            (json!({"counts": [4]}), "size: missing"),
            (json!({"counts": [4], "size": [2]}), "size: expected [height, width], got 1 values"),
            (json!({"counts": [4], "size": [2, -2]}), "size: expected two non-negative integers"),
            (json!({"counts": [4], "size": "2x2"}), "size: expected [height, width], got a string"),
            (json!({"counts": [1, -3], "size": [2, 2]}), "counts: item 1 is -3"),
            (json!({"counts": [1.5, 2.5], "size": [2, 2]}), "counts: item 0 is 1.5"),
            (json!({"counts": {"a": 1}, "size": [2, 2]}), "counts: expected a list of integers or a string"),
            (json!({"counts": [1, 2], "size": [2, 2]}), "counts sum to 3 but size is 2×2"),
            (json!({"counts": "b", "size": [8, 8]}), "truncated"),
        ];
        for (value, expected) in cases {
            let err = Rle::from_json(&value).unwrap_err().to_string();
            assert!(err.contains(expected), "{value}: got {err:?}, wanted {expected:?}");
        }
    }
}
