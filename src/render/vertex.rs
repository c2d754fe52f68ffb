//! The vertex the renderer's shader reads: what a mesh upload (`gpu_mesh`) writes and the
//! pipeline (`pipeline`) declares.

use bytemuck::{Pod, Zeroable};

/// Mirrors `VsIn` in shader.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct Vertex {
    pub(super) position: [f32; 3],
    pub(super) normal: [f32; 3],
    /// Linear RGB.
    pub(super) color: [f32; 3],
    /// Texture convention: (u, 1 − v), row 0 of the image at the top.
    pub(super) uv: [f32; 2],
}

impl Vertex {
    const ATTRIBUTES: [wgpu::VertexAttribute; 4] = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2];
    pub const LAYOUT: wgpu::VertexBufferLayout<'static> =
        wgpu::VertexBufferLayout { array_stride: std::mem::size_of::<Vertex>() as u64, step_mode: wgpu::VertexStepMode::Vertex, attributes: &Self::ATTRIBUTES };
}
