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

/// A segment sharing more than this share of the smaller one's pixels with another is a
/// reading of the same pixels, not a thing beside it (a sliver is left for closed holes).
const SAME_PIXELS_SHARE: f64 = 0.05;

/// What the other masks of an image are, which decides which of them are the same thing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OtherMasks {
    /// A caller's (or the colour detector's) detections: one on the same place (IoU ≥
    /// `SAME_THING_IOU`) is the same thing named again.
    Detections,
    /// Segments of one depth frame (the depth detector's): two things' segments share no
    /// pixel there, so one overlapping by more than a sliver is another reading of the same
    /// pixels (a part cut at a neck or at a depth, or it joined with a neighbour), however
    /// small its IoU: the inside of a mug is no occluder of the whole mug.
    DepthSegments,
}

/// The union of the `others` masks of an image that may hide the one whose mask is `own`:
/// all but those that are the same thing (`OtherMasks` says which), alternatives to it
/// (the depth detector offers one segment to every object of its size), not occluders.
pub fn occluders<'a>(own: &GrayImage, others: impl IntoIterator<Item = &'a GrayImage>, kind: OtherMasks, width: u32, height: u32) -> Option<GrayImage> {
    let same_thing = |m: &GrayImage| {
        let (both, in_own, in_m) = super::instances::overlap_counts(own, m);
        match kind {
            OtherMasks::Detections => {
                let union = in_own + in_m - both;
                union > 0 && both as f64 / union as f64 >= SAME_THING_IOU
            }
            OtherMasks::DepthSegments => {
                let smaller = in_own.min(in_m);
                smaller > 0 && both as f64 / smaller as f64 > SAME_PIXELS_SHARE
            }
        }
    };
    union(others.into_iter().filter(|m| !same_thing(m)), width, height)
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
        assert_eq!(occluders(&own, [&same, &beside], OtherMasks::Detections, 4, 1).unwrap().as_raw(), &vec![0, 0, 0, 255]);
        assert!(occluders(&own, [&same], OtherMasks::Detections, 4, 1).is_none());
    }

    #[test]
    fn a_segment_sharing_pixels_with_another_is_another_reading_of_them() {
        // The whole (8 px), a part of it (3 px: IoU 0.375), a thing beside it.
        let whole = GrayImage::from_raw(10, 1, vec![255, 255, 255, 255, 255, 255, 255, 255, 0, 0]).unwrap();
        let part = GrayImage::from_raw(10, 1, vec![255, 255, 255, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        let beside = GrayImage::from_raw(10, 1, vec![0, 0, 0, 0, 0, 0, 0, 0, 0, 255]).unwrap();
        assert_eq!(occluders(&whole, [&part, &beside], OtherMasks::DepthSegments, 10, 1).unwrap().as_raw(), beside.as_raw());
        assert_eq!(occluders(&part, [&whole], OtherMasks::DepthSegments, 10, 1), None);
        // Among a caller's detections the part would hide the whole.
        assert_eq!(occluders(&whole, [&part], OtherMasks::Detections, 10, 1).unwrap().as_raw(), part.as_raw());
    }
}
