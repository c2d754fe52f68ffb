//! Between a scene composited at `s`× the resolution and the image a camera records: the
//! colour of each pixel is the mean over its `s`×`s` block (a sensor pixel integrates
//! the light over its area, so an outline blends into what is behind it), while masks and
//! depth take the block's centre sample (what a renderer at the image's resolution gives,
//! as BOP's ground truth has it). `s` is odd, so every block has a centre.

use image::{GrayImage, RgbImage};

/// The mean colour of each `s`×`s` block (rounded).
pub(super) fn average_down(img: &RgbImage, s: u32) -> RgbImage {
    let area = s * s;
    RgbImage::from_fn(img.width() / s, img.height() / s, |x, y| {
        let mut sum = [0u32; 3];
        for dy in 0..s {
            for dx in 0..s {
                let p = img.get_pixel(x * s + dx, y * s + dy);
                sum.iter_mut().zip(p.0).for_each(|(a, v)| *a += v as u32);
            }
        }
        image::Rgb(sum.map(|v| ((v + area / 2) / area) as u8))
    })
}

/// Each block's centre pixel of a mask.
pub(super) fn centre_samples(mask: &GrayImage, s: u32) -> GrayImage {
    let c = s / 2;
    GrayImage::from_fn(mask.width() / s, mask.height() / s, |x, y| *mask.get_pixel(x * s + c, y * s + c))
}

/// Each block's centre value of a row-major `width`-wide depth image.
pub(super) fn centre_depth(depth: &[f32], width: u32, s: u32) -> Vec<f32> {
    let (w, h, c) = (width / s, depth.len() as u32 / width / s, s / 2);
    (0..h).flat_map(|y| (0..w).map(move |x| ((y * s + c) * width + x * s + c) as usize)).map(|i| depth[i]).collect()
}

/// Each pixel repeated over an `s`×`s` block: a picture made at the image's resolution
/// (the clutter) that `average_down` gives back unchanged.
pub(super) fn repeat_up(img: &RgbImage, s: u32) -> RgbImage {
    RgbImage::from_fn(img.width() * s, img.height() * s, |x, y| *img.get_pixel(x / s, y / s))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_average_and_centres_sample() {
        // A 6×3 picture, two blocks of 3×3: the left block's first two columns white (its
        // centre column among them), the right block black.
        let img = RgbImage::from_fn(6, 3, |x, _| if x < 2 { image::Rgb([255, 255, 255]) } else { image::Rgb([0, 0, 0]) });
        let small = average_down(&img, 3);
        assert_eq!(small.dimensions(), (2, 1));
        assert_eq!(small.get_pixel(0, 0).0, [170, 170, 170]); // 6 of 9 white
        assert_eq!(small.get_pixel(1, 0).0, [0, 0, 0]);
        let mask = GrayImage::from_fn(6, 3, |x, _| image::Luma([if x < 2 { 255 } else { 0 }]));
        let m = centre_samples(&mask, 3);
        assert_eq!((m.get_pixel(0, 0)[0], m.get_pixel(1, 0)[0]), (255, 0));
        let depth: Vec<f32> = (0..18).map(|i| i as f32).collect();
        assert_eq!(centre_depth(&depth, 6, 3), vec![7.0, 10.0]); // (1, 1) and (4, 1)
        assert_eq!(average_down(&repeat_up(&small, 3), 3), small);
    }
}
