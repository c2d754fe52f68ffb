//! Per-image lighting and degradations drawn from an `Appearance`, applied with the
//! functions of `eval::degrade`.

use super::config::Appearance;
use crate::eval::degrade::{add_noise, color_shift, gaussian_blur, jpeg_round_trip, PrintDrift};
use crate::mesh::procedural::Rng;
use crate::render::RenderOptions;
use image::{GrayImage, RgbImage};

fn draw(rng: &mut Rng, (lo, hi): (f64, f64)) -> f64 {
    rng.range(lo, hi)
}

/// One light for the whole image, so that all its objects are lit alike. The mesh is
/// shown as it is (texture and vertex colours on): only the templates are bare.
pub(super) fn sample_lighting(a: &Appearance, rng: &mut Rng) -> RenderOptions {
    // Uniform over the spherical cap within `light_angle_deg` of the headlight direction.
    let cos_max = a.light_angle_deg.to_radians().cos();
    let cos_t = rng.range(cos_max, 1.0);
    let sin_t = (1.0 - cos_t * cos_t).sqrt();
    let phi = rng.range(0.0, std::f64::consts::TAU);
    let light_dir = [(sin_t * phi.cos()) as f32, (sin_t * phi.sin()) as f32, -cos_t as f32];
    let f32s = |(lo, hi): (f32, f32)| (lo as f64, hi as f64);
    RenderOptions {
        light_dir,
        light_intensity: draw(rng, f32s(a.light_intensity)) as f32,
        ambient: draw(rng, f32s(a.ambient)) as f32,
        use_texture: true,
        use_vertex_colors: true,
        ..RenderOptions::default()
    }
}

/// Optics blur, then white balance / exposure, then sensor noise, as a camera orders them.
pub(super) fn degrade(img: &RgbImage, a: &Appearance, rng: &mut Rng) -> RgbImage {
    let sigma = draw(rng, a.blur_sigma);
    let gains: [f64; 3] = std::array::from_fn(|_| 1.0 + rng.range(-a.color_gain, a.color_gain));
    let offsets: [f64; 3] = std::array::from_fn(|_| rng.range(-a.color_offset, a.color_offset));
    let noise = draw(rng, a.noise_sigma);
    let shifted = color_shift(&gaussian_blur(img, sigma), gains, offsets);
    if noise > 0.0 {
        add_noise(&shifted, noise, rng)
    } else {
        shifted
    }
}

/// An object's print drifting from its mesh's texture, on its render alone (so the drift
/// follows the object, not the image). Draws nothing when the appearance has no drift, so
/// such scenes stay as they were.
pub(super) fn drift_print(rgb: &mut RgbImage, mask: &GrayImage, a: &Appearance, rng: &mut Rng) {
    if a.print_gain > 0.0 || a.print_shift_px > 0.0 {
        PrintDrift::sample(a.print_gain, a.print_shift_px, rng).apply(rgb, mask);
    }
}

/// The photo as stored: a JPEG round trip at a quality drawn from the appearance's range,
/// or the image itself when it has none.
pub(super) fn as_stored(img: RgbImage, a: &Appearance, rng: &mut Rng) -> anyhow::Result<RgbImage> {
    match a.jpeg_quality {
        Some((lo, hi)) => jpeg_round_trip(&img, rng.range(lo as f64, hi as f64 + 1.0).floor().min(hi as f64) as u8),
        None => Ok(img),
    }
}
