//! `Renderer`: one device, its pipeline, its mesh cache and its reusable targets. Renders
//! are synchronous: submit, wait, read back.

use super::context::GpuContext;
use super::gpu_mesh::GpuMesh;
use super::mesh_cache::MeshCache;
use super::output::{assemble, RenderOutput};
use super::pipeline::{FrameUniform, Pipeline};
use super::projection::{check_intrinsics, check_pose, clip_from_camera, clip_range_for_sphere};
use super::targets::{padded_row_bytes, Targets};
use super::{RenderError, RenderOptions};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;

#[derive(Clone, Debug)]
pub struct RendererConfig {
    /// Meshes kept uploaded per renderer (least recently used evicted first); at least 1.
    pub max_cached_meshes: usize,
    /// Skip the triangles facing away from the camera on closed meshes (`mesh::surface`),
    /// which cannot show from outside: the same images in about half the time on a software
    /// rasteriser (docs/benchmarks/estimation-outlines.md, "Each face drawn once, closed
    /// meshes one-sided"). A camera inside a closed mesh sees nothing of it, where
    /// two-sided drawing shows its inside.
    pub cull_closed_meshes: bool,
    /// Draw a face that repeats an earlier one exactly only once (`mesh::surface`).
    pub drop_repeated_faces: bool,
}

impl RendererConfig {
    /// The defaults, keeping at least `objects` meshes uploaded: for a run that draws that
    /// many objects in turn (each image searching them all), which would otherwise upload
    /// them again and again (17 objects searched on the 10 real YCB-V frames: 316 uploads of
    /// 30–60 ms, docs/detection.md).
    pub fn keeping(objects: usize) -> Self {
        let config = Self::default();
        Self { max_cached_meshes: config.max_cached_meshes.max(objects), ..config }
    }
}

impl Default for RendererConfig {
    fn default() -> Self {
        Self { max_cached_meshes: 8, cull_closed_meshes: true, drop_repeated_faces: true }
    }
}

pub struct Renderer {
    ctx: GpuContext,
    pipeline: Pipeline,
    cache: MeshCache<GpuMesh>,
    /// What it draws of each mesh (the cache's size is in `cache`).
    config: RendererConfig,
    /// Targets of the last image size that needed new ones (`Targets::serves`); most
    /// callers render one size repeatedly, or sizes a little apart.
    targets: Option<Targets>,
}

impl Renderer {
    pub fn new() -> Result<Self, RenderError> {
        Self::with_config(RendererConfig::default())
    }

    pub fn with_config(config: RendererConfig) -> Result<Self, RenderError> {
        let ctx = GpuContext::open()?;
        let pipeline = ctx.catching(|| Pipeline::new(&ctx.device, &ctx.queue))?;
        Ok(Self { ctx, pipeline, cache: MeshCache::new(config.max_cached_meshes), config, targets: None })
    }

    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.ctx.info
    }

    /// E.g. "llvmpipe (LLVM 15.0.6, 256 bits) via Vulkan", for logs.
    pub fn describe(&self) -> String {
        format!("{} via {}", self.ctx.info.name, self.ctx.info.backend)
    }

    /// Largest image width or height this device renders.
    pub fn max_image_side(&self) -> u32 {
        self.ctx.device.limits().max_texture_dimension_2d
    }

    /// Meshes uploaded so far (cache misses), over this renderer's lifetime.
    pub fn mesh_uploads(&self) -> u64 {
        self.cache.uploads()
    }

    /// Whether `mesh` is uploaded here (a render of it would upload nothing).
    pub fn holds(&self, mesh: &Mesh) -> bool {
        self.cache.contains(mesh.id())
    }

    pub fn cached_meshes(&self) -> usize {
        self.cache.len()
    }

    /// Renders `mesh` at `pose` (object → camera) through `k`. See `RenderOutput` for what
    /// each image holds.
    pub fn render(&mut self, mesh: &Mesh, pose: &Pose, k: &Intrinsics, opts: &RenderOptions) -> Result<RenderOutput, RenderError> {
        self.check_inputs(pose, k, opts)?;
        let Self { ctx, pipeline, cache, config, targets } = self;
        let submitted = ctx.catching(|| {
            let gpu = cache.get_or_insert_with(mesh.id(), || GpuMesh::upload(&ctx.device, &ctx.queue, pipeline, mesh, config));
            let (near, far) = opts.clip_range.unwrap_or_else(|| clip_range_for_sphere(pose, gpu.sphere_center, gpu.sphere_radius));
            let frame = FrameUniform::new(pose, &clip_from_camera(k, near, far), opts);
            ctx.queue.write_buffer(&pipeline.frame_buffer, 0, bytemuck::bytes_of(&frame));
            let t = match targets {
                Some(t) if t.serves(k.width, k.height) => t,
                _ => targets.insert(Targets::for_image(&ctx.device, k.width, k.height)),
            };
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = t.begin_pass(&mut encoder, k.width, k.height);
                pass.set_pipeline(if gpu.culled { &pipeline.culling } else { &pipeline.pipeline });
                pass.set_bind_group(0, &pipeline.frame_group, &[]);
                gpu.draw(&mut pass);
            }
            t.encode_readback(&mut encoder, k.width, k.height);
            ctx.queue.submit([encoder.finish()]);
        });
        if let Err(e) = submitted {
            // Whatever was created inside the failed scope may be invalid: rebuild next time.
            cache.remove(mesh.id());
            *targets = None;
            return Err(e);
        }
        let t = targets.as_ref().expect("created above");
        let pitch = padded_row_bytes(k.width) as usize;
        t.read(&ctx.device, k.width, k.height, |rgba, depth| assemble(k.width, k.height, pitch, rgba, depth, opts.background))
    }

    /// Uploads `mesh` now unless it is cached, so that its first render does not pay for it.
    pub fn prepare(&mut self, mesh: &Mesh) -> Result<(), RenderError> {
        let Self { ctx, pipeline, cache, config, .. } = self;
        let uploaded = ctx.catching(|| {
            cache.get_or_insert_with(mesh.id(), || GpuMesh::upload(&ctx.device, &ctx.queue, pipeline, mesh, config));
        });
        if uploaded.is_err() {
            cache.remove(mesh.id());
        }
        uploaded
    }

    /// Several views of one mesh, in order; the mesh is uploaded at most once.
    pub fn render_batch(&mut self, mesh: &Mesh, views: &[(Pose, Intrinsics)], opts: &RenderOptions) -> Result<Vec<RenderOutput>, RenderError> {
        views.iter().map(|(pose, k)| self.render(mesh, pose, k, opts)).collect()
    }

    fn check_inputs(&self, pose: &Pose, k: &Intrinsics, opts: &RenderOptions) -> Result<(), RenderError> {
        check_intrinsics(k, self.max_image_side())?;
        let readback = padded_row_bytes(k.width) as u64 * k.height as u64;
        let max_buffer = self.ctx.device.limits().max_buffer_size;
        if readback > max_buffer {
            return Err(RenderError::InvalidIntrinsics(format!("{}x{} needs a {readback}-byte readback buffer; this device allows {max_buffer}", k.width, k.height)));
        }
        check_pose(pose)?;
        opts.validate()
    }
}
