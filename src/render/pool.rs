//! `RenderPool`: a few renderers behind mutexes so that any thread can render. Each
//! renderer has its own device and mesh cache, so a mesh is uploaded once per renderer.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, TryLockError};

use super::{RenderError, RenderOptions, RenderOutput, Renderer, RendererConfig};
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::Mesh;

pub struct RenderPool {
    renderers: Vec<Mutex<Renderer>>,
    /// Where the next checkout starts looking, so that load spreads over the renderers.
    next: AtomicUsize,
    /// Mesh uploads over all renderers, counted as checkouts end (readable without waiting
    /// for a render in progress).
    uploads: AtomicU64,
}

impl RenderPool {
    /// Two: a second renderer lets one render's CPU-side readback and unpadding overlap
    /// another's rasterisation, at the cost of a second copy of each cached mesh. On
    /// lavapipe (2 shared cores, 512², 10k triangles) one renderer gave ~100 renders/s,
    /// pools of 2 and 4 gave 80–140 and 80–170 (noisy: the cores were shared).
    pub const DEFAULT_SIZE: usize = 2;

    /// A pool of `size` renderers (at least 1).
    pub fn new(size: usize, config: RendererConfig) -> Result<Self, RenderError> {
        let renderers = (0..size.max(1)).map(|_| Renderer::with_config(config.clone()).map(Mutex::new)).collect::<Result<_, _>>()?;
        Ok(Self { renderers, next: AtomicUsize::new(0), uploads: AtomicU64::new(0) })
    }

    pub fn size(&self) -> usize {
        self.renderers.len()
    }

    pub fn describe(&self) -> String {
        format!("{} x {}", self.size(), self.checkout().describe())
    }

    /// Mesh uploads summed over all renderers (those of renders still in progress not yet).
    pub fn mesh_uploads(&self) -> u64 {
        self.uploads.load(Ordering::Relaxed)
    }

    pub fn render(&self, mesh: &Mesh, pose: &Pose, k: &Intrinsics, opts: &RenderOptions) -> Result<RenderOutput, RenderError> {
        self.checkout().render(mesh, pose, k, opts)
    }

    /// Uploads `mesh` to every renderer that does not hold it yet. Its stored textures are
    /// decoded once for all of them (held here until the last upload) rather than once per
    /// renderer, as first renders on each would.
    pub fn prepare(&self, mesh: &Mesh) -> Result<(), RenderError> {
        let _decoded: Vec<_> = mesh.materials().iter().filter_map(|m| m.texture.as_ref()?.pixels().ok()).collect();
        self.renderers.iter().try_for_each(|r| self.counted(lock(r)).prepare(mesh))
    }

    /// Whether a renderer not busy right now lacks `mesh` (busy ones are not waited for: a
    /// caller deciding whether to upload ahead can leave them to upload on first use).
    pub fn lacks(&self, mesh: &Mesh) -> bool {
        self.renderers.iter().any(|r| match r.try_lock() {
            Ok(r) => !r.holds(mesh),
            Err(TryLockError::Poisoned(e)) => !e.into_inner().holds(mesh),
            Err(TryLockError::WouldBlock) => false,
        })
    }

    /// Several views of one mesh, in order, spread over the pool's renderers.
    pub fn render_batch(&self, mesh: &Mesh, views: &[(Pose, Intrinsics)], opts: &RenderOptions) -> Result<Vec<RenderOutput>, RenderError> {
        let workers = self.size().min(views.len());
        if workers <= 1 {
            return self.checkout().render_batch(mesh, views, opts);
        }
        let next_view = AtomicUsize::new(0);
        let mut done: Vec<(usize, Result<RenderOutput, RenderError>)> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..workers)
                .map(|_| {
                    s.spawn(|| {
                        let mut renderer = self.checkout();
                        let mut out = Vec::new();
                        loop {
                            let i = next_view.fetch_add(1, Ordering::Relaxed);
                            let Some((pose, k)) = views.get(i) else { break };
                            let r = renderer.render(mesh, pose, k, opts);
                            let failed = r.is_err();
                            out.push((i, r));
                            if failed {
                                break;
                            }
                        }
                        out
                    })
                })
                .collect();
            handles.into_iter().flat_map(|h| h.join().expect("render worker panicked")).collect()
        });
        done.sort_by_key(|(i, _)| *i);
        // A worker that failed stops early, so on error some views may be missing.
        done.into_iter().map(|(_, r)| r).collect()
    }

    /// A free renderer if there is one, else waits for the next in turn.
    fn checkout(&self) -> Checkout<'_> {
        let n = self.renderers.len();
        let start = self.next.fetch_add(1, Ordering::Relaxed) % n;
        for i in 0..n {
            match self.renderers[(start + i) % n].try_lock() {
                Ok(r) => return self.counted(r),
                Err(TryLockError::Poisoned(e)) => return self.counted(e.into_inner()),
                Err(TryLockError::WouldBlock) => {}
            }
        }
        self.counted(lock(&self.renderers[start]))
    }

    fn counted<'a>(&'a self, renderer: MutexGuard<'a, Renderer>) -> Checkout<'a> {
        Checkout { uploads_before: renderer.mesh_uploads(), renderer, total: &self.uploads }
    }
}

/// A renderer in use; adds the meshes it uploaded meanwhile to the pool's count when done.
struct Checkout<'a> {
    renderer: MutexGuard<'a, Renderer>,
    uploads_before: u64,
    total: &'a AtomicU64,
}

impl std::ops::Deref for Checkout<'_> {
    type Target = Renderer;
    fn deref(&self) -> &Renderer {
        &self.renderer
    }
}

impl std::ops::DerefMut for Checkout<'_> {
    fn deref_mut(&mut self) -> &mut Renderer {
        &mut self.renderer
    }
}

impl Drop for Checkout<'_> {
    fn drop(&mut self) {
        self.total.fetch_add(self.renderer.mesh_uploads() - self.uploads_before, Ordering::Relaxed);
    }
}

/// A panic mid-render leaves the renderer usable (every render starts from a clean pass),
/// so poisoning is ignored.
fn lock(m: &Mutex<Renderer>) -> MutexGuard<'_, Renderer> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}
