//! The object's and the background's colour statistics, for tracking without a mask: two
//! RGB histograms (16 levels per channel), learnt from the pixels under the object's
//! silhouette and from a band around it, blended over time so that slow lighting changes
//! are followed. A pixel's foreground probability is P(colour | object) /
//! (P(colour | object) + P(colour | background)), the posterior of the region-based
//! trackers (SRT3D, ICG), with equal priors.

use image::{GrayImage, RgbImage};

const LEVELS: usize = 16;
const BINS: usize = LEVELS * LEVELS * LEVELS;

/// A pixel window: x0, y0 inclusive, x1, y1 exclusive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Window {
    /// The window's rows of `image`, top to bottom: each row's y and its pixels' colours,
    /// read from the raw buffer (no per-pixel bounds checks: the tracker reads its window
    /// of every frame, up to a third of a megapixel, this way).
    pub fn colour_rows<'a>(self, image: &'a RgbImage) -> impl Iterator<Item = (u32, impl Iterator<Item = image::Rgb<u8>> + 'a)> + 'a {
        let (width, x0, x1) = (image.width() as usize, self.x0 as usize, self.x1 as usize);
        (self.y0..self.y1).map(move |y| {
            let row = y as usize * width;
            (y, image.as_raw()[3 * (row + x0)..3 * (row + x1)].chunks_exact(3).map(|c| image::Rgb([c[0], c[1], c[2]])))
        })
    }

    /// The square of half-side `half` around (u, v), clipped to a `width × height` image;
    /// None when nothing of it is inside.
    pub fn around(u: f64, v: f64, half: f64, width: u32, height: u32) -> Option<Self> {
        let clip = |a: f64, n: u32| a.clamp(0.0, n as f64) as u32;
        let w = Self { x0: clip(u - half, width), y0: clip(v - half, height), x1: clip((u + half).ceil(), width), y1: clip((v + half).ceil(), height) };
        (w.x1 > w.x0 && w.y1 > w.y0).then_some(w)
    }

    /// Whether `other` lies inside this window.
    pub fn contains(&self, other: &Window) -> bool {
        self.x0 <= other.x0 && self.y0 <= other.y0 && other.x1 <= self.x1 && other.y1 <= self.y1
    }

    /// The smallest window holding both.
    pub fn union(&self, other: &Window) -> Window {
        Window { x0: self.x0.min(other.x0), y0: self.y0.min(other.y0), x1: self.x1.max(other.x1), y1: self.y1.max(other.y1) }
    }

    pub fn size(&self) -> (u32, u32) {
        (self.x1 - self.x0, self.y1 - self.y0)
    }

    /// Calls `f` on the window's pixels of `image`, row by row, each with whether
    /// `silhouette` (the window's size, non-zero on the object) covers it; false (and no
    /// call) when the silhouette is another size. Raw rows in plain loops rather than an
    /// iterator flattened over the rows: each relearning reads the window (up to a third
    /// of a megapixel) twice this way, and the flattened iterator cost about 0.6 ms more
    /// a relearning (`bench track`, one core).
    pub fn each_with_silhouette(self, image: &RgbImage, silhouette: &GrayImage, mut f: impl FnMut(image::Rgb<u8>, bool)) -> bool {
        if silhouette.dimensions() != self.size() {
            return false;
        }
        let (width, x0, w) = (image.width() as usize, self.x0 as usize, self.size().0 as usize);
        for (y, drawn) in (self.y0 as usize..).zip(silhouette.as_raw().chunks_exact(w)) {
            let start = 3 * (y * width + x0);
            for (c, &m) in image.as_raw()[start..start + 3 * w].chunks_exact(3).zip(drawn) {
                f(image::Rgb([c[0], c[1], c[2]]), m > 0);
            }
        }
        true
    }

    /// `k` seeing only this window: a render through it covers the window's pixels alone.
    pub fn intrinsics(&self, k: &crate::geometry::Intrinsics) -> Option<crate::geometry::Intrinsics> {
        let (w, h) = self.size();
        k.window(self.x0, self.y0, w, h)
    }
}

fn bin(p: &image::Rgb<u8>) -> usize {
    let q = |c: u8| c as usize * LEVELS / 256;
    (q(p[0]) * LEVELS + q(p[1])) * LEVELS + q(p[2])
}

#[derive(Clone)]
pub struct ColourModel {
    foreground: Vec<f32>,
    background: Vec<f32>,
    /// Each bin's foreground probability as a grey level (`probability` × 255, rounded),
    /// kept with the histograms: a frame's probability image is then one lookup a pixel.
    levels: Vec<u8>,
    learnt: bool,
}

impl Default for ColourModel {
    fn default() -> Self {
        // Nothing seen on either side: every colour undecided (probability ½, level 128).
        Self { foreground: vec![0.0; BINS], background: vec![0.0; BINS], levels: vec![128; BINS], learnt: false }
    }
}

impl ColourModel {
    /// Learns from the pixels of `image` in `window`: the object where `silhouette` (the
    /// window's size, non-zero on the object; a render through the window alone) covers
    /// them, the background elsewhere, blending the new histograms in with weight `rate`
    /// (1: replace; the first call always replaces). Returns false, learning nothing, when
    /// either side has no pixel or the silhouette is not the window's size.
    pub fn learn(&mut self, image: &RgbImage, silhouette: &GrayImage, window: Window, rate: f32) -> bool {
        let (mut fg, mut bg) = (vec![0f32; BINS], vec![0f32; BINS]);
        let (mut nf, mut nb) = (0usize, 0usize);
        let read = window.each_with_silhouette(image, silhouette, |c, drawn| {
            let b = bin(&c);
            if drawn {
                fg[b] += 1.0;
                nf += 1;
            } else {
                bg[b] += 1.0;
                nb += 1;
            }
        });
        read && self.blend(&fg, nf, &bg, nb, rate)
    }

    /// Learns from pixels sampled on either side of the object's outline (the tracker's
    /// lines at the pose a frame ended at: no render), blending as `learn` does. `samples`
    /// gives each pixel's colour and whether it lies inside the outline.
    pub fn learn_samples(&mut self, samples: impl IntoIterator<Item = (image::Rgb<u8>, bool)>, rate: f32) -> bool {
        let (mut fg, mut bg) = (vec![0f32; BINS], vec![0f32; BINS]);
        let (mut nf, mut nb) = (0usize, 0usize);
        for (c, inside) in samples {
            let (h, n) = if inside { (&mut fg, &mut nf) } else { (&mut bg, &mut nb) };
            h[bin(&c)] += 1.0;
            *n += 1;
        }
        self.blend(&fg, nf, &bg, nb, rate)
    }

    /// Blends new counts (`nf`, `nb` pixels) into the running histograms with weight
    /// `rate` (the first learning replaces); false, changing nothing, when a side is empty.
    fn blend(&mut self, fg: &[f32], nf: usize, bg: &[f32], nb: usize, rate: f32) -> bool {
        if nf == 0 || nb == 0 {
            return false;
        }
        let rate = if self.learnt { rate.clamp(0.0, 1.0) } else { 1.0 };
        for (h, new, n) in [(&mut self.foreground, fg, nf), (&mut self.background, bg, nb)] {
            for (old, &c) in h.iter_mut().zip(new.iter()) {
                *old = (1.0 - rate) * *old + rate * c / n as f32;
            }
        }
        self.learnt = true;
        self.levels = self.bin_levels();
        true
    }

    /// Foreground probability of one colour; 0.5 for colours neither side has seen.
    pub fn probability(&self, p: &image::Rgb<u8>) -> f32 {
        self.bin_probability(bin(p))
    }

    /// Whether a colour is more likely the object's than the background's (`probability`
    /// over one half), from a table of the bins made once: a test per pixel of a window.
    pub fn object_bins(&self) -> impl Fn(&image::Rgb<u8>) -> bool {
        let object: Vec<bool> = (0..BINS).map(|b| self.bin_probability(b) > 0.5).collect();
        move |p| object[bin(p)]
    }

    fn bin_probability(&self, b: usize) -> f32 {
        let (f, g) = (self.foreground[b], self.background[b]);
        // A floor of one count in ten thousand keeps unseen colours undecided rather than
        // certain either way.
        let floor = 1e-4;
        (f + floor) / (f + g + 2.0 * floor)
    }

    fn bin_levels(&self) -> Vec<u8> {
        (0..BINS).map(|b| (self.bin_probability(b) * 255.0).round() as u8).collect()
    }

    /// An image of foreground probabilities (value / 255) inside `window`, 128 (undecided)
    /// elsewhere.
    pub fn probability_image(&self, image: &RgbImage, window: Window) -> GrayImage {
        let mut out = GrayImage::from_pixel(image.width(), image.height(), image::Luma([128]));
        let (width, (x0, x1)) = (image.width() as usize, (window.x0 as usize, window.x1 as usize));
        let grey = out.as_mut();
        for (y, colours) in window.colour_rows(image) {
            let row = y as usize * width;
            for (level, c) in grey[row + x0..row + x1].iter_mut().zip(colours) {
                *level = self.levels[bin(&c)];
            }
        }
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 40×40 image of a red square (10..30 on both axes) on a blue-green background,
    /// and the square's silhouette.
    pub(crate) fn red_square() -> (RgbImage, GrayImage) {
        let mut img = RgbImage::from_pixel(40, 40, image::Rgb([20, 120, 200]));
        let mut sil = GrayImage::new(40, 40);
        for y in 10..30 {
            for x in 10..30 {
                img.put_pixel(x, y, image::Rgb([220, 30, 30]));
                sil.put_pixel(x, y, image::Luma([255]));
            }
        }
        (img, sil)
    }

    #[test]
    fn a_window_off_the_corner_learns_its_own_pixels() {
        let (img, sil) = red_square();
        // Rows 8..33 and columns 5..35: the square's part in it is object, the rest background.
        let part = Window { x0: 5, y0: 8, x1: 35, y1: 33 };
        let sil_part = image::imageops::crop_imm(&sil, 5, 8, 30, 25).to_image();
        let mut m = ColourModel::default();
        assert!(m.learn(&img, &sil_part, part, 1.0));
        assert!(m.probability(&image::Rgb([220, 30, 30])) > 0.99);
        assert!(m.probability(&image::Rgb([20, 120, 200])) < 0.01);
        // The table of object colours says what the probability says, for every colour.
        let object = m.object_bins();
        for c in (0..=255u8).step_by(5).flat_map(|r| (0..=255u8).step_by(17).map(move |g| image::Rgb([r, g, 255 - r]))) {
            assert_eq!(object(&c), m.probability(&c) > 0.5, "{c:?}");
        }
        assert!(object(&image::Rgb([220, 30, 30])) && !object(&image::Rgb([20, 120, 200])));
    }

    #[test]
    fn samples_blend_in_as_a_silhouettes_pixels_do() {
        let (red, blue, green) = (image::Rgb([220, 30, 30]), image::Rgb([20, 120, 200]), image::Rgb([0, 250, 0]));
        let mut m = ColourModel::default();
        assert!(!m.learn_samples([(red, true)], 1.0), "no background sample");
        assert!(!m.learn_samples([(blue, false)], 1.0), "no object sample");
        assert!((m.probability(&red) - 0.5).abs() < 1e-6, "a refused learning changes nothing");
        // The first learning replaces, whatever the rate.
        assert!(m.learn_samples([(red, true), (red, true), (blue, false)], 0.1));
        assert!(m.probability(&red) > 0.99 && m.probability(&blue) < 0.01);
        // The same counts as a silhouette's: the two models agree on every colour.
        let (img, sil) = red_square();
        let all = Window { x0: 0, y0: 0, x1: 40, y1: 40 };
        let mut from_silhouette = ColourModel::default();
        assert!(from_silhouette.learn(&img, &sil, all, 1.0));
        let mut from_samples = ColourModel::default();
        let samples = img.enumerate_pixels().map(|(x, y, c)| (*c, sil.get_pixel(x, y)[0] > 0));
        assert!(from_samples.learn_samples(samples, 1.0));
        assert_eq!(from_silhouette.levels, from_samples.levels);
        // Later learnings blend at their rate: at 0.5, green (new background) takes half the
        // background's weight, red stays the object's whole.
        assert!(from_samples.learn_samples([(red, true), (green, false)], 0.5));
        assert!((from_samples.probability(&green) - 1e-4 / (0.5 + 2e-4)).abs() < 1e-6);
        assert!((from_samples.probability(&blue) - 1e-4 / (0.5 + 2e-4)).abs() < 1e-6);
        assert!((from_samples.probability(&red) - (1.0 + 1e-4) / (1.0 + 2e-4)).abs() < 1e-6);
    }

    #[test]
    fn learns_which_colours_are_the_object() {
        let (img, sil) = red_square();
        let mut m = ColourModel::default();
        let all = Window::around(20.0, 20.0, 20.0, 40, 40).unwrap();
        assert!(!m.learn(&img, &GrayImage::new(10, 10), all, 0.2), "a silhouette of another size than the window");
        assert!(m.learn(&img, &sil, all, 0.2));
        assert!(m.probability(&image::Rgb([220, 30, 30])) > 0.99);
        assert!(m.probability(&image::Rgb([20, 120, 200])) < 0.01);
        assert!((m.probability(&image::Rgb([0, 255, 0])) - 0.5).abs() < 1e-6);
        let probs = m.probability_image(&img, Window::around(20.0, 20.0, 5.0, 40, 40).unwrap());
        assert_eq!((probs.get_pixel(20, 20)[0], probs.get_pixel(0, 0)[0]), (255, 128));
        // Every pixel of the window is its colour's probability, after a blended relearning
        // too, whatever the colour.
        let mut noisy = img.clone();
        for (i, p) in noisy.pixels_mut().enumerate() {
            p.0 = [(i * 37 % 256) as u8, (i * 91 % 256) as u8, (i * 13 % 256) as u8];
        }
        assert!(m.learn(&noisy, &sil, all, 0.3));
        let window = Window { x0: 3, y0: 5, x1: 31, y1: 38 };
        let probs = m.probability_image(&noisy, window);
        for (x, y, v) in probs.enumerate_pixels() {
            let inside = (window.x0..window.x1).contains(&x) && (window.y0..window.y1).contains(&y);
            let want = if inside { (m.probability(noisy.get_pixel(x, y)) * 255.0).round() as u8 } else { 128 };
            assert_eq!(v[0], want, "at ({x}, {y})");
        }
        // Nothing to learn from a window without background.
        let inner = Window::around(20.0, 20.0, 5.0, 40, 40).unwrap();
        assert!(!m.learn(&img, &image::imageops::crop_imm(&sil, 15, 15, 10, 10).to_image(), inner, 0.2));
        // A window's own intrinsics move the principal point to its corner.
        let k = crate::geometry::Intrinsics::new(50.0, 50.0, 19.5, 19.5, 40, 40).unwrap();
        let wk = inner.intrinsics(&k).unwrap();
        assert_eq!((wk.cx, wk.cy, wk.width, wk.height), (4.5, 4.5, 10, 10));
        assert_eq!(Window::around(-50.0, -50.0, 5.0, 40, 40), None);
        let (a, b) = (Window { x0: 2, y0: 3, x1: 10, y1: 8 }, Window { x0: 5, y0: 1, x1: 12, y1: 6 });
        assert_eq!(a.union(&b), Window { x0: 2, y0: 1, x1: 12, y1: 8 });
        assert!(a.union(&b).contains(&a) && a.union(&b).contains(&b) && !a.contains(&b) && a.contains(&a));
    }
}
