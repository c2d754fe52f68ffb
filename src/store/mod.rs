//! Object databases: where onboarded objects live between runs. One trait, three backends:
//! a folder per object (`dir://PATH`), one SQLite file (`sqlite://PATH.db`, the default)
//! and an S3 bucket (`s3://BUCKET/PREFIX`), all holding the same encoded form
//! (`codec.rs`), plus an in-memory LRU cache
//! of loaded objects under a byte budget (`cache.rs`).
//!
//! Guarantees every backend keeps (and the shared test suite checks): a put is atomic (an
//! object is absent or complete, also after the writer is killed), a damaged object gives
//! an error naming it while the others still load, and readers work while a writer puts.

pub mod cache;
pub mod codec;
pub mod dir;
pub mod read_only;
pub mod s3;
mod s3_url;
pub mod sqlite;

pub use cache::ModelCache;

use crate::features::BackboneIdentity;
use crate::mesh::Units;
use crate::onboard::ObjectModel;
use std::path::PathBuf;
use std::sync::Arc;

/// One stored object as `list` shows it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ObjectInfo {
    pub id: String,
    /// Units of the mesh file it was onboarded from (the model itself is in metres).
    pub units: Units,
    pub diameter_m: f64,
    pub backbone: BackboneIdentity,
    pub templates: usize,
    /// Bytes the object takes in the store.
    pub bytes: u64,
    /// Unix seconds.
    pub created_at: u64,
    /// The object's symmetries (metres) and their source; `None`: unknown (stored before
    /// format 5).
    pub symmetries: Option<crate::geometry::symmetry::KnownSymmetries>,
}

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("invalid object id {0:?}: 1–64 characters of A–Z a–z 0–9 - _ . not starting with '.'")]
    BadId(String),
    #[error("object {0:?} not found")]
    NotFound(String),
    #[error("object {0:?} already exists (replace it explicitly)")]
    AlreadyExists(String),
    #[error("object {object:?} is damaged: {message}")]
    Corrupt { object: String, message: String },
    #[error("object {object:?} was written in model format {found}, newer than this program understands ({supported}); upgrade b2tfpose")]
    TooNew { object: String, found: u32, supported: u32 },
    #[error("{context}: {source}")]
    Io { context: String, source: std::io::Error },
    #[error("{context}: {message}")]
    Database { context: String, message: String },
    #[error("store database {path} has schema version {found}, newer than this program understands ({supported}); upgrade b2tfpose")]
    SchemaTooNew { path: PathBuf, found: u32, supported: u32 },
    #[error("store URL {0}: expected dir://PATH, sqlite://PATH or s3://BUCKET[/PREFIX][?OPTIONS]")]
    BadUrl(String),
    /// A remote store (S3) did not answer as it should: unreachable, refused credentials,
    /// a missing bucket.
    #[error("{context}: {message}")]
    Remote { context: String, message: String },
    #[error("store {0} is open read-only: onboard and delete objects with a writer on the same store (e.g. `b2tf onboard --store {0}`, or a server without --read-only)")]
    ReadOnly(String),
}

impl StoreError {
    pub(crate) fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> StoreError {
        let context = context.into();
        move |source| StoreError::Io { context, source }
    }

    pub(crate) fn from_codec(object: &str, e: codec::CodecError) -> StoreError {
        match e {
            codec::CodecError::Corrupt(message) => StoreError::Corrupt { object: object.to_string(), message },
            codec::CodecError::TooNew { found, supported } => StoreError::TooNew { object: object.to_string(), found, supported },
        }
    }
}

/// Checks an object id before it becomes a folder name or a database key: no path
/// separators, no leading dot, no traversal, bounded length.
pub fn validate_id(id: &str) -> Result<(), StoreError> {
    crate::onboard::validate_object_id(id).map_err(|_| StoreError::BadId(id.to_string()))
}

/// A place that keeps onboarded objects. Implementations are safe to share between threads
/// and to open from several processes at once.
pub trait ObjectStore: Send + Sync {
    /// Stores `model` under its id; an existing object is replaced only with `replace`.
    fn put(&self, model: &ObjectModel, replace: bool) -> Result<ObjectInfo, StoreError>;
    fn get(&self, id: &str) -> Result<ObjectModel, StoreError>;
    /// Every object, by id.
    fn list(&self) -> Result<Vec<ObjectInfo>, StoreError>;
    fn info(&self, id: &str) -> Result<ObjectInfo, StoreError>;
    fn delete(&self, id: &str) -> Result<(), StoreError>;
    fn exists(&self, id: &str) -> Result<bool, StoreError>;
    /// A number that changes whenever the object is written (put or replaced), read
    /// without reading the object: what a replica's cache compares to notice a replaced
    /// object (`ModelCache::revalidate`). `None` when there is no such object.
    fn generation(&self, id: &str) -> Result<Option<u64>, StoreError>;
    /// The URL this store was opened from.
    fn url(&self) -> String;
}

/// The store used when none is given: `$B2TF_STORE`, else SQLite in the user's data folder
/// (`$XDG_DATA_HOME/b2tfpose/objects.db`, `~/.local/share/b2tfpose/objects.db`).
pub fn default_url() -> String {
    if let Ok(u) = std::env::var("B2TF_STORE") {
        if !u.is_empty() {
            return u;
        }
    }
    let data = std::env::var_os("XDG_DATA_HOME").map(PathBuf::from).or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/share"))).unwrap_or_else(|| PathBuf::from("."));
    format!("sqlite://{}", data.join("b2tfpose/objects.db").display())
}

/// Opens `dir://PATH` or `sqlite://PATH` (created when missing), or `s3://BUCKET/PREFIX`
/// (the bucket must exist).
pub fn open(url: &str) -> Result<Arc<dyn ObjectStore>, StoreError> {
    if url.starts_with("s3://") {
        Ok(Arc::new(s3::S3Store::open(url)?))
    } else if let Some(p) = url.strip_prefix("dir://") {
        if p.is_empty() {
            return Err(StoreError::BadUrl(url.into()));
        }
        Ok(Arc::new(dir::DirStore::open(p)?))
    } else if let Some(p) = url.strip_prefix("sqlite://") {
        if p.is_empty() {
            return Err(StoreError::BadUrl(url.into()));
        }
        Ok(Arc::new(sqlite::SqliteStore::open(p)?))
    } else {
        Err(StoreError::BadUrl(url.into()))
    }
}

/// Opens an existing `dir://PATH` or `sqlite://PATH` without ever writing to it: nothing is
/// created, migrated or cleaned up (a writer elsewhere may be mid-put), and puts and
/// deletes are refused. For replicas that share a store another process writes.
pub fn open_read_only(url: &str) -> Result<Arc<dyn ObjectStore>, StoreError> {
    let inner: Arc<dyn ObjectStore> = match (url.strip_prefix("dir://"), url.strip_prefix("sqlite://")) {
        _ if url.starts_with("s3://") => Arc::new(s3::S3Store::open_read_only(url)?),
        (Some(p), _) if !p.is_empty() => Arc::new(dir::DirStore::open_read_only(p)?),
        (_, Some(p)) if !p.is_empty() => Arc::new(sqlite::SqliteStore::open_read_only(p)?),
        _ => return Err(StoreError::BadUrl(url.into())),
    };
    Ok(Arc::new(read_only::ReadOnlyStore::new(inner)))
}

/// A name part unique to this process and moment, for temporary files and folders.
pub(crate) fn unique_suffix() -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    format!("{}-{nanos}-{n}", std::process::id())
}

/// Info of a model about to be stored, from the encoded manifest.
pub(crate) fn info_of(summary: &codec::ManifestSummary, bytes: u64) -> ObjectInfo {
    ObjectInfo {
        id: summary.object_id.clone(),
        units: summary.source_units,
        diameter_m: summary.diameter_m,
        backbone: summary.backbone.clone(),
        templates: summary.templates,
        bytes,
        created_at: summary.created_unix_s,
        symmetries: summary.symmetries.clone(),
    }
}
