//! Texture images for every loader: decoded to RGBA8 and kept as stored (sRGB), with errors
//! that name both the mesh file and the texture.

use super::MeshError;
use image::RgbaImage;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Reads and decodes the image file `file`; `name` is how the mesh file referred to it, which is
/// what the user can search for in the mesh file when the error appears.
pub(super) fn load_texture(mesh: &Path, file: &Path, name: &str) -> Result<Arc<RgbaImage>, MeshError> {
    let bytes = std::fs::read(file).map_err(|e| texture_error(mesh, name, format!("{}: {e}", file.display())))?;
    decode_texture(mesh, name, &bytes)
}

/// Decodes an in-memory image; the format comes from its magic bytes, not from a name or MIME
/// type, because files in the wild often carry wrong ones.
pub(super) fn decode_texture(mesh: &Path, name: &str, bytes: &[u8]) -> Result<Arc<RgbaImage>, MeshError> {
    let image = image::load_from_memory(bytes).map_err(|e| texture_error(mesh, name, format!("cannot decode: {e}")))?;
    Ok(Arc::new(image.into_rgba8()))
}

pub(super) fn texture_error(mesh: &Path, name: &str, message: String) -> MeshError {
    MeshError::Texture { path: mesh.to_path_buf(), texture: name.to_string(), message }
}

/// Shares one decoded image among the materials that name the same file.
#[derive(Default)]
pub(super) struct TextureCache {
    images: HashMap<PathBuf, Arc<RgbaImage>>,
}

impl TextureCache {
    pub(super) fn load(&mut self, mesh: &Path, file: &Path, name: &str) -> Result<Arc<RgbaImage>, MeshError> {
        if let Some(image) = self.images.get(file) {
            return Ok(image.clone());
        }
        let image = load_texture(mesh, file, name)?;
        self.images.insert(file.to_path_buf(), image.clone());
        Ok(image)
    }
}
