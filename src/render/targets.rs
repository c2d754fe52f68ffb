//! Render targets and their readback buffers for one image size. Kept by the renderer
//! across calls because allocating them per render dominates small renders.

use std::sync::mpsc;

use super::pipeline::{COLOR_FORMAT, DEPTH_FORMAT, DEPTH_OUT_FORMAT};
use super::RenderError;

/// Bytes per row in a readback buffer: texture→buffer copies need rows aligned to 256.
/// Both colour formats are 4 bytes per pixel, so one pitch serves both.
pub(crate) fn padded_row_bytes(width: u32) -> u32 {
    (4 * width).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

pub(crate) struct Targets {
    pub width: u32,
    pub height: u32,
    color: wgpu::Texture,
    depth_out: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_out_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    color_readback: wgpu::Buffer,
    depth_readback: wgpu::Buffer,
}

impl Targets {
    pub fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let texture = |format, usage, label| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let copyable = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        let color = texture(COLOR_FORMAT, copyable, "b2tf colour");
        let depth_out = texture(DEPTH_OUT_FORMAT, copyable, "b2tf metric depth");
        let depth = texture(DEPTH_FORMAT, wgpu::TextureUsages::RENDER_ATTACHMENT, "b2tf depth buffer");
        let readback = |label| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: padded_row_bytes(width) as u64 * height as u64,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            })
        };
        Self {
            width,
            height,
            color_view: color.create_view(&Default::default()),
            depth_out_view: depth_out.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            color,
            depth_out,
            color_readback: readback("b2tf colour readback"),
            depth_readback: readback("b2tf depth readback"),
        }
    }

    /// Clears everything to "background": colour 0, metric depth 0, depth buffer 0 (far,
    /// since depth is reversed).
    pub fn begin_pass<'e>(&self, encoder: &'e mut wgpu::CommandEncoder) -> wgpu::RenderPass<'e> {
        let clear = |view| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT), store: wgpu::StoreOp::Store },
            })
        };
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("b2tf"),
            color_attachments: &[clear(&self.color_view), clear(&self.depth_out_view)],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Discard }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }

    pub fn encode_readback(&self, encoder: &mut wgpu::CommandEncoder) {
        let size = wgpu::Extent3d { width: self.width, height: self.height, depth_or_array_layers: 1 };
        for (texture, buffer) in [(&self.color, &self.color_readback), (&self.depth_out, &self.depth_readback)] {
            encoder.copy_texture_to_buffer(
                texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo { buffer, layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded_row_bytes(self.width)), rows_per_image: Some(self.height) } },
                size,
            );
        }
    }

    /// Waits for the submitted copies, then hands `read` the padded colour and depth bytes.
    pub fn read<R>(&self, device: &wgpu::Device, read: impl FnOnce(&[u8], &[u8]) -> R) -> Result<R, RenderError> {
        let buffers = [&self.color_readback, &self.depth_readback];
        let (tx, rx) = mpsc::channel();
        for (i, b) in buffers.iter().enumerate() {
            let tx = tx.clone();
            b.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = tx.send((i, r));
            });
        }
        drop(tx);
        let polled = device.poll(wgpu::PollType::wait_indefinitely());
        // Unmap whatever did map, on every path, so the buffers are usable next time.
        let results: Vec<_> = rx.try_iter().collect();
        let mapped = |i: usize| results.iter().any(|(j, r)| *j == i && r.is_ok());
        let outcome = (|| {
            polled.map_err(|e| RenderError::Readback(e.to_string()))?;
            if !(mapped(0) && mapped(1)) {
                return Err(RenderError::Readback(format!("buffer mapping failed: {results:?}")));
            }
            let err = |e: wgpu::MapRangeError| RenderError::Readback(e.to_string());
            let color = buffers[0].get_mapped_range(..).map_err(err)?;
            let depth = buffers[1].get_mapped_range(..).map_err(err)?;
            Ok(read(&color, &depth))
        })();
        for (i, b) in buffers.iter().enumerate() {
            if mapped(i) {
                b.unmap();
            }
        }
        outcome
    }
}
