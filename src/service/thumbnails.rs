//! The thumbnails the service keeps (an object drawn from a fixed three-quarter view, by
//! object and size, with the object's generation it shows) and the PNG encoding of the
//! pictures it answers; `core_thumbnail` draws them for `Core`.

use super::error::ServiceError;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

pub const DEFAULT_SIZE: u32 = 192;
pub const SIZES: std::ops::RangeInclusive<u32> = 32..=512;
/// Kept thumbnails; past this many, all are dropped and drawn again when asked for.
pub(super) const KEPT: usize = 1024;

/// A drawn thumbnail and the object's generation (`ObjectStore::generation`) it shows.
pub(super) struct Kept {
    pub(super) generation: u64,
    pub(super) png: Arc<[u8]>,
}

/// Drawn thumbnails by (object id, size).
#[derive(Default)]
pub struct Thumbnails {
    pub(super) kept: Mutex<HashMap<(String, u32), Kept>>,
    /// Held while one thumbnail is drawn. A console opening on a catalogue asks for every
    /// card's picture at once; drawn one at a time, at most one object not in memory is
    /// read for them (a whole object, on S3), and a request that waited finds its picture
    /// kept rather than drawing it again.
    pub(super) drawing: Mutex<()>,
    /// Thumbnails drawn since start (`b2tf_thumbnails_drawn_total`: what the lock saves
    /// shows there).
    pub(super) drawn: AtomicU64,
}

impl Thumbnails {
    pub(super) fn kept(&self, key: &(String, u32), generation: u64) -> Option<Arc<[u8]>> {
        self.kept.lock().expect("thumbnail lock").get(key).filter(|k| k.generation == generation).map(|k| k.png.clone())
    }

    pub fn drawn(&self) -> u64 {
        self.drawn.load(Ordering::Relaxed)
    }
}

/// A picture for an answer (a thumbnail, an estimate's overlay) as PNG bytes.
pub(super) fn png(img: &image::RgbImage) -> Result<Vec<u8>, ServiceError> {
    super::client::png_bytes(img).map_err(|e| ServiceError::internal(format!("encoding a PNG: {e}")))
}
