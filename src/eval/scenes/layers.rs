//! Depth compositing of one image: per pixel, which surface is nearest (an object, an
//! occluder or nothing) and at what depth. Visible masks and fractions follow from it.

use super::occluders::{Occluder, OccluderPhoto};
use crate::render::RenderOutput;
use image::{GrayImage, RgbImage};

/// Who owns a pixel. Small, so that a trial copy of a 640×480 image is cheap.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Owner {
    Background,
    Object(u8),
    Occluder(u8),
}

#[derive(Clone, Debug)]
pub(super) struct Layers {
    width: u32,
    height: u32,
    owner: Vec<Owner>,
    /// Metres along the optical axis; 0 where nothing is (the clutter is a picture, not
    /// geometry, so it has no depth: BOP's "no measurement").
    depth: Vec<f32>,
}

impl Layers {
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        Self { width, height, owner: vec![Owner::Background; n], depth: vec![0.0; n] }
    }

    pub fn depth(&self) -> &[f32] {
        &self.depth
    }

    fn cover(&mut self, i: usize, z: f32, who: Owner) {
        if z > 0.0 && (self.depth[i] == 0.0 || z < self.depth[i]) {
            self.depth[i] = z;
            self.owner[i] = who;
        }
    }

    /// Adds object `index` rendered alone; the nearest surface wins each pixel.
    pub fn add_object(&mut self, index: usize, render: &RenderOutput) {
        let who = Owner::Object(u8::try_from(index).expect("few objects per image"));
        for (i, &z) in render.depth.iter().enumerate() {
            self.cover(i, z, who);
        }
    }

    /// Adds a flat occluder at depth `z` (metres), fronto-parallel.
    pub fn add_occluder(&mut self, index: usize, occ: &Occluder, z: f32) {
        let who = Owner::Occluder(u8::try_from(index).expect("few occluders per image"));
        let [x0, y0, x1, y1] = occ.shape.pixel_bounds(self.width, self.height);
        for y in y0..y1 {
            for x in x0..x1 {
                if occ.shape.contains(x as f64, y as f64) {
                    self.cover((y * self.width + x) as usize, z, who);
                }
            }
        }
    }

    /// Nearest depth in the image, 0 if empty.
    pub fn nearest(&self) -> f32 {
        self.depth.iter().copied().filter(|&z| z > 0.0).fold(0.0, |a, z| if a == 0.0 { z } else { a.min(z) })
    }

    /// Visible pixels of each of the first `n` objects.
    pub fn visible_counts(&self, n: usize) -> Vec<usize> {
        let mut counts = vec![0; n];
        for o in &self.owner {
            if let Owner::Object(i) = *o {
                counts[i as usize] += 1;
            }
        }
        counts
    }

    /// Visible fraction of each object whose full silhouette has `full[i]` pixels.
    pub fn visible_fractions(&self, full: &[usize]) -> Vec<f64> {
        self.visible_counts(full.len()).iter().zip(full).map(|(&v, &a)| v as f64 / a.max(1) as f64).collect()
    }

    /// Smallest visible fraction over objects whose full silhouettes have `full` pixels.
    pub fn min_visible_fraction(&self, full: &[usize]) -> f64 {
        self.visible_fractions(full).into_iter().fold(1.0, f64::min)
    }

    pub fn visible_mask(&self, index: usize) -> GrayImage {
        let me = Owner::Object(index as u8);
        let px = self.owner.iter().map(|&o| if o == me { 255 } else { 0 }).collect();
        GrayImage::from_raw(self.width, self.height, px).expect("sized by construction")
    }

    /// Each pixel from its owner: the object's render, the occluder's colour, or `background`.
    pub fn paint(&self, renders: &[&RenderOutput], occluders: &[Occluder], occluder_photo: Option<&OccluderPhoto>, background: &RgbImage) -> RgbImage {
        RgbImage::from_fn(self.width, self.height, |x, y| match self.owner[(y * self.width + x) as usize] {
            Owner::Background => *background.get_pixel(x, y),
            Owner::Object(i) => *renders[i as usize].rgb.get_pixel(x, y),
            Owner::Occluder(j) => match occluder_photo {
                Some(photo) => photo.pixel(j as usize, x, y),
                None => image::Rgb(occluders[j as usize].color),
            },
        })
    }
}
