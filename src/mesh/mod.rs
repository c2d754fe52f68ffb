//! One `Mesh` type for every format: positions in metres in the object frame, per-vertex
//! normals, optional vertex colours and UVs, triangles grouped into parts by material.
//! Loaders live beside this file, one per format; they never guess units. `load_mesh` picks
//! one by file extension.

mod assemble;
mod files;
mod gltf;
#[cfg(test)]
mod hostile_tests;
mod load;
mod material_texture;
mod obj;
mod ply;
#[cfg(test)]
mod test_util;
mod texture;
mod types;

pub use self::gltf::load_gltf;
pub use files::{Folder, InMemory, MeshFiles};
pub use load::{load_mesh, load_mesh_bytes, load_mesh_with};
pub use material_texture::Texture;
pub use obj::load_obj;
pub use ply::{load_ply, load_ply_points};
pub use types::*;

pub mod procedural;
pub mod surface;
pub mod symmetry_finder;
pub mod write_obj;
pub mod write_ply;
