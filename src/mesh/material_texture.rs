//! A material's texture image: decoded pixels (meshes loaded from files, generated ones),
//! or the PNG an object store holds, kept encoded and decoded only when its pixels are
//! needed — a GPU upload, once per render context. A loaded object then holds its
//! texture's file size on the heap (2.2 MB for a HOPE object) instead of 16.8 MB of RGBA
//! per 2048² texture, and its load skips the decode.

use image::RgbaImage;
use std::sync::{Arc, Mutex, Weak};

#[derive(Clone)]
pub struct Texture {
    width: u32,
    height: u32,
    pixels: Pixels,
}

#[derive(Clone)]
enum Pixels {
    Decoded(Arc<RgbaImage>),
    Encoded {
        png: Arc<[u8]>,
        /// The decoded image while some caller still holds it, so that uploads to several
        /// render contexts at once decode it once.
        shared: Arc<Mutex<Weak<RgbaImage>>>,
    },
}

impl Texture {
    /// A stored PNG, checked from its header (format, size within `limits::TEXTURE`) and
    /// decoded later.
    pub fn from_png(png: Vec<u8>) -> Result<Self, String> {
        let reader = image::ImageReader::new(std::io::Cursor::new(&png)).with_guessed_format().map_err(|e| e.to_string())?;
        if reader.format() != Some(image::ImageFormat::Png) {
            return Err("not a PNG file".into());
        }
        let (width, height) = reader.into_dimensions().map_err(|e| e.to_string())?;
        crate::limits::TEXTURE.check(width, height).map_err(|e| e.to_string())?;
        Ok(Self { width, height, pixels: Pixels::Encoded { png: png.into(), shared: Default::default() } })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn dimensions(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The RGBA pixels (sRGB), decoded now when held encoded. Fails only for a stored PNG
    /// whose body is damaged (its header was checked when it was read).
    pub fn pixels(&self) -> Result<Arc<RgbaImage>, String> {
        let (png, shared) = match &self.pixels {
            Pixels::Decoded(image) => return Ok(image.clone()),
            Pixels::Encoded { png, shared } => (png, shared),
        };
        let mut shared = shared.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(image) = shared.upgrade() {
            return Ok(image);
        }
        let image = Arc::new(crate::limits::TEXTURE.decode(png).map_err(|e| e.to_string())?.into_rgba8());
        if image.dimensions() != (self.width, self.height) {
            return Err(format!("decoded {:?}, its header said {}x{}", image.dimensions(), self.width, self.height));
        }
        *shared = Arc::downgrade(&image);
        Ok(image)
    }

    /// The PNG file it was read from, when held encoded: a store writes it back as it is.
    pub fn png(&self) -> Option<&[u8]> {
        match &self.pixels {
            Pixels::Encoded { png, .. } => Some(png),
            Pixels::Decoded(_) => None,
        }
    }

    /// Heap bytes it holds for as long as it lives (not a decode's passing copy).
    pub fn heap_bytes(&self) -> usize {
        match &self.pixels {
            Pixels::Decoded(image) => image.as_raw().len(),
            Pixels::Encoded { png, .. } => png.len(),
        }
    }
}

impl From<RgbaImage> for Texture {
    fn from(image: RgbaImage) -> Self {
        Arc::new(image).into()
    }
}

impl From<Arc<RgbaImage>> for Texture {
    fn from(image: Arc<RgbaImage>) -> Self {
        let (width, height) = image.dimensions();
        Self { width, height, pixels: Pixels::Decoded(image) }
    }
}

impl std::fmt::Debug for Texture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let held = if self.png().is_some() { "PNG" } else { "decoded" };
        write!(f, "Texture({}x{}, {held}, {} bytes)", self.width, self.height, self.heap_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_of(image: &RgbaImage) -> Vec<u8> {
        let mut png = Vec::new();
        image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
        png
    }

    /// PNG's chunk checksum (CRC-32, ISO 3309), for editing a header in place.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }

    fn gradient() -> RgbaImage {
        RgbaImage::from_fn(64, 32, |x, y| image::Rgba([x as u8 * 4, y as u8 * 8, 7, 255]))
    }

    #[test]
    fn a_stored_png_holds_its_bytes_and_decodes_to_the_same_pixels() {
        let image = gradient();
        let t = Texture::from_png(png_of(&image)).unwrap();
        assert_eq!(t.dimensions(), (64, 32));
        assert!(t.heap_bytes() < image.as_raw().len(), "{t:?}");
        let a = t.pixels().unwrap();
        assert_eq!(a.as_raw(), image.as_raw());
        // Decoded once while held: a second caller gets the same image.
        assert!(Arc::ptr_eq(&a, &t.clone().pixels().unwrap()));
        drop(a);
        assert_eq!(t.pixels().unwrap().as_raw(), image.as_raw());
        assert_eq!(t.png(), Some(png_of(&image).as_slice()));
        let decoded = Texture::from(image.clone());
        assert_eq!((decoded.png(), decoded.heap_bytes()), (None, image.as_raw().len()));
    }

    #[test]
    fn bad_stored_images_are_refused_or_fail_when_decoded() {
        assert!(Texture::from_png(b"not an image".to_vec()).is_err());
        let mut jpeg = Vec::new();
        image::DynamicImage::ImageRgba8(gradient()).to_rgb8().write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg).unwrap();
        assert_eq!(Texture::from_png(jpeg).unwrap_err(), "not a PNG file");
        // A header over the limits is refused before any decoding.
        let mut wide = png_of(&RgbaImage::new(1, 1));
        wide[16..20].copy_from_slice(&(crate::limits::MAX_TEXTURE_SIDE + 1).to_be_bytes());
        let crc = crc32(&wide[12..29]);
        wide[29..33].copy_from_slice(&crc.to_be_bytes());
        assert!(Texture::from_png(wide).unwrap_err().contains("8193"), "over the side limit");
        // A damaged body passes the header check and fails when the pixels are asked for.
        let mut damaged = png_of(&gradient());
        let n = damaged.len();
        damaged.truncate(n - 40);
        let t = Texture::from_png(damaged).unwrap();
        assert!(t.pixels().is_err());
    }
}
