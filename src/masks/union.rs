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

/// Two detections overlapping this much (IoU) are one thing named twice, not one in front
/// of the other.
const SAME_THING_IOU: f64 = 0.5;

/// The union of the `others` detections of an image that may hide the one whose mask is
/// `own`: all but those on the same place (IoU ≥ `SAME_THING_IOU`), which are alternatives
/// to it (the depth detector offers one segment to every object of its size), not
/// occluders of it.
pub fn occluders<'a>(own: &GrayImage, others: impl IntoIterator<Item = &'a GrayImage>, width: u32, height: u32) -> Option<GrayImage> {
    union(others.into_iter().filter(|m| super::mask_iou(own, m) < SAME_THING_IOU), width, height)
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

    #[test]
    fn the_same_place_named_as_another_object_hides_nothing() {
        let own = GrayImage::from_raw(4, 1, vec![255, 255, 0, 0]).unwrap();
        let same = GrayImage::from_raw(4, 1, vec![255, 255, 255, 0]).unwrap();
        let beside = GrayImage::from_raw(4, 1, vec![0, 0, 0, 255]).unwrap();
        assert_eq!(occluders(&own, [&same, &beside], 4, 1).unwrap().as_raw(), &vec![0, 0, 0, 255]);
        assert!(occluders(&own, [&same], 4, 1).is_none());
    }
}
