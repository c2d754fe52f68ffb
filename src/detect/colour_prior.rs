//! Where an object with colours may be, before any template is tried: each pixel's
//! probability of being the object judged by its chromaticity alone (the object's colour
//! histogram, from its renders at onboarding, against the whole image's), summed in an
//! integral image so any box's mean is four lookups. Painted clutter that traces an
//! object's outline rarely has its colours; this ranks candidates before the costly
//! verification cuts them.

use super::verify::chroma_bin;
use image::RgbImage;

pub struct ColourPrior {
    width: usize,
    height: usize,
    /// (width + 1) × (height + 1) running sums of the per-pixel probability.
    integral: Vec<f64>,
}

impl ColourPrior {
    /// `object`: the object's normalised chromaticity histogram.
    pub fn new(object: &[f32], image: &RgbImage) -> ColourPrior {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let mut scene = vec![0f32; object.len()];
        let bins: Vec<usize> = image.pixels().map(chroma_bin).collect();
        for &b in &bins {
            scene[b] += 1.0;
        }
        let n = bins.len().max(1) as f32;
        // P(object | colour) with equal priors: the object's share of the colour's mass.
        let p: Vec<f64> = object.iter().zip(&scene).map(|(&o, &s)| (o / (o + s / n + 1e-6)) as f64).collect();
        let mut integral = vec![0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += p[bins[y * w + x]];
                integral[(y + 1) * (w + 1) + x + 1] = integral[y * (w + 1) + x + 1] + row;
            }
        }
        ColourPrior { width: w, height: h, integral }
    }

    /// Mean probability over the pixels of [x0, x1) × [y0, y1), clipped to the image
    /// (0 for a box outside it).
    pub fn box_mean(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> f32 {
        let cx = |v: i64| v.clamp(0, self.width as i64) as usize;
        let cy = |v: i64| v.clamp(0, self.height as i64) as usize;
        let (x0, x1, y0, y1) = (cx(x0), cx(x1), cy(y0), cy(y1));
        if x0 >= x1 || y0 >= y1 {
            return 0.0;
        }
        let at = |x: usize, y: usize| self.integral[y * (self.width + 1) + x];
        let sum = at(x1, y1) - at(x0, y1) - at(x1, y0) + at(x0, y0);
        (sum / ((x1 - x0) * (y1 - y0)) as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_objects_colours_stand_out_from_the_rest() {
        // Green background, a red square: an object histogram of pure red.
        let img = RgbImage::from_fn(40, 40, |x, y| if (10..20).contains(&x) && (10..20).contains(&y) { image::Rgb([200, 30, 30]) } else { image::Rgb([30, 200, 30]) });
        let mut object = vec![0f32; super::super::verify::CHROMA_HISTOGRAM_LEN];
        object[chroma_bin(&image::Rgb([200, 30, 30]))] = 1.0;
        let p = ColourPrior::new(&object, &img);
        assert!(p.box_mean(10, 10, 20, 20) > 0.8);
        assert!(p.box_mean(25, 25, 35, 35) < 0.01);
        // Half the box on the square.
        let half = p.box_mean(15, 10, 25, 20);
        assert!((half - p.box_mean(10, 10, 20, 20) / 2.0).abs() < 0.01, "{half}");
        assert_eq!(p.box_mean(50, 50, 60, 60), 0.0);
    }
}
