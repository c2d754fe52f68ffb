//! One `Mesh` type for every format: positions in metres in the object frame, per-vertex
//! normals, optional vertex colours and UVs, triangles grouped into parts by material.
//! Loaders live beside this file, one per format; they never guess units.

mod types;
pub use types::*;

pub mod procedural;
