//! Lines a candidate's render up with the photo before it is scored. The coarse pose of a
//! template match is 10–20° and some pixels off, so the render's outline and print land
//! beside the photo's edges and a true object scores little better than clutter. Searching
//! small 2D shifts, scales and turns of the render's oriented edge points (edgels) for the
//! best agreement with the photo's edges stands in for a pose refinement at a fraction of
//! its cost; agreements are then corrected for what the photo's edge density would give by
//! chance, so a window full of clutter does not score high for being full of edges.

use super::gradients::{bin_of, colour_gradients, mask_gradients, quantised_bits, spread, BINS};
use image::{GrayImage, RgbImage};

/// An oriented edge point of a render, in window pixels; `angle` in [0, π).
#[derive(Clone, Copy, Debug)]
pub struct Edgel {
    pub x: f32,
    pub y: f32,
    pub angle: f32,
}

/// Edgels kept per set, evenly thinned (enough for a stable share, cheap to search).
const MAX_EDGELS: usize = 240;

/// The silhouette's outline: pixels where the coverage gradient is at least a quarter of
/// its peak.
pub fn outline_edgels(mask: &GrayImage) -> Vec<Edgel> {
    let g = mask_gradients(mask);
    let peak = g.magnitude.iter().copied().fold(0.0f32, f32::max);
    if peak == 0.0 {
        return Vec::new();
    }
    let w = g.width;
    let all: Vec<Edgel> =
        (0..g.magnitude.len()).filter(|&i| mask.as_raw()[i] > 0 && g.magnitude[i] >= 0.25 * peak).map(|i| Edgel { x: (i % w) as f32, y: (i / w) as f32, angle: g.angle[i] }).collect();
    thin(all)
}

/// Edges of the render's surface (print, colour borders, creases in its shading) at least
/// two pixels inside the silhouette, so they are the object's own and not its outline.
pub fn interior_edgels(rgb: &RgbImage, mask: &GrayImage, min_magnitude: f32) -> Vec<Edgel> {
    let g = colour_gradients(rgb);
    let bits = quantised_bits(&g, min_magnitude);
    let (w, h) = (g.width, g.height);
    let inside = |x: usize, y: usize| -> bool {
        let (x0, y0, x1, y1) = (x.saturating_sub(2), y.saturating_sub(2), (x + 2).min(w - 1), (y + 2).min(h - 1));
        x >= 2 && y >= 2 && x + 2 < w && y + 2 < h && (y0..=y1).all(|yy| (x0..=x1).all(|xx| mask.as_raw()[yy * w + xx] > 0))
    };
    let all: Vec<Edgel> = (0..w * h).filter(|&i| bits[i] != 0 && inside(i % w, i / w)).map(|i| Edgel { x: (i % w) as f32, y: (i / w) as f32, angle: g.angle[i] }).collect();
    thin(all)
}

fn thin(all: Vec<Edgel>) -> Vec<Edgel> {
    if all.len() <= MAX_EDGELS {
        return all;
    }
    let step = all.len() as f64 / MAX_EDGELS as f64;
    (0..MAX_EDGELS).map(|k| all[(k as f64 * step) as usize]).collect()
}

/// The photo's quantised edges in the window, spread by a pixel, and for each bin how much
/// of the window would answer an edgel of that bin (±1 bin) by chance.
pub struct PhotoEdges {
    width: usize,
    height: usize,
    bits: Vec<u8>,
    density: [f32; BINS],
}

/// Which photo bits answer an edgel of bin `b`: its own and the two neighbours.
fn wanted(b: usize) -> u8 {
    (1u8 << b) | (1u8 << ((b + 1) % BINS)) | (1u8 << ((b + BINS - 1) % BINS))
}

impl PhotoEdges {
    pub fn new(photo: &RgbImage, min_magnitude: f32) -> Self {
        let (width, height) = (photo.width() as usize, photo.height() as usize);
        let bits = spread(&quantised_bits(&colour_gradients(photo), min_magnitude), width, height, 3);
        let mut density = [0f32; BINS];
        for (b, d) in density.iter_mut().enumerate() {
            let m = wanted(b);
            *d = bits.iter().filter(|&&v| v & m != 0).count() as f32 / bits.len().max(1) as f32;
        }
        Self { width, height, bits, density }
    }

    /// Share of `edgels` answered by the photo at `placement`, and the share chance would
    /// give (the mean density of their bins). Edgels falling outside the window count as
    /// unanswered.
    fn answered(&self, edgels: &[Edgel], p: &Placement) -> (f32, f32) {
        if edgels.is_empty() {
            return (0.0, 0.0);
        }
        let (sin, cos) = p.turn.sin_cos();
        let (mut hit, mut chance) = (0u32, 0f32);
        for e in edgels {
            let (rx, ry) = (e.x - p.cx, e.y - p.cy);
            let x = (p.cx + p.scale * (cos * rx - sin * ry) + p.dx).round();
            let y = (p.cy + p.scale * (sin * rx + cos * ry) + p.dy).round();
            let b = bin_of(e.angle + p.turn) as usize;
            chance += self.density[b];
            if x < 0.0 || y < 0.0 || x >= self.width as f32 || y >= self.height as f32 {
                continue;
            }
            hit += (self.bits[y as usize * self.width + x as usize] & wanted(b) != 0) as u32;
        }
        let n = edgels.len() as f32;
        (hit as f32 / n, chance / n)
    }

    /// How far above chance the photo answers `edgels` at `placement`: 0 at chance or
    /// below, 1 when every edgel is answered.
    pub fn agreement(&self, edgels: &[Edgel], p: &Placement) -> f32 {
        let (hit, chance) = self.answered(edgels, p);
        if chance >= 1.0 {
            return 0.0;
        }
        ((hit - chance) / (1.0 - chance)).max(0.0)
    }
}

/// A 2D similarity about (cx, cy): scale and turn (radians) there, then the shift.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub cx: f32,
    pub cy: f32,
    pub dx: f32,
    pub dy: f32,
    pub scale: f32,
    pub turn: f32,
}

impl Placement {
    pub fn identity(cx: f32, cy: f32) -> Self {
        Self { cx, cy, dx: 0.0, dy: 0.0, scale: 1.0, turn: 0.0 }
    }
}

/// Search range: shifts up to this share of the outline's extent, scales and turns on
/// these ladders (a coarse pose is ~15° and a few % of depth off).
const SHIFT_SHARE: f32 = 0.1;
const SCALES: [f32; 5] = [0.92, 0.96, 1.0, 1.04, 1.08];
const TURNS_DEG: [f32; 5] = [-10.0, -5.0, 0.0, 5.0, 10.0];

/// The placement of the outline that the photo answers best, with its agreement: every
/// scale and turn on the ladders with shifts on a two-pixel grid and every other edgel,
/// then the neighbourhood of the best at one pixel, half steps of scale and turn, and all
/// edgels (a tenth of the exhaustive search's cost for the same optimum in practice).
pub fn best_placement(photo: &PhotoEdges, outline: &[Edgel]) -> (Placement, f32) {
    if outline.is_empty() {
        return (Placement::identity(0.0, 0.0), 0.0);
    }
    let n = outline.len() as f32;
    let (cx, cy) = (outline.iter().map(|e| e.x).sum::<f32>() / n, outline.iter().map(|e| e.y).sum::<f32>() / n);
    let extent = outline.iter().map(|e| (e.x - cx).abs().max((e.y - cy).abs())).fold(0.0f32, f32::max);
    // `extent` is half the outline's size; the coarse grid steps by 2 px.
    let r = 2 * (SHIFT_SHARE * extent).round().max(1.0) as i32;
    let sparse: Vec<Edgel> = outline.iter().step_by(2).copied().collect();
    let start = Placement::identity(cx, cy);
    let mut coarse = (start, photo.agreement(&sparse, &start));
    for &scale in &SCALES {
        for &t in &TURNS_DEG {
            for dy in (-r..=r).step_by(2) {
                for dx in (-r..=r).step_by(2) {
                    let p = Placement { cx, cy, dx: dx as f32, dy: dy as f32, scale, turn: t.to_radians() };
                    let a = photo.agreement(&sparse, &p);
                    if a > coarse.1 {
                        coarse = (p, a);
                    }
                }
            }
        }
    }
    let c = coarse.0;
    let mut best = (c, photo.agreement(outline, &c));
    let (ds, dt) = ((SCALES[1] - SCALES[0]) / 2.0, (TURNS_DEG[1] - TURNS_DEG[0]).to_radians() / 2.0);
    for s in [-1.0, 0.0, 1.0] {
        for t in [-1.0, 0.0, 1.0] {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let p = Placement { dx: c.dx + dx as f32, dy: c.dy + dy as f32, scale: c.scale + s * ds, turn: c.turn + t * dt, ..c };
                    let a = photo.agreement(outline, &p);
                    if a > best.1 {
                        best = (p, a);
                    }
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square_mask(w: u32, x0: u32, y0: u32, side: u32) -> GrayImage {
        GrayImage::from_fn(w, w, |x, y| image::Luma([if (x0..x0 + side).contains(&x) && (y0..y0 + side).contains(&y) { 255 } else { 0 }]))
    }

    #[test]
    fn finds_a_shifted_outline_and_discounts_chance() {
        // The render's square sits 4 px left of and 3 px above the photo's.
        let render = square_mask(64, 16, 16, 28);
        let truth = square_mask(64, 20, 19, 28);
        let photo = RgbImage::from_fn(64, 64, |x, y| if truth.get_pixel(x, y)[0] > 0 { image::Rgb([200, 160, 40]) } else { image::Rgb([30, 40, 90]) });
        let edges = PhotoEdges::new(&photo, 20.0);
        let outline = outline_edgels(&render);
        let at_start = edges.agreement(&outline, &Placement::identity(30.0, 30.0));
        let (p, a) = best_placement(&edges, &outline);
        assert!(a > 0.9 && at_start < 0.5, "start {at_start}, best {a}");
        // Within the pixel of tolerance that the photo's spread edges give.
        assert!((p.dx - 4.0).abs() <= 1.0 && (p.dy - 3.0).abs() <= 1.0, "{p:?}");
        // A photo with edges of every orientation everywhere answers any outline, by chance.
        let noise = RgbImage::from_fn(64, 64, |x, y| if (x / 2 + y / 2) % 2 == 0 || (x * 7 + y * 3) % 5 == 0 { image::Rgb([255, 255, 255]) } else { image::Rgb([0, 0, 0]) });
        let busy = PhotoEdges::new(&noise, 20.0);
        let (_, a) = best_placement(&busy, &outline);
        assert!(a < 0.5, "{a}");
    }

    #[test]
    fn interior_edgels_skip_the_outline() {
        let mask = square_mask(48, 8, 8, 32);
        let plain = RgbImage::from_pixel(48, 48, image::Rgb([200, 40, 40]));
        assert!(interior_edgels(&plain, &mask, 20.0).is_empty());
        let striped = RgbImage::from_fn(48, 48, |x, _| if (x / 8) % 2 == 0 { image::Rgb([200, 40, 40]) } else { image::Rgb([40, 40, 200]) });
        let e = interior_edgels(&striped, &mask, 20.0);
        assert!(!e.is_empty() && e.iter().all(|e| (12.0..36.0).contains(&e.x) && (10.0..38.0).contains(&e.y)));
    }
}
