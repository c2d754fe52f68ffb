//! Texture images for every loader: decoded to RGBA8 and kept as stored (sRGB), with errors
//! that name both the mesh file and the texture, and refused from their header when over
//! [`crate::limits::TEXTURE`].

use super::files::MeshFiles;
use super::MeshError;
use image::RgbaImage;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

/// Reads and decodes the image the mesh file `mesh` calls `name`.
pub(super) fn load_texture(mesh: &Path, files: &dyn MeshFiles, name: &str) -> Result<Arc<RgbaImage>, MeshError> {
    let bytes = files.read(name).map_err(|e| texture_error(mesh, name, e))?;
    decode_texture(mesh, name, &bytes)
}

/// Decodes an in-memory image; the format comes from its magic bytes, not from a name or MIME
/// type, because files in the wild often carry wrong ones.
pub(super) fn decode_texture(mesh: &Path, name: &str, bytes: &[u8]) -> Result<Arc<RgbaImage>, MeshError> {
    let image = crate::limits::TEXTURE.decode(bytes).map_err(|e| texture_error(mesh, name, format!("cannot decode: {e}")))?;
    Ok(Arc::new(image.into_rgba8()))
}

pub(super) fn texture_error(mesh: &Path, name: &str, message: String) -> MeshError {
    MeshError::Texture { path: mesh.to_path_buf(), texture: name.to_string(), message }
}

/// Shares one decoded image among the materials that name the same file.
#[derive(Default)]
pub(super) struct TextureCache {
    images: HashMap<String, Arc<RgbaImage>>,
}

impl TextureCache {
    pub(super) fn load(&mut self, mesh: &Path, files: &dyn MeshFiles, name: &str) -> Result<Arc<RgbaImage>, MeshError> {
        if let Some(image) = self.images.get(name) {
            return Ok(image.clone());
        }
        let image = load_texture(mesh, files, name)?;
        self.images.insert(name.to_string(), image.clone());
        Ok(image)
    }
}
