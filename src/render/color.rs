//! sRGB transfer function. Shading happens in linear light and the colour target is an
//! sRGB format, so the GPU re-encodes on write; CPU-side inputs given in sRGB are decoded
//! here once.

pub(crate) fn srgb_to_linear(c: f32) -> f32 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

pub(crate) fn srgb_to_linear3(c: [f32; 3]) -> [f32; 3] {
    c.map(srgb_to_linear)
}

#[cfg(test)]
mod tests {
    #[test]
    fn endpoints_and_midpoint() {
        assert_eq!(super::srgb_to_linear(0.0), 0.0);
        assert!((super::srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((super::srgb_to_linear(0.5) - 0.21404).abs() < 1e-4);
    }
}
