//! Offscreen rendering of a `Mesh` at a `Pose` through `Intrinsics`: colour, metric depth
//! and mask, with the OpenCV pinhole model reproduced exactly (pixel centres at integer
//! coordinates; see `projection`).
//!
//! Headless wgpu: Vulkan first (Mesa's lavapipe on machines without a GPU), then GL, or
//! whatever `WGPU_BACKEND` names. `Renderer` owns one device and is used from one thread
//! at a time; `RenderPool` shares a few of them between threads.
//!
//! Shading: base colour × texture × vertex colour (each switchable), two-sided Lambert
//! with one directional light in the camera frame plus ambient, computed in linear light
//! and written sRGB-encoded.

mod color;
mod context;
mod error;
mod gpu_mesh;
mod mesh_cache;
mod options;
mod output;
pub mod overlay;
mod pipeline;
mod pool;
pub mod projection;
mod renderer;
mod targets;
mod vertex;

#[cfg(test)]
pub(crate) mod tests;

pub use context::quiet_headless_vulkan_loader;
pub use error::RenderError;
pub use options::RenderOptions;
pub use output::RenderOutput;
pub use pool::RenderPool;
pub use renderer::{Renderer, RendererConfig};
