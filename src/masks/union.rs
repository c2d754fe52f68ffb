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

/// A segment sharing more than this share of the smaller one's pixels with another is a
/// reading of the same pixels, not a thing beside it (a sliver is left for closed holes).
const SAME_PIXELS_SHARE: f64 = 0.05;

/// As `occluders`, when all the masks are segments of one depth frame (the depth
/// detector's): two things' segments share no pixel there, and one overlapping `own` is
/// another reading of the same pixels (a part of it cut at a neck or at a depth, or it
/// joined with a neighbour), however small its IoU: the inside of a mug is no occluder of
/// the whole mug.
pub fn occluders_among_segments<'a>(own: &GrayImage, others: impl IntoIterator<Item = &'a GrayImage>, width: u32, height: u32) -> Option<GrayImage> {
    union(others.into_iter().filter(|m| shared_share(own, m) <= SAME_PIXELS_SHARE), width, height)
}

/// The pixels two masks share, as a share of the smaller's (0 when either is empty).
fn shared_share(a: &GrayImage, b: &GrayImage) -> f64 {
    let (mut both, mut in_a, mut in_b) = (0u64, 0u64, 0u64);
    for (&x, &y) in a.as_raw().iter().zip(b.as_raw()) {
        both += (x > 0 && y > 0) as u64;
        in_a += (x > 0) as u64;
        in_b += (y > 0) as u64;
    }
    let smaller = in_a.min(in_b);
    if smaller == 0 {
        0.0
    } else {
        both as f64 / smaller as f64
    }
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

    #[test]
    fn a_segment_sharing_pixels_with_another_is_another_reading_of_them() {
        // The whole (8 px), a part of it (3 px: IoU 0.375), a thing beside it.
        let whole = GrayImage::from_raw(10, 1, vec![255, 255, 255, 255, 255, 255, 255, 255, 0, 0]).unwrap();
        let part = GrayImage::from_raw(10, 1, vec![255, 255, 255, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        let beside = GrayImage::from_raw(10, 1, vec![0, 0, 0, 0, 0, 0, 0, 0, 0, 255]).unwrap();
        assert_eq!(occluders_among_segments(&whole, [&part, &beside], 10, 1).unwrap().as_raw(), beside.as_raw());
        assert_eq!(occluders_among_segments(&part, [&whole], 10, 1), None);
        // Among a caller's detections the part would hide the whole.
        assert_eq!(occluders(&whole, [&part], 10, 1).unwrap().as_raw(), part.as_raw());
    }
}
