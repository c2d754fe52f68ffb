//! Masks from what callers send: PNG/JPEG bytes, an RLE, or a box `[x, y, w, h]`. Every
//! error says what is wrong with the input, so the service can put the field name in front
//! and answer 400, and the BOP runner can count the detection as unusable.

use super::pixel_box::PixelBox;
use super::rle::Rle;
use super::segment::{segment_box, Method, SegmentConfig, Segmentation};
use super::{MaskError, OBJECT};
use crate::limits::REQUEST_IMAGE;
use image::{DynamicImage, GrayImage, Luma, RgbImage};
use std::time::Instant;

/// How a box-only detection becomes a mask.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BoxMask {
    /// Several proposals ([`super::proposals`]), among which the estimator chooses by
    /// the poses they lead to.
    #[default]
    Propose,
    /// One segmentation of the object inside the box ([`segment_box`]).
    Segment,
    /// The whole box (the behaviour before segmentation existed; a poor outline).
    Fill,
}

impl std::str::FromStr for BoxMask {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "propose" => Ok(BoxMask::Propose),
            "segment" => Ok(BoxMask::Segment),
            "fill" => Ok(BoxMask::Fill),
            other => Err(format!("box mask {other:?}: expected propose, segment or fill")),
        }
    }
}

/// Object = any nonzero colour channel, whatever the PNG's colour type (L, LA, RGB,
/// RGBA): a red-on-black mask has a nonzero luma but a blue one may not. Alpha is ignored.
pub fn binarise(img: &DynamicImage) -> GrayImage {
    let rgb = img.to_rgb8();
    GrayImage::from_fn(rgb.width(), rgb.height(), |x, y| Luma([if rgb.get_pixel(x, y).0.iter().any(|&c| c > 0) { OBJECT } else { 0 }]))
}

/// A `width × height` mask from PNG (or JPEG) bytes; a mask of another size is refused
/// from its header, before decoding.
pub fn mask_from_png(bytes: &[u8], width: u32, height: u32) -> Result<GrayImage, MaskError> {
    let expect = |mask_width, mask_height| match (mask_width, mask_height) == (width, height) {
        true => Ok(()),
        false => Err(MaskError::SizeMismatch { mask_width, mask_height, width, height }),
    };
    Ok(binarise(&REQUEST_IMAGE.decode_expecting(bytes, expect)?))
}

/// A `width × height` mask from an RLE, whose size must be the image's.
pub fn mask_from_rle(rle: &Rle, width: u32, height: u32) -> Result<GrayImage, MaskError> {
    if (rle.width(), rle.height()) != (width, height) {
        return Err(MaskError::SizeMismatch { mask_width: rle.width(), mask_height: rle.height(), width, height });
    }
    Ok(rle.decode()?)
}

pub fn check_size(mask: GrayImage, width: u32, height: u32) -> Result<GrayImage, MaskError> {
    if mask.dimensions() != (width, height) {
        return Err(MaskError::SizeMismatch { mask_width: mask.width(), mask_height: mask.height(), width, height });
    }
    Ok(mask)
}

/// An empty mask gives no crop, no silhouette and no pose: refuse it where it enters.
pub fn require_nonempty(mask: GrayImage) -> Result<GrayImage, MaskError> {
    if mask.as_raw().iter().all(|&v| v == 0) {
        return Err(MaskError::Empty);
    }
    Ok(mask)
}

/// The mask of a box-only detection on `image`: the object segmented inside the box, or
/// the filled box. The box is validated and clipped first.
pub fn box_to_mask(image: &RgbImage, bbox: [f64; 4], how: BoxMask) -> Result<Segmentation, MaskError> {
    box_to_mask_with(image, bbox, how, &SegmentConfig::default())
}

/// `box_to_mask` with the segmentation's settings (`Propose` makes the one segmentation
/// too: a single mask has no choice to offer).
pub fn box_to_mask_with(image: &RgbImage, bbox: [f64; 4], how: BoxMask, cfg: &SegmentConfig) -> Result<Segmentation, MaskError> {
    let b = PixelBox::from_xywh(bbox, image.width(), image.height())?;
    Ok(match how {
        BoxMask::Propose | BoxMask::Segment => segment_box(image, &b, cfg),
        BoxMask::Fill => {
            let t = Instant::now();
            let mask = b.filled(image.width(), image.height());
            Segmentation { mask, method: Method::Fill, fill: 1.0, ms: t.elapsed().as_secs_f64() * 1e3, note: None }
        }
    })
}

/// What a box-only detection offers the estimator: the box clipped to `image`, whether its
/// masks are proposals to choose among (`Propose`), the masks, never empty, and the
/// proposal sources still to try where the first one's pose does not fit it.
pub struct BoxMasks {
    pub bbox: PixelBox,
    pub proposed: bool,
    pub masks: Vec<GrayImage>,
    pub later: Option<super::ProposalConfig>,
}

/// The masks of a box-only detection as `how` says: the first proposal of
/// [`super::proposals::propose_first`] (every one where it is the only source or declines)
/// with the sources still to try, or the one mask of [`box_to_mask`].
pub fn box_masks(image: &RgbImage, bbox: [f64; 4], how: BoxMask, proposals: &super::ProposalConfig) -> Result<BoxMasks, MaskError> {
    let b = PixelBox::from_xywh(bbox, image.width(), image.height())?;
    Ok(match how {
        BoxMask::Propose => {
            let (first, later) = super::proposals::propose_first(image, &b, proposals);
            BoxMasks { bbox: b, proposed: true, masks: first.into_iter().map(|p| p.mask).collect(), later }
        }
        one => BoxMasks { bbox: b, proposed: false, masks: vec![box_to_mask(image, bbox, one)?.mask], later: None },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ones(m: &GrayImage) -> usize {
        m.pixels().filter(|p| p[0] == OBJECT).count()
    }

    #[test]
    fn fractional_box_covers_partly_covered_pixels_and_is_clipped() {
        let b = PixelBox::from_xywh([1.5, 1.0, 2.0, 2.0], 10, 10).unwrap();
        assert_eq!(b, PixelBox { x0: 1, y0: 1, x1: 4, y1: 3 });
        let on: Vec<(u32, u32)> = b.filled(10, 10).enumerate_pixels().filter(|p| p.2[0] == OBJECT).map(|p| (p.0, p.1)).collect();
        assert_eq!(on, vec![(1, 1), (2, 1), (3, 1), (1, 2), (2, 2), (3, 2)]);
        let clipped = PixelBox::from_xywh([-5.0, 8.0, 7.0, 100.0], 10, 10).unwrap();
        assert_eq!(ones(&clipped.filled(10, 10)), 2 * 2);
        // Touching the border from inside is fine.
        assert_eq!(PixelBox::from_xywh([0.0, 0.0, 10.0, 10.0], 10, 10).unwrap().area(), 100);
    }

    #[test]
    fn bad_boxes_say_what_is_wrong() {
        let cases: [([f64; 4], &str); 6] = [
            ([20.0, 0.0, 5.0, 5.0], "lies outside the 10×10 image"),
            ([-8.0, -8.0, 8.0, 8.0], "lies outside the 10×10 image"),
            ([2.0, 2.0, 0.0, 3.0], "zero area"),
            ([2.0, 2.0, 3.0, -1.0], "zero area"),
            ([f64::NAN, 2.0, 3.0, 3.0], "non-finite"),
            ([2.0, 2.0, f64::INFINITY, 3.0], "non-finite"),
        ];
        for (bbox, expected) in cases {
            let err = PixelBox::from_xywh(bbox, 10, 10).unwrap_err().to_string();
            assert!(err.contains(expected), "{bbox:?}: {err}");
            let image = RgbImage::new(10, 10);
            for how in [BoxMask::Propose, BoxMask::Segment, BoxMask::Fill] {
                assert_eq!(box_to_mask(&image, bbox, how).unwrap_err().to_string(), err);
            }
        }
    }

    #[test]
    fn png_masks_are_binarised_and_size_checked() {
        let mut rgb = RgbImage::new(4, 3);
        rgb.put_pixel(1, 1, image::Rgb([0, 0, 1])); // luma 0, still object
        let mut png = Vec::new();
        DynamicImage::ImageRgb8(rgb).write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        let mask = mask_from_png(&png, 4, 3).unwrap();
        assert_eq!(ones(&mask), 1);
        assert_eq!(mask.get_pixel(1, 1)[0], OBJECT);
        let err = mask_from_png(&png, 3, 4).unwrap_err().to_string();
        assert_eq!(err, "mask is 4×3 (w×h) but the image is 3×4");
        assert!(mask_from_png(b"not a png", 4, 3).unwrap_err().to_string().starts_with("not a readable PNG/JPEG image"));
        // A header claiming a huge mask is refused before any pixel is allocated.
        let huge = crate::limits::tests::png_header_only(40_000, 40_000);
        assert_eq!(mask_from_png(&huge, 40_000, 40_000).unwrap_err().to_string(), "mask 40000×40000 is over the limit of 16384 pixels a side and 40000000 pixels in all");
        // One within the limits but of another size is refused from its header too.
        let other = crate::limits::tests::png_header_only(5_000, 4_000);
        assert!(matches!(mask_from_png(&other, 4, 3), Err(MaskError::SizeMismatch { mask_width: 5_000, .. })));
    }

    #[test]
    fn rle_masks_are_size_checked_and_empty_masks_refused() {
        let rle = Rle::new([3, 2], vec![0, 1, 2, 1, 1, 1]).unwrap();
        let mask = mask_from_rle(&rle, 2, 3).unwrap();
        assert_eq!(ones(&mask), 3);
        assert_eq!(mask_from_rle(&rle, 3, 2).unwrap_err().to_string(), "mask is 2×3 (w×h) but the image is 3×2");
        let empty = Rle::encode(&GrayImage::new(5, 5));
        let err = require_nonempty(mask_from_rle(&empty, 5, 5).unwrap()).unwrap_err();
        assert_eq!(err.to_string(), "the mask is empty (no nonzero pixel)");
        assert!(require_nonempty(mask).is_ok());
    }

    #[test]
    fn fill_gives_the_old_filled_box() {
        let image = RgbImage::new(10, 10);
        let s = box_to_mask(&image, [1.5, 1.0, 2.0, 2.0], BoxMask::Fill).unwrap();
        assert_eq!((s.method, ones(&s.mask)), (Method::Fill, 6));
        assert_eq!("fill".parse::<BoxMask>().unwrap(), BoxMask::Fill);
        assert!("grabcut".parse::<BoxMask>().is_err());
    }
}
