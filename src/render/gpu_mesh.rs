//! A `Mesh` uploaded to one device: interleaved vertices, indices, and one bind group per
//! material. Built once per mesh and context (see `mesh_cache`).

use std::ops::Range;

use wgpu::util::DeviceExt;

use super::color::srgb_to_linear3;
use super::pipeline::{upload_texture, MaterialUniform, Pipeline};
use super::vertex::Vertex;
use super::RendererConfig;
use crate::mesh::surface::drawn_surface;
use crate::mesh::Mesh;

pub(crate) struct GpuMesh {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    /// (index range, material) per part.
    draws: Vec<(Range<u32>, usize)>,
    materials: Vec<wgpu::BindGroup>,
    /// Closed: drawn with back faces culled.
    pub culled: bool,
    /// Object-frame bounding sphere, for automatic near/far planes.
    pub sphere_center: [f64; 3],
    pub sphere_radius: f64,
}

impl GpuMesh {
    /// Draws `mesh`'s triangles (less exact repeats, wound outward where they close:
    /// `mesh::surface`) as `config` says.
    pub fn upload(device: &wgpu::Device, queue: &wgpu::Queue, pipeline: &Pipeline, mesh: &Mesh, config: &RendererConfig) -> Self {
        let vertices = build_vertices(mesh);
        let t = std::time::Instant::now();
        let drawn = drawn_surface(mesh, config.drop_repeated_faces);
        tracing::debug!(
            mesh = mesh.name(),
            triangles = mesh.triangles().len(),
            repeats = drawn.repeats,
            closed = drawn.closed,
            rewound = drawn.rewound,
            ms = t.elapsed().as_secs_f64() * 1e3,
            "uploading a mesh"
        );
        let culled = config.cull_closed_meshes && drawn.closed;
        let vertices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(mesh.name()), contents: bytemuck::cast_slice(&vertices), usage: wgpu::BufferUsages::VERTEX });
        let indices = device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(mesh.name()), contents: bytemuck::cast_slice(&drawn.triangles), usage: wgpu::BufferUsages::INDEX });
        let draws = drawn.parts.iter().filter(|p| p.triangle_count > 0).map(|p| (p.first_triangle * 3..(p.first_triangle + p.triangle_count) * 3, p.material as usize)).collect();
        let max_side = device.limits().max_texture_dimension_2d;
        let materials = mesh
            .materials()
            .iter()
            .map(|m| {
                // A texture is useless without UVs (or pixels); treat the material as untextured.
                let texture = m.texture.as_ref().filter(|t| mesh.uvs().is_some() && t.width() > 0 && t.height() > 0);
                // A stored texture is decoded here, for this upload only. One whose file
                // is damaged is drawn as the base colour rather than failing every render.
                let pixels = texture.and_then(|t| t.pixels().map_err(|e| tracing::error!(mesh = mesh.name(), material = m.name, "texture not drawn: {e}")).ok());
                let view = pixels.map(|t| {
                    let t = fit_texture(&t, max_side);
                    upload_texture(device, queue, t.width(), t.height(), t.as_raw(), &m.name)
                });
                let uniform = MaterialUniform { base_color: m.base_color, flags: [if view.is_some() { 1.0 } else { 0.0 }, 0.0, 0.0, 0.0] };
                let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(&m.name), contents: bytemuck::bytes_of(&uniform), usage: wgpu::BufferUsages::UNIFORM });
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(&m.name),
                    layout: &pipeline.material_layout,
                    entries: &[
                        wgpu::BindGroupEntry { binding: 0, resource: buffer.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(view.as_ref().unwrap_or(&pipeline.white)) },
                        wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(&pipeline.sampler) },
                    ],
                })
            })
            .collect();
        let (lo, hi) = mesh.bbox();
        let half_diagonal = (0..3).map(|i| ((hi[i] - lo[i]) as f64 * 0.5).powi(2)).sum::<f64>().sqrt();
        Self { vertices, indices, draws, materials, culled, sphere_center: mesh.bbox_center(), sphere_radius: half_diagonal }
    }

    /// Records the draws; the pipeline and frame bind group must already be set.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>) {
        pass.set_vertex_buffer(0, self.vertices.slice(..));
        pass.set_index_buffer(self.indices.slice(..), wgpu::IndexFormat::Uint32);
        for (range, material) in &self.draws {
            pass.set_bind_group(1, &self.materials[*material], &[]);
            pass.draw_indexed(range.clone(), 0, 0..1);
        }
    }
}

fn build_vertices(mesh: &Mesh) -> Vec<Vertex> {
    let colors = mesh.colors();
    let uvs = mesh.uvs();
    mesh.positions()
        .iter()
        .zip(mesh.normals())
        .enumerate()
        .map(|(i, (&position, &normal))| Vertex {
            position,
            normal,
            color: colors.map_or([1.0; 3], |c| srgb_to_linear3(c[i])),
            // OBJ's v points up while texture rows go down.
            uv: uvs.map_or([0.0; 2], |t| [t[i][0], 1.0 - t[i][1]]),
        })
        .collect()
}

/// Textures larger than the device allows are shrunk (rare: such limits are ≥ 8192).
fn fit_texture(t: &image::RgbaImage, max_side: u32) -> std::borrow::Cow<'_, image::RgbaImage> {
    let (w, h) = t.dimensions();
    if w <= max_side && h <= max_side {
        return std::borrow::Cow::Borrowed(t);
    }
    let s = max_side as f64 / w.max(h) as f64;
    let (nw, nh) = (((w as f64 * s) as u32).max(1), ((h as f64 * s) as u32).max(1));
    tracing::warn!("texture {w}x{h} exceeds the device limit {max_side}; resized to {nw}x{nh}");
    std::borrow::Cow::Owned(image::imageops::resize(t, nw, nh, image::imageops::FilterType::Triangle))
}
