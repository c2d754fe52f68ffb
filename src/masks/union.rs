//! The union of several masks: where any of them marks the object. The estimator reads the
//! union of the other detections in an image as "this object may be hidden here".

use image::GrayImage;

/// Non-zero wherever any of `masks` is (each `width × height`); `None` for no mask.
pub fn union<'a>(masks: impl IntoIterator<Item = &'a GrayImage>, width: u32, height: u32) -> Option<GrayImage> {
    let mut out: Option<GrayImage> = None;
    for m in masks {
        let u = out.get_or_insert_with(|| GrayImage::new(width, height));
        for (o, p) in u.pixels_mut().zip(m.pixels()) {
            o[0] |= p[0];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_of_two_and_of_none() {
        let a = GrayImage::from_raw(3, 1, vec![255, 0, 0]).unwrap();
        let b = GrayImage::from_raw(3, 1, vec![0, 0, 7]).unwrap();
        assert_eq!(union([&a, &b], 3, 1).unwrap().as_raw(), &vec![255, 0, 7]);
        assert!(union([], 3, 1).is_none());
    }
}
