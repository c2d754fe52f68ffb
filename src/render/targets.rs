//! Render targets and their readback buffers. Kept by the renderer across calls because
//! allocating them per render dominates small renders; an image smaller than the targets
//! is drawn into their top-left corner (viewport and scissor), so that renders whose size
//! changes a little from call to call (a tracker's window around a moving object) reuse
//! them too.

use std::sync::mpsc;

use super::pipeline::{COLOR_FORMAT, DEPTH_FORMAT, DEPTH_OUT_FORMAT};
use super::RenderError;

/// Bytes per row in a readback buffer: texture→buffer copies need rows aligned to 256.
/// Both colour formats are 4 bytes per pixel, so one pitch serves both.
pub(crate) fn padded_row_bytes(width: u32) -> u32 {
    (4 * width).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT
}

/// Targets are allocated in steps of this many pixels a side, so that sizes a few pixels
/// apart share them.
const SIZE_STEP: u32 = 64;

pub(crate) struct Targets {
    /// The size allocated; an image is at most this large.
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
    /// Targets for a `width × height` image, rounded up to the allocation step where the
    /// device allows textures and buffers that large.
    pub fn for_image(device: &wgpu::Device, width: u32, height: u32) -> Self {
        let limits = device.limits();
        let up = |n: u32| n.div_ceil(SIZE_STEP).saturating_mul(SIZE_STEP).min(limits.max_texture_dimension_2d).max(n);
        let (w, h) = (up(width), up(height));
        if padded_row_bytes(w) as u64 * h as u64 <= limits.max_buffer_size {
            Self::new(device, w, h)
        } else {
            Self::new(device, width, height)
        }
    }

    /// Whether a `width × height` image fits, without clearing and reading back more than
    /// about twice its pixels (a small render after a large one gets targets of its own).
    pub fn serves(&self, width: u32, height: u32) -> bool {
        width <= self.width && height <= self.height && 2 * (width as u64 + SIZE_STEP as u64) * (height as u64 + SIZE_STEP as u64) >= self.width as u64 * self.height as u64
    }

    fn new(device: &wgpu::Device, width: u32, height: u32) -> Self {
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
    /// since depth is reversed), and draws into the top-left `width × height` pixels.
    pub fn begin_pass<'e>(&self, encoder: &'e mut wgpu::CommandEncoder, width: u32, height: u32) -> wgpu::RenderPass<'e> {
        let clear = |view| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT), store: wgpu::StoreOp::Store },
            })
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
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
        });
        // The viewport maps clip space onto the image's pixels exactly as targets of its
        // own size would; the scissor keeps every fragment inside them.
        pass.set_viewport(0.0, 0.0, width as f32, height as f32, 0.0, 1.0);
        pass.set_scissor_rect(0, 0, width, height);
        pass
    }

    /// Copies the top-left `width × height` pixels to the readback buffers, rows
    /// `padded_row_bytes(width)` apart.
    pub fn encode_readback(&self, encoder: &mut wgpu::CommandEncoder, width: u32, height: u32) {
        let size = wgpu::Extent3d { width, height, depth_or_array_layers: 1 };
        for (texture, buffer) in [(&self.color, &self.color_readback), (&self.depth_out, &self.depth_readback)] {
            encoder.copy_texture_to_buffer(
                texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo { buffer, layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded_row_bytes(width)), rows_per_image: Some(height) } },
                size,
            );
        }
    }

    /// Waits for the submitted copies of a `height`-row image, then hands `read` the padded
    /// colour and depth bytes (`encode_readback`'s rows).
    pub fn read<R>(&self, device: &wgpu::Device, width: u32, height: u32, read: impl FnOnce(&[u8], &[u8]) -> R) -> Result<R, RenderError> {
        let buffers = [&self.color_readback, &self.depth_readback];
        let bytes = padded_row_bytes(width) as u64 * height as u64;
        let (tx, rx) = mpsc::channel();
        for (i, b) in buffers.iter().enumerate() {
            let tx = tx.clone();
            b.slice(..bytes).map_async(wgpu::MapMode::Read, move |r| {
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
            let color = buffers[0].get_mapped_range(..bytes).map_err(err)?;
            let depth = buffers[1].get_mapped_range(..bytes).map_err(err)?;
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
