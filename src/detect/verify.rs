//! A second look at each candidate: the mesh rendered at the candidate's coarse pose into a
//! small window around it, compared with the image there. Shape matching alone fires on
//! clutter whose edges happen to trace an outline (a painted ellipse looks like a can from
//! above); the render tells whether the whole outline is there at the candidate's exact
//! perspective, and, for meshes with colours, whether the surface has the object's colours.
//! The render's edges are first lined up with the photo's (`align`: the coarse pose is some
//! degrees off), then the outline's and the interior edges' agreement are measured there.
//! No measure depends on brightness, so all survive lighting changes.

use super::align::{best_placement, interior_edgels, outline_edgels, PhotoEdges};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderPool};
use image::{imageops, GrayImage, RgbImage};

/// Longer side of the comparison window, pixels.
const WINDOW_PX: f64 = 64.0;

/// What the render says about one candidate.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Evidence {
    /// Share of the rendered outline where the image has an edge of that orientation
    /// (within a pixel and a bin), 0–1.
    pub outline: f32,
    /// Overlap of the render's and the image's chromaticity histograms inside the
    /// silhouette, 0–1; `None` for a mesh without colours (its grey render says nothing
    /// about the surface).
    pub colour: Option<f32>,
    /// Share of the render's interior edges (print, creases) that the photo answers at the
    /// outline's best placement, above chance; `None` when the render has too few.
    pub texture: Option<f32>,
}

/// Edge thresholds (gradient magnitude): the photo's, low since edges at this size are
/// softened by resampling; the render's interior, higher, so that only clear print counts.
const PHOTO_EDGE: f32 = 20.0;
const RENDER_EDGE: f32 = 40.0;
/// Fewer interior edgels than this say nothing about the surface.
const MIN_INTERIOR_EDGELS: usize = 12;

/// The photo around one candidate, prepared once for every render compared with it: the
/// window `bbox` (x, y, w, h) grown by a fifth on each side, resampled to about
/// `WINDOW_PX` across, its edges, and the intrinsics that render into it.
pub struct Window {
    intrinsics: Intrinsics,
    photo: RgbImage,
    edges: PhotoEdges,
}

impl Window {
    /// `None` when the window is under 4 pixels across (nothing to compare).
    pub fn new(image: &RgbImage, k: &Intrinsics, bbox: [f64; 4]) -> Option<Self> {
        let grow = 0.2 * bbox[2].max(bbox[3]);
        let x0 = (bbox[0] - grow).floor().max(0.0);
        let y0 = (bbox[1] - grow).floor().max(0.0);
        let x1 = (bbox[0] + bbox[2] + grow).ceil().min(image.width() as f64);
        let y1 = (bbox[1] + bbox[3] + grow).ceil().min(image.height() as f64);
        if x1 - x0 < 4.0 || y1 - y0 < 4.0 {
            return None;
        }
        let s = (WINDOW_PX / (x1 - x0).max(y1 - y0)).min(1.0);
        let (w, h) = (((x1 - x0) * s).round().max(4.0) as u32, ((y1 - y0) * s).round().max(4.0) as u32);
        let (sx, sy) = (w as f64 / (x1 - x0), h as f64 / (y1 - y0));
        // Pixel centres at integers on both sides: window pixel i sits at x0 + (i + ½)/s − ½.
        let intrinsics = Intrinsics { fx: k.fx * sx, fy: k.fy * sy, cx: (k.cx - x0 + 0.5) * sx - 0.5, cy: (k.cy - y0 + 0.5) * sy - 0.5, width: w, height: h };
        let crop = imageops::crop_imm(image, x0 as u32, y0 as u32, (x1 - x0) as u32, (y1 - y0) as u32).to_image();
        let photo = imageops::resize(&crop, w, h, imageops::FilterType::Triangle);
        let edges = PhotoEdges::new(&photo, PHOTO_EDGE);
        Some(Self { intrinsics, photo, edges })
    }

    /// Renders `mesh` at `pose` into the window and compares it with the photo there.
    pub fn evidence(&self, renderer: &RenderPool, mesh: &Mesh, pose: &Pose) -> Result<Evidence, RenderError> {
        let render = renderer.render(mesh, pose, &self.intrinsics, &RenderOptions::default())?;
        let (placement, outline) = best_placement(&self.edges, &outline_edgels(&render.mask));
        let inner = interior_edgels(&render.rgb, &render.mask, RENDER_EDGE);
        let texture = (inner.len() >= MIN_INTERIOR_EDGELS).then(|| self.edges.agreement(&inner, &placement));
        let colour = mesh.has_colours().then(|| chroma_overlap(&render.rgb, &render.mask, &self.photo));
        Ok(Evidence { outline, colour, texture })
    }
}

/// Chromaticity bins per axis (r/(r+g+b), g/(r+g+b)), plus one bin for dark pixels.
const CHROMA_BINS: usize = 6;
pub const CHROMA_HISTOGRAM_LEN: usize = CHROMA_BINS * CHROMA_BINS + 1;
/// r + g + b below this is too dark to have a reliable chromaticity.
const DARK: u32 = 90;

/// The chromaticity bin of a pixel (brightness-free; one bin for the dark ones).
pub fn chroma_bin(p: &image::Rgb<u8>) -> usize {
    let sum = p[0] as u32 + p[1] as u32 + p[2] as u32;
    if sum < DARK {
        return CHROMA_BINS * CHROMA_BINS;
    }
    let q = |v: u8| ((v as f32 / sum as f32) * CHROMA_BINS as f32).min(CHROMA_BINS as f32 - 1.0) as usize;
    q(p[0]) * CHROMA_BINS + q(p[1])
}

/// Normalised histogram of the chromaticities of the pixels inside `mask`.
pub fn chroma_histogram(rgb: &RgbImage, mask: &GrayImage) -> Vec<f32> {
    let mut h = vec![0f32; CHROMA_HISTOGRAM_LEN];
    for (p, m) in rgb.pixels().zip(mask.as_raw()) {
        if *m > 0 {
            h[chroma_bin(p)] += 1.0;
        }
    }
    let n: f32 = h.iter().sum();
    if n > 0.0 {
        h.iter_mut().for_each(|v| *v /= n);
    }
    h
}

/// Histogram intersection of the render's and the photo's chromaticities over the
/// silhouette: which colours the surface has, not where (so a pose some degrees off, or
/// turned by a symmetry of its outline, still agrees), and free of brightness.
fn chroma_overlap(render: &RgbImage, mask: &GrayImage, photo: &RgbImage) -> f32 {
    if mask.as_raw().iter().filter(|&&m| m > 0).count() < 16 {
        return 0.0;
    }
    let (a, b) = (chroma_histogram(render, mask), chroma_histogram(photo, mask));
    a.iter().zip(&b).map(|(x, y)| x.min(*y)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc(w: u32, r: f64) -> GrayImage {
        GrayImage::from_fn(w, w, |x, y| image::Luma([if (x as f64 - w as f64 / 2.0).hypot(y as f64 - w as f64 / 2.0) < r { 255 } else { 0 }]))
    }

    #[test]
    fn an_outline_present_in_the_photo_agrees_and_an_absent_one_does_not() {
        let m = disc(48, 14.0);
        let photo = RgbImage::from_fn(48, 48, |x, y| if m.get_pixel(x, y)[0] > 0 { image::Rgb([200, 180, 40]) } else { image::Rgb([30, 60, 90]) });
        let agreement = |photo: &RgbImage| best_placement(&PhotoEdges::new(photo, PHOTO_EDGE), &outline_edgels(&m)).1;
        assert!(agreement(&photo) > 0.9);
        let flat = RgbImage::from_pixel(48, 48, image::Rgb([90, 90, 90]));
        assert_eq!(agreement(&flat), 0.0);
    }

    #[test]
    fn chromaticities_overlap_under_brightness_changes_only() {
        let m = disc(48, 18.0);
        let stripes = RgbImage::from_fn(48, 48, |x, _| if (x / 6) % 2 == 0 { image::Rgb([220, 40, 40]) } else { image::Rgb([40, 40, 220]) });
        let darker = RgbImage::from_fn(48, 48, |x, y| image::Rgb(stripes.get_pixel(x, y).0.map(|v| (v as f32 * 0.7) as u8)));
        assert!(chroma_overlap(&stripes, &m, &darker) > 0.9);
        let flat = RgbImage::from_pixel(48, 48, image::Rgb([200, 40, 40]));
        let o = chroma_overlap(&stripes, &m, &flat);
        assert!((0.3..0.7).contains(&o), "{o}");
        let green = RgbImage::from_pixel(48, 48, image::Rgb([40, 200, 40]));
        assert!(chroma_overlap(&stripes, &m, &green) < 0.05);
    }
}
