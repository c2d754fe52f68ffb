//! Thumbnails: an object drawn from a fixed three-quarter view, for lists of objects (the
//! web console's). Drawn once per object version and size and kept (a few KB each); an
//! object not already in memory is read from the store for the drawing without entering
//! the model cache, so browsing a catalogue does not push out the objects being estimated.

use super::core::Core;
use super::error::{ErrorKind, ServiceError};
use super::thumbnails::{png, Kept, KEPT, SIZES};
use crate::geometry::{views, Intrinsics};
use crate::mesh::Mesh;
use crate::render::{RenderOptions, RenderPool};
use nalgebra::Vector3;
use std::sync::atomic::Ordering;
use std::sync::Arc;

impl Core {
    /// The PNG thumbnail of object `id`, `size` pixels square.
    pub fn thumbnail(&self, id: &str, size: u32) -> Result<Arc<[u8]>, ServiceError> {
        if !SIZES.contains(&size) {
            return Err(ServiceError::invalid(format!("size {size} is outside {}–{} pixels", SIZES.start(), SIZES.end())));
        }
        crate::store::validate_id(id)?;
        let Some(generation) = self.store.generation(id)? else {
            return Err(crate::store::StoreError::NotFound(id.to_string()).into());
        };
        let key = (id.to_string(), size);
        if let Some(png) = self.thumbnails.kept(&key, generation) {
            return Ok(png);
        }
        let _drawing = self.thumbnails.drawing.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(png) = self.thumbnails.kept(&key, generation) {
            return Ok(png);
        }
        let model = match self.cache.held(id) {
            Some(m) => m,
            None => Arc::new(tracing::info_span!("store.get", object_id = id).in_scope(|| self.store.get(id))?),
        };
        let png: Arc<[u8]> = draw(&self.pool, &model.mesh, size)?.into();
        self.thumbnails.drawn.fetch_add(1, Ordering::Relaxed);
        let mut kept = self.thumbnails.kept.lock().expect("thumbnail lock");
        if kept.len() >= KEPT {
            kept.clear();
        }
        kept.insert(key, Kept { generation, png: png.clone() });
        Ok(png)
    }
}

/// The mesh seen from above-front-right, filling about 90 % of a light grey square.
fn draw(pool: &RenderPool, mesh: &Mesh, size: u32) -> Result<Vec<u8>, ServiceError> {
    let f = 1.2 * size as f64;
    let c = (size as f64 - 1.0) / 2.0;
    let k = Intrinsics::new(f, f, c, c, size, size).map_err(|e| ServiceError::internal(e.to_string()))?;
    let radius = mesh.bounding_radius().max(1e-6);
    let pose = views::view_pose(&Vector3::new(1.0, -1.3, 0.9), 0.0, &Vector3::from(mesh.bbox_center()), f * radius / (0.45 * size as f64));
    let opts = RenderOptions { light_dir: [0.4, -0.6, -1.0], background: [238, 241, 245], ..Default::default() };
    let r = pool.render(mesh, &pose, &k, &opts).map_err(|e| ServiceError::new(ErrorKind::Internal, format!("drawing the thumbnail: {e}")))?;
    png(&r.rgb)
}

#[cfg(test)]
mod tests {
    use crate::service::core::{Core, CoreConfig};

    /// A burst of requests for one picture not yet drawn draws it once; the others wait
    /// and get the same bytes. A new size is a new drawing.
    #[test]
    fn concurrent_requests_draw_a_thumbnail_once() {
        let Some(model) = crate::onboard::test_model::small_model() else { return };
        let dir = tempfile::tempdir().unwrap();
        let core = Core::new(CoreConfig { store_url: format!("dir://{}", dir.path().display()), render_pool: 2, ..Default::default() }).unwrap();
        core.store.put(&crate::onboard::ObjectModel { object_id: "a".into(), ..(*model).clone() }, false).unwrap();
        let pngs: Vec<_> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..6).map(|_| s.spawn(|| core.thumbnail("a", 64).unwrap())).collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(core.thumbnails.drawn(), 1, "six requests, one drawing");
        assert!(pngs.iter().all(|p| p == &pngs[0]));
        core.thumbnail("a", 96).unwrap();
        assert_eq!(core.thumbnails.drawn(), 2);
    }
}
