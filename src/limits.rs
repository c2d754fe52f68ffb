//! Bounds on what hostile input may ask for: every decoder that takes outside bytes checks
//! its input against these before allocating in proportion to what the input *claims*
//! (a PNG header's size, a PLY header's counts, an RLE's size, a JSON array's length).
//! docs/reliability.md ("Input limits") lists them; change both together.
//!
//! The errors name the field (or file) and the limit, so a client can tell a refused
//! request from a broken one.

use std::io::Cursor;

/// Longest side of a request image or mask, pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Pixels in a request image (and so in each of its masks): 40 MP, e.g. 8000 × 5000.
pub const MAX_IMAGE_PIXELS: u64 = 40_000_000;
/// Detections in one estimate request. Each becomes a full-image mask, so this and
/// [`MAX_MASK_PIXELS_PER_REQUEST`] bound an estimate's mask memory.
pub const MAX_DETECTIONS: usize = 256;
/// Objects one detect (or estimate-by-detection) request may search for: each adds its
/// templates to the search.
pub const MAX_DETECT_OBJECTS: usize = 64;
/// Mask pixels one estimate may decode: detections × image pixels (1 byte each).
pub const MAX_MASK_PIXELS_PER_REQUEST: u64 = 1_000_000_000;
/// Runs in one RLE mask (list or COCO string); a segmenter's masks have a few thousand.
pub const MAX_RLE_RUNS: usize = 2_000_000;
/// Retrieval's `k` (templates kept per mask): more than any object has templates
/// (level 3 × 36 in-plane steps is 23 112).
pub const MAX_RETRIEVAL_K: usize = 100_000;
/// `max_masks` and `instances_per_object` of an estimate: at most one per detection.
pub const MAX_MASKS_PER_INSTANCE: usize = MAX_DETECTIONS;
/// `verify_templates` and `verify_matched` of an estimate: each is a hypothesis refined (a
/// few ms of CPU).
pub const MAX_VERIFY_TEMPLATES: usize = 64;
/// `spin_steps` of an estimate: 72 is 5° steps, 3 × 68 hypotheses.
pub const MAX_SPIN_STEPS: usize = 72;

/// Vertices of a loaded mesh (after OBJ/glTF assembly or PLY texture-seam splitting).
pub const MAX_MESH_VERTICES: usize = 10_000_000;
/// Triangles of a loaded mesh (polygons fan-triangulated).
pub const MAX_MESH_TRIANGLES: usize = 20_000_000;
/// Longest side of a mesh texture, pixels (GPUs are only required to take 8192).
pub const MAX_TEXTURE_SIDE: u32 = 8_192;
/// Pixels of a mesh texture (RGBA, 4 bytes each).
pub const MAX_TEXTURE_PIXELS: u64 = 8_192 * 8_192;
/// Bytes of one file a mesh refers to (MTL, texture, glTF buffer) read from disk.
pub const MAX_MESH_RESOURCE_BYTES: u64 = 1 << 30;
/// Files (MTL, textures, buffers) uploaded with one mesh.
pub const MAX_MESH_RESOURCES: usize = 64;
/// Parts of a multipart onboarding body: the text fields, the mesh and its resources.
pub const MAX_MULTIPART_PARTS: usize = MAX_MESH_RESOURCES + 16;
/// Nesting of JSON bodies and files: serde_json's own recursion limit (128 levels of
/// recursion allow 127 nested lists or objects), which refuses deeper documents with
/// "recursion limit exceeded" (stated here to document it; the tests pin it).
pub const MAX_JSON_DEPTH: usize = 127;

/// How large a decoded image may be.
#[derive(Clone, Copy, Debug)]
pub struct ImageLimits {
    pub max_side: u32,
    pub max_pixels: u64,
}

/// Request images and masks.
pub const REQUEST_IMAGE: ImageLimits = ImageLimits { max_side: MAX_IMAGE_SIDE, max_pixels: MAX_IMAGE_PIXELS };
/// Mesh textures.
pub const TEXTURE: ImageLimits = ImageLimits { max_side: MAX_TEXTURE_SIDE, max_pixels: MAX_TEXTURE_PIXELS };

/// Why an image was not decoded; the caller puts the field name in front.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImageRefused {
    #[error("not a readable PNG/JPEG image: {0}")]
    Unreadable(String),
    #[error("{width}×{height} is over the limit of {max_side} pixels a side and {max_pixels} pixels in all")]
    TooLarge { width: u32, height: u32, max_side: u32, max_pixels: u64 },
}

impl ImageLimits {
    /// Refuses a `width × height` image over the limits.
    pub fn check(&self, width: u32, height: u32) -> Result<(), ImageRefused> {
        if width > self.max_side || height > self.max_side || width as u64 * height as u64 > self.max_pixels {
            return Err(ImageRefused::TooLarge { width, height, max_side: self.max_side, max_pixels: self.max_pixels });
        }
        Ok(())
    }

    /// Decodes PNG/JPEG bytes, reading the size from the header first so that an image
    /// over the limits is refused before its pixels are allocated; `expect` may refuse the
    /// size too (a mask must have its image's).
    pub fn decode_expecting<E: From<ImageRefused>>(&self, bytes: &[u8], expect: impl FnOnce(u32, u32) -> Result<(), E>) -> Result<image::DynamicImage, E> {
        let unreadable = |e: image::ImageError| ImageRefused::Unreadable(e.to_string());
        let reader = || image::ImageReader::new(Cursor::new(bytes)).with_guessed_format().map_err(|e| unreadable(e.into()));
        let (width, height) = reader()?.into_dimensions().map_err(unreadable)?;
        self.check(width, height)?;
        expect(width, height)?;
        let mut r = reader()?;
        // The decoders' own guard, for what they allocate besides the pixels (8 bytes a
        // pixel covers 16-bit RGBA).
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(self.max_side);
        limits.max_image_height = Some(self.max_side);
        limits.max_alloc = Some(self.max_pixels * 8);
        r.limits(limits);
        Ok(r.decode().map_err(unreadable)?)
    }

    /// [`ImageLimits::decode_expecting`] any size within the limits.
    pub fn decode(&self, bytes: &[u8]) -> Result<image::DynamicImage, ImageRefused> {
        self.decode_expecting(bytes, |_, _| Ok::<(), ImageRefused>(()))
    }
}

/// Refuses a list longer than `max`; `what` names the field.
pub fn check_count(what: &str, count: usize, max: usize) -> Result<(), String> {
    if count > max {
        return Err(format!("{what} has {count} items, over the limit of {max}"));
    }
    Ok(())
}

/// Deserializes a JSON list of at most `MAX` items, refusing a longer one as soon as the
/// item past the limit arrives (before the rest of it is read). For request fields:
/// `#[serde(deserialize_with = "crate::limits::bounded_vec::<_, _, N>")]`.
pub fn bounded_vec<'de, D, T, const MAX: usize>(d: D) -> Result<Vec<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: serde::Deserialize<'de>,
{
    struct Bounded<T, const MAX: usize>(std::marker::PhantomData<T>);
    impl<'de, T: serde::Deserialize<'de>, const MAX: usize> serde::de::Visitor<'de> for Bounded<T, MAX> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            write!(f, "a list of at most {MAX} items")
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(MAX).min(4096));
            while let Some(item) = seq.next_element()? {
                if out.len() == MAX {
                    return Err(serde::de::Error::custom(format!("more than {MAX} items, over the limit")));
                }
                out.push(item);
            }
            Ok(out)
        }
    }
    d.deserialize_seq(Bounded::<T, MAX>(std::marker::PhantomData))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn png(width: u32, height: u32) -> Vec<u8> {
        let mut out = Vec::new();
        image::DynamicImage::new_luma8(width, height).write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
        out
    }

    /// A PNG whose header claims `width × height`, with no pixel data (an empty IDAT chunk:
    /// decoders read the header up to the first one).
    pub(crate) fn png_header_only(width: u32, height: u32) -> Vec<u8> {
        let mut bytes = png(1, 1)[..8].to_vec();
        let mut ihdr = [0u8; 13];
        ihdr[..4].copy_from_slice(&width.to_be_bytes());
        ihdr[4..8].copy_from_slice(&height.to_be_bytes());
        ihdr[8] = 8; // 8-bit grey
        for (kind, data) in [(b"IHDR", &ihdr[..]), (b"IDAT", &[]), (b"IEND", &[])] {
            bytes.extend((data.len() as u32).to_be_bytes());
            let typed = [&kind[..], data].concat();
            bytes.extend(&typed);
            bytes.extend(crc32(&typed).to_be_bytes());
        }
        bytes
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }

    #[test]
    fn images_over_the_limits_are_refused_from_the_header() {
        let small = ImageLimits { max_side: 100, max_pixels: 5_000 };
        let ok = small.decode(&png(100, 50)).unwrap();
        assert_eq!((ok.width(), ok.height()), (100, 50));
        assert_eq!(small.decode(&png(101, 1)).unwrap_err().to_string(), "101×1 is over the limit of 100 pixels a side and 5000 pixels in all");
        assert!(matches!(small.decode(&png(100, 51)), Err(ImageRefused::TooLarge { .. })));
        // Headers alone: a decoder that allocated before checking would ask for gigabytes.
        let e = REQUEST_IMAGE.decode(&png_header_only(60_000, 60_000)).unwrap_err().to_string();
        assert!(e.starts_with("60000×60000 is over the limit of 16384 pixels a side"), "{e}");
        assert!(matches!(REQUEST_IMAGE.decode(&png_header_only(16_000, 16_000)), Err(ImageRefused::TooLarge { .. })));
        assert!(REQUEST_IMAGE.decode(b"junk").unwrap_err().to_string().starts_with("not a readable PNG/JPEG image"));
        let refused = REQUEST_IMAGE.decode_expecting(&png(3, 2), |w, h| if (w, h) == (2, 3) { Ok(()) } else { Err(ImageRefused::Unreadable("size".into())) });
        assert_eq!(refused.unwrap_err(), ImageRefused::Unreadable("size".into()));
    }

    #[test]
    fn lists_over_the_limit_are_refused() {
        #[derive(serde::Deserialize, Debug)]
        struct Two {
            #[serde(deserialize_with = "bounded_vec::<_, _, 2>")]
            items: Vec<u8>,
        }
        assert_eq!(serde_json::from_str::<Two>(r#"{"items": [1, 2]}"#).unwrap().items, vec![1, 2]);
        let e = serde_json::from_str::<Two>(r#"{"items": [1, 2, 3]}"#).unwrap_err().to_string();
        assert!(e.contains("more than 2 items, over the limit"), "{e}");
        assert_eq!(check_count("resources", 3, 2).unwrap_err(), "resources has 3 items, over the limit of 2");
    }

    #[test]
    fn json_nesting_is_bounded_by_serde_json() {
        let deep = |n: usize| format!("{}{}", "[".repeat(n), "]".repeat(n));
        assert!(serde_json::from_str::<serde_json::Value>(&deep(MAX_JSON_DEPTH)).is_ok());
        let e = serde_json::from_str::<serde_json::Value>(&deep(MAX_JSON_DEPTH + 1)).unwrap_err().to_string();
        assert!(e.contains("recursion limit exceeded"), "{e}");
    }
}
