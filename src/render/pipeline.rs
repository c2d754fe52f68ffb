//! The one render pipeline and the per-context GPU objects every draw shares: shader,
//! bind-group layouts, the per-frame uniform, the sampler and a white fallback texture.

use bytemuck::{Pod, Zeroable};
use nalgebra::Matrix4;

use super::color::srgb_to_linear3;
use super::vertex::Vertex;
use super::RenderOptions;
use crate::geometry::Pose;

pub(crate) const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Metric depth as the bits of an f32. R32Float would be the obvious format, but it is not
/// renderable on GLES without EXT_color_buffer_float (Mesa's llvmpipe GL lacks it), while
/// R32Uint is renderable everywhere and carries the same 32 bits exactly.
pub(crate) const DEPTH_OUT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
pub(crate) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// sRGB: textures are authored in sRGB and the sampler must decode before filtering.
pub(crate) const ALBEDO_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

/// Which winding faces the camera in framebuffer space: counter-clockwise in the object
/// frame seen from outside, once `projection`'s clip matrix (which flips the image's y
/// axis) has mapped it.
const FRONT_FACE: wgpu::FrontFace = wgpu::FrontFace::Ccw;

/// Mirrors `Frame` in shader.wgsl (std140-compatible: only vec4/mat4 members).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct FrameUniform {
    clip_from_obj: [[f32; 4]; 4],
    cam_from_obj: [[f32; 4]; 4],
    light_dir: [f32; 4],
    override_color: [f32; 4],
    params: [f32; 4],
}

impl FrameUniform {
    /// `clip_from_camera` comes from `projection`; products are formed in f64 and only the
    /// result is rounded to f32.
    pub fn new(pose: &Pose, clip_from_camera: &Matrix4<f64>, opts: &RenderOptions) -> Self {
        let cam_from_obj = pose.to_homogeneous();
        let clip_from_obj = clip_from_camera * cam_from_obj;
        let l = opts.light_dir;
        let norm = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        let light_dir = if norm > 0.0 { [l[0] / norm, l[1] / norm, l[2] / norm, 0.0] } else { [0.0; 4] };
        let override_color = match opts.override_color {
            Some(c) => {
                let [r, g, b] = srgb_to_linear3(c);
                [r, g, b, 1.0]
            }
            None => [0.0; 4],
        };
        let flag = |b: bool| if b { 1.0 } else { 0.0 };
        Self {
            // nalgebra stores column-major, as WGSL expects.
            clip_from_obj: clip_from_obj.cast::<f32>().into(),
            cam_from_obj: cam_from_obj.cast::<f32>().into(),
            light_dir,
            override_color,
            params: [opts.ambient, opts.light_intensity, flag(opts.use_texture), flag(opts.use_vertex_colors)],
        }
    }
}

/// Mirrors `Material` in shader.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct MaterialUniform {
    pub base_color: [f32; 4],
    pub flags: [f32; 4],
}

pub(crate) struct Pipeline {
    /// Draws both sides of every triangle.
    pub pipeline: wgpu::RenderPipeline,
    /// Skips the triangles that face away from the camera: for closed meshes wound outward.
    pub culling: wgpu::RenderPipeline,
    pub material_layout: wgpu::BindGroupLayout,
    pub frame_buffer: wgpu::Buffer,
    pub frame_group: wgpu::BindGroup,
    pub sampler: wgpu::Sampler,
    /// Bound by materials without a texture so that one layout fits every part.
    pub white: wgpu::TextureView,
}

impl Pipeline {
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let shader = device.create_shader_module(wgpu::include_wgsl!("shader.wgsl"));
        let frame_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some("b2tf frame"), entries: &[uniform_entry(0)] });
        let material_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("b2tf material"),
            entries: &[
                uniform_entry(0),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture { sample_type: wgpu::TextureSampleType::Float { filterable: true }, view_dimension: wgpu::TextureViewDimension::D2, multisampled: false },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry { binding: 2, visibility: wgpu::ShaderStages::FRAGMENT, ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering), count: None },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor { label: Some("b2tf"), bind_group_layouts: &[Some(&frame_layout), Some(&material_layout)], immediate_size: 0 });
        let render_pipeline = |cull_mode| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("b2tf"),
                layout: Some(&layout),
                vertex: wgpu::VertexState { module: &shader, entry_point: Some("vs_main"), compilation_options: Default::default(), buffers: &[Some(Vertex::LAYOUT)] },
                primitive: wgpu::PrimitiveState { topology: wgpu::PrimitiveTopology::TriangleList, front_face: FRONT_FACE, cull_mode, ..Default::default() },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    // Reversed depth (see projection.rs): nearer is larger.
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some("fs_main"),
                    compilation_options: Default::default(),
                    targets: &[
                        Some(wgpu::ColorTargetState { format: COLOR_FORMAT, blend: None, write_mask: wgpu::ColorWrites::ALL }),
                        Some(wgpu::ColorTargetState { format: DEPTH_OUT_FORMAT, blend: None, write_mask: wgpu::ColorWrites::ALL }),
                    ],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        // CAD meshes often have inconsistent winding: both sides are drawn unless the mesh
        // is known to be closed and wound outward (`mesh::surface`).
        let pipeline = render_pipeline(None);
        let culling = render_pipeline(Some(wgpu::Face::Back));
        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("b2tf frame uniform"),
            size: std::mem::size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let frame_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("b2tf frame"),
            layout: &frame_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: frame_buffer.as_entire_binding() }],
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("b2tf albedo"),
            // OBJ/glTF UVs outside 0..1 mean tiling.
            address_mode_u: wgpu::AddressMode::Repeat,
            address_mode_v: wgpu::AddressMode::Repeat,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let white = upload_texture(device, queue, 1, 1, &[255; 4], "b2tf white");
        Self { pipeline, culling, material_layout, frame_buffer, frame_group, sampler, white }
    }
}

/// An sRGB RGBA8 texture (one mip level) holding `rgba`, tightly packed rows.
pub(crate) fn upload_texture(device: &wgpu::Device, queue: &wgpu::Queue, width: u32, height: u32, rgba: &[u8], label: &str) -> wgpu::TextureView {
    let size = wgpu::Extent3d { width, height, depth_or_array_layers: 1 };
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: ALBEDO_FORMAT,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    queue.write_texture(
        wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
        rgba,
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * width), rows_per_image: Some(height) },
        size,
    );
    texture.create_view(&Default::default())
}

fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty: wgpu::BindingType::Buffer { ty: wgpu::BufferBindingType::Uniform, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}
