//! Request images and masks: encoded or raw images, mask PNGs of a given size, and RLEs
//! in every form (JSON lists, COCO strings, the request's serde type).

use crate::masks::{mask_from_png, Rle};
use crate::service::requests::{ImageInput, RleInput};

/// First byte even: `encoded` is the rest; odd: `raw_rgb8` with width and height from the
/// next four bytes (u16 each, 0 for absent).
pub fn image_input(data: &[u8]) {
    let Some(([mode, w0, w1, h0, h1], rest)) = super::header::<5>(data) else { return };
    let size = |a, b| Some(u16::from_le_bytes([a, b]) as u32).filter(|&v| v > 0);
    let bytes = Some(rest.to_vec().into());
    let input = match mode % 2 {
        0 => ImageInput { encoded: bytes, raw_rgb8: None, width: None, height: None },
        _ => ImageInput { encoded: None, raw_rgb8: bytes, width: size(w0, w1), height: size(h0, h1) },
    };
    if let Ok(image) = input.decode() {
        assert!(crate::limits::REQUEST_IMAGE.check(image.width(), image.height()).is_ok());
    }
}

/// The image's width and height (u16 each), then the mask file.
pub fn mask_png(data: &[u8]) {
    let Some(([w0, w1, h0, h1], png)) = super::header::<4>(data) else { return };
    let (width, height) = (u16::from_le_bytes([w0, w1]) as u32, u16::from_le_bytes([h0, h1]) as u32);
    if let Ok(mask) = mask_from_png(png, width, height) {
        assert_eq!(mask.dimensions(), (width, height));
        let _ = crate::masks::require_nonempty(mask);
    }
}

/// First byte 0: a COCO string with the size in the next four bytes (u16 height, width);
/// 1: the request's `RleInput` as JSON; else an RLE JSON object as BOP files hold it.
/// A readable RLE must decode, and survive a round trip through the COCO string.
pub fn mask_rle(data: &[u8]) {
    let Some(([mode], rest)) = super::header::<1>(data) else { return };
    let rle = match mode {
        0 => {
            let Some(([a, b, c, d], text)) = super::header::<4>(rest) else { return };
            let Ok(text) = std::str::from_utf8(text) else { return };
            Rle::from_coco_string(text, [u16::from_le_bytes([a, b]) as u32, u16::from_le_bytes([c, d]) as u32])
        }
        1 => match serde_json::from_slice::<RleInput>(rest) {
            Ok(r) => Rle::new(r.size, r.counts),
            Err(_) => return,
        },
        _ => match serde_json::from_slice(rest) {
            Ok(v) => Rle::from_json(&v),
            Err(_) => return,
        },
    };
    let Ok(rle) = rle else { return };
    let mask = rle.decode().expect("a validated RLE decodes");
    assert_eq!(Rle::encode(&mask).area(), rle.area());
    let again = Rle::from_coco_string(&rle.to_coco_string(), rle.size).expect("a valid RLE's COCO string reads back");
    assert_eq!(again, rle);
    if let Some([x, y, w, h]) = rle.bbox() {
        assert!(x + w <= rle.width() && y + h <= rle.height());
    }
}
