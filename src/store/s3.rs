//! `s3://BUCKET[/PREFIX][?OPTIONS]`: objects in an S3-compatible bucket (AWS S3, MinIO,
//! Ceph RGW, Cloudflare R2, ...), for replicas on several nodes without a shared volume.
//!
//! Layout under the prefix, per object:
//! - `<id>/parts/<write>/tensors.safetensors` and `<id>/parts/<write>/textures/*.png`,
//!   one folder per write (the codec's random write number, `codec::encode`);
//! - `<id>/manifest.json`, written last. It names its write, so it is the commit: a PUT
//!   of one S3 object is atomic, so readers see the old object or the new one whole, and a
//!   writer killed before it leaves only unreferenced parts, which nobody reads. A new id
//!   is put with `If-None-Match: *`, so two writers racing for it cannot both win.
//!
//! A replace deletes the old write's parts after the new manifest is in place; a reader
//! that read the old manifest just before then finds its parts gone (or mixed: the codec
//! notices) and reads again, as `dir://` readers do. Parts of killed writes are removed by
//! later puts of the same id and, for ids that never got a manifest, by a writer's open
//! once they are older than an hour (a live writer elsewhere may still be uploading).
//!
//! Settings: `s3_url.rs`. object_store is async; the store's trait is not (its callers run
//! on blocking threads or the CLI's main thread), so each call runs its requests on one
//! process-wide runtime (concurrently where they are independent: the parts of a put or a
//! get, the objects of a listing) and waits; decoding stays on the caller's thread.

use super::codec;
use super::s3_url::{config_key, mask_secrets, parse_url};
use super::{info_of, validate_id, ObjectInfo, ObjectStore as Store, StoreError};
use crate::onboard::ObjectModel;
use futures_util::{StreamExt, TryStreamExt};
use object_store::aws::AmazonS3Builder;
use object_store::path::Path;
use object_store::{ObjectMeta, ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload};
use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

const MANIFEST: &str = "manifest.json";
const TENSORS: &str = "tensors.safetensors";
/// Reads of one object attempted before a torn read (a replace racing it) is reported.
const READ_ATTEMPTS: u32 = 6;
/// Parts without a manifest younger than this may belong to a put still under way.
pub const DEFAULT_ORPHAN_AGE: Duration = Duration::from_secs(3600);
/// Requests in flight at once for one call (a listing's objects, a put's parts).
const CONCURRENCY: usize = 16;
/// Parts larger than two of these are read as byte ranges of this size, `RANGE_READS` at
/// once: one HTTP stream rarely fills a link (S3's own advice for throughput), and a
/// write's parts never change, so the ranges of one part cannot come from two writes.
const RANGE_BYTES: u64 = 8 << 20;
const RANGE_READS: usize = 8;

pub struct S3Store {
    bucket: Bucket,
    /// The URL as opened, secrets masked.
    url: String,
}

/// The client and the folder of the bucket that holds the objects (may be empty: the
/// bucket's root); cheap to clone into each call's task.
#[derive(Clone)]
struct Bucket {
    client: Arc<dyn ObjectStore>,
    prefix: Path,
}

/// The runtime every S3 call runs on: one per process, never dropped (dropping a runtime
/// from inside another one's async context panics, and stores live in `Arc`s that may be
/// dropped anywhere).
fn runtime() -> Result<&'static tokio::runtime::Runtime, StoreError> {
    static RT: OnceLock<Result<tokio::runtime::Runtime, String>> = OnceLock::new();
    RT.get_or_init(|| tokio::runtime::Builder::new_multi_thread().worker_threads(2).thread_name("b2tf-s3").enable_all().build().map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|e| StoreError::Remote { context: "starting the S3 client's runtime".into(), message: e.clone() })
}

/// Runs `fut` on the S3 runtime and waits for it, from any thread (also one of another
/// runtime's, where `block_on` would panic).
fn run<T: Send + 'static>(fut: impl Future<Output = Result<T, StoreError>> + Send + 'static) -> Result<T, StoreError> {
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    runtime()?.spawn(async move {
        let _ = tx.send(fut.await);
    });
    rx.recv().map_err(|_| StoreError::Remote { context: "S3 request".into(), message: "the request's task ended without an answer".into() })?
}

/// An object_store error as a store error about `what`.
fn remote(what: impl Into<String>) -> impl FnOnce(object_store::Error) -> StoreError {
    let context = what.into();
    move |e| {
        let mut message = e.to_string();
        // With no credentials configured, object_store asks the EC2 instance metadata
        // service, and the error names only that address.
        if message.contains("169.254.169.254") {
            message.push_str(" (no credentials were found: set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, or run where instance, container or web-identity credentials exist; skip_signature=true for a public bucket)");
        }
        StoreError::Remote { context, message }
    }
}

/// `base/rel`, `rel` split at its slashes (a texture's name is `textures/NAME.png`; one
/// `Path` part would encode the slash).
fn below(base: &Path, rel: &str) -> Path {
    rel.split('/').fold(base.clone(), |p, segment| p.join(segment))
}

/// How long ago S3 says a key was written (zero for clocks that disagree).
fn age(meta: &ObjectMeta) -> Duration {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs() as i64).unwrap_or(0);
    Duration::from_secs(now.saturating_sub(meta.last_modified.timestamp()).max(0) as u64)
}

/// `0..size` in `RANGE_BYTES` pieces, the last one shorter.
fn ranges_of(size: u64) -> impl Iterator<Item = std::ops::Range<u64>> {
    (0..size.div_ceil(RANGE_BYTES)).map(move |i| i * RANGE_BYTES..((i + 1) * RANGE_BYTES).min(size))
}

/// The write a manifest names (every manifest this store writes names one).
fn write_of(id: &str, manifest: &[u8]) -> Result<(codec::ManifestSummary, u64), StoreError> {
    let summary = codec::summary(manifest).map_err(|e| StoreError::from_codec(id, e))?;
    let write = summary.generation.ok_or_else(|| StoreError::Corrupt { object: id.into(), message: "its manifest names no write".into() })?;
    Ok((summary, write))
}

/// An object's bytes as one read fetched them: the manifest, and the parts of its write
/// by name relative to the write's folder.
struct Fetched {
    manifest: Vec<u8>,
    parts: HashMap<String, Vec<u8>>,
}

impl Bucket {
    fn folder(&self, id: &str) -> Path {
        self.prefix.clone().join(id)
    }

    fn manifest(&self, id: &str) -> Path {
        self.folder(id).join(MANIFEST)
    }

    fn write_folder(&self, id: &str, write: u64) -> Path {
        self.folder(id).join("parts").join(format!("{write:016x}"))
    }

    /// The bytes at `path`; `None` when there is no such key.
    async fn get(&self, path: &Path) -> object_store::Result<Option<Vec<u8>>> {
        match self.client.get(path).await {
            Ok(r) => Ok(Some(r.bytes().await?.to_vec())),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// The whole of a part, in concurrent byte ranges when it is large; `None` when it is
    /// gone.
    async fn get_part(&self, meta: &ObjectMeta) -> object_store::Result<Option<Vec<u8>>> {
        if meta.size <= 2 * RANGE_BYTES {
            return self.get(&meta.location).await;
        }
        let chunks = futures_util::stream::iter(ranges_of(meta.size))
            .map(|r| async move { self.client.get_range(&meta.location, r.clone()).await.map(|b| (r, b)) })
            .buffer_unordered(RANGE_READS)
            .try_collect::<Vec<_>>()
            .await;
        let chunks = match chunks {
            Ok(c) => c,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(e),
        };
        let mut out = vec![0u8; meta.size as usize];
        for (r, bytes) in chunks {
            out[r.start as usize..r.end as usize].copy_from_slice(&bytes);
        }
        Ok(Some(out))
    }

    async fn head(&self, path: &Path) -> object_store::Result<Option<ObjectMeta>> {
        match self.client.head(path).await {
            Ok(m) => Ok(Some(m)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// Every key under `folder`, with its size and time.
    async fn list(&self, folder: &Path) -> object_store::Result<Vec<ObjectMeta>> {
        self.client.list(Some(folder)).try_collect().await
    }

    async fn delete_all(&self, keys: Vec<Path>) -> object_store::Result<()> {
        if keys.is_empty() {
            return Ok(());
        }
        let stream = futures_util::stream::iter(keys.into_iter().map(Ok)).boxed();
        self.client.delete_stream(stream).try_collect::<Vec<_>>().await.map(drop)
    }

    /// Removes every key under `folder`.
    async fn delete_under(&self, folder: &Path) -> object_store::Result<()> {
        self.delete_all(self.list(folder).await?.into_iter().map(|m| m.location).collect()).await
    }

    /// The object's manifest, its summary, and the folder and keys of the write it names.
    async fn current_write(&self, id: &str) -> Result<(Vec<u8>, codec::ManifestSummary, Path, Vec<ObjectMeta>), StoreError> {
        let context = || format!("reading object {id:?}");
        let manifest = self.get(&self.manifest(id)).await.map_err(remote(context()))?.ok_or_else(|| StoreError::NotFound(id.into()))?;
        let (summary, write) = write_of(id, &manifest)?;
        let folder = self.write_folder(id, write);
        let keys = self.list(&folder).await.map_err(remote(context()))?;
        Ok((manifest, summary, folder, keys))
    }

    /// The manifest and every part of the write it names, fetched concurrently.
    async fn fetch(&self, id: &str) -> Result<Fetched, StoreError> {
        let context = || format!("reading object {id:?}");
        let (manifest, _, folder, keys) = self.current_write(id).await?;
        let parts = futures_util::stream::iter(keys)
            .map(|meta| {
                let folder = &folder;
                async move {
                    let name = meta.location.prefix_match(folder).map(|segments| segments.map(|s| s.as_ref().to_string()).collect::<Vec<_>>().join("/")).unwrap_or_default();
                    // Gone since the listing: a replace removed it; the caller reads again.
                    let bytes = self
                        .get_part(&meta)
                        .await
                        .map_err(remote(context()))?
                        .ok_or_else(|| StoreError::Corrupt { object: id.into(), message: format!("its part {name} vanished while it was read") })?;
                    Ok::<_, StoreError>((name, bytes))
                }
            })
            .buffer_unordered(CONCURRENCY)
            .try_collect()
            .await?;
        Ok(Fetched { manifest, parts })
    }

    /// What `list` shows of one object: its manifest's summary and the bytes of its write.
    async fn info(&self, id: &str) -> Result<ObjectInfo, StoreError> {
        let (manifest, summary, _, parts) = self.current_write(id).await?;
        Ok(info_of(&summary, manifest.len() as u64 + parts.iter().map(|m| m.size).sum::<u64>()))
    }

    /// Removes the parts of writes under `id` other than `keep`; with `min_age`, only those
    /// older than it (another writer may be uploading younger ones).
    async fn remove_writes(&self, id: &str, keep: Option<u64>, min_age: Option<Duration>) -> object_store::Result<()> {
        let parts = self.folder(id).join("parts");
        let keep = keep.map(|w| format!("{w:016x}"));
        let stale = self
            .list(&parts)
            .await?
            .into_iter()
            .filter(|m| {
                let write = m.location.prefix_match(&parts).and_then(|mut segments| segments.next()).map(|s| s.as_ref().to_string());
                write != keep && min_age.is_none_or(|min| age(m) >= min)
            })
            .map(|m| m.location)
            .collect();
        self.delete_all(stale).await
    }

    /// Ids with parts but no manifest whose youngest part is older than `min_age`: puts
    /// killed before their commit. One listing of the whole prefix.
    async fn remove_orphans(&self, min_age: Duration) -> object_store::Result<()> {
        let all = self.list(&self.prefix).await?;
        let id_of = |m: &ObjectMeta| m.location.prefix_match(&self.prefix).and_then(|mut segments| segments.next()).map(|s| s.as_ref().to_string()).filter(|id| validate_id(id).is_ok());
        // Per id: whether it has a manifest, and the age of its youngest key.
        let mut ids: HashMap<String, (bool, Duration)> = HashMap::new();
        for m in &all {
            let Some(id) = id_of(m) else { continue };
            let entry = ids.entry(id).or_insert((false, Duration::MAX));
            entry.0 |= m.location.filename() == Some(MANIFEST) && m.location.parts_count() == self.prefix.parts_count() + 2;
            entry.1 = entry.1.min(age(m));
        }
        let abandoned: Vec<Path> =
            all.iter().filter(|m| id_of(m).and_then(|id| ids.get(&id)).is_some_and(|&(has_manifest, youngest)| !has_manifest && youngest >= min_age)).map(|m| m.location.clone()).collect();
        self.delete_all(abandoned).await
    }
}

impl S3Store {
    /// Opens the bucket as a writer: checks that it answers, and removes the parts of puts
    /// killed more than `DEFAULT_ORPHAN_AGE` ago that never got a manifest.
    pub fn open(url: &str) -> Result<Self, StoreError> {
        Self::open_with_orphan_age(url, DEFAULT_ORPHAN_AGE)
    }

    /// `open` with another age for abandoned parts (tests use zero).
    pub fn open_with_orphan_age(url: &str, orphan_age: Duration) -> Result<Self, StoreError> {
        let store = Self::connect(url)?;
        let (bucket, context) = (store.bucket.clone(), format!("reaching store {}", store.url));
        run(async move { bucket.remove_orphans(orphan_age).await.map_err(remote(context)) })?;
        Ok(store)
    }

    /// Opens the bucket for reading only: nothing is removed (a writer elsewhere may be
    /// mid-put); the bucket must answer (one LIST of at most a page).
    pub fn open_read_only(url: &str) -> Result<Self, StoreError> {
        let store = Self::connect(url)?;
        let (bucket, context) = (store.bucket.clone(), format!("reaching store {}", store.url));
        run(async move { bucket.client.list_with_delimiter(Some(&bucket.prefix)).await.map(drop).map_err(remote(context)) })?;
        Ok(store)
    }

    fn connect(url: &str) -> Result<Self, StoreError> {
        let settings = parse_url(url)?;
        // reqwest's rustls needs a process-wide crypto provider for https endpoints; ring is
        // the one this program already uses. Fails harmlessly when one is installed.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let mut builder = AmazonS3Builder::from_env().with_bucket_name(&settings.bucket).with_retry(settings.retry.clone());
        for (k, v) in &settings.options {
            if let Some(key) = config_key(k) {
                builder = builder.with_config(key, v);
            }
        }
        let client = builder.build().map_err(|e| StoreError::BadUrl(format!("{}: {e}", mask_secrets(url))))?;
        Ok(Self { bucket: Bucket { client: Arc::new(client), prefix: Path::from(settings.prefix.as_str()) }, url: mask_secrets(url) })
    }

    /// One attempt at reading an object: fetched whole, then decoded here.
    fn read_once(&self, id: &str) -> Result<ObjectModel, StoreError> {
        let (bucket, owned_id) = (self.bucket.clone(), id.to_string());
        let mut fetched = run(async move { bucket.fetch(&owned_id).await })?;
        let tensors = fetched.parts.remove(TENSORS).ok_or_else(|| StoreError::Corrupt { object: id.into(), message: format!("its part {TENSORS} is missing") })?;
        let mut texture = |name: &str| fetched.parts.remove(name).ok_or_else(|| format!("part {name} is missing"));
        let model = codec::decode(&fetched.manifest, &tensors, &mut texture).map_err(|e| StoreError::from_codec(id, e))?;
        if model.object_id != id {
            return Err(StoreError::Corrupt { object: id.into(), message: format!("its manifest holds object {:?}", model.object_id) });
        }
        Ok(model)
    }

    fn head_manifest(&self, id: &str) -> Result<Option<ObjectMeta>, StoreError> {
        validate_id(id)?;
        let (bucket, path, context) = (self.bucket.clone(), self.bucket.manifest(id), format!("looking up object {id:?}"));
        run(async move { bucket.head(&path).await.map_err(remote(context)) })
    }
}

impl Store for S3Store {
    fn put(&self, model: &ObjectModel, replace: bool) -> Result<ObjectInfo, StoreError> {
        let id = model.object_id.clone();
        validate_id(&id)?;
        let (bucket, manifest_path) = (self.bucket.clone(), self.bucket.manifest(&id));
        let context = format!("putting object {id:?} into {}", self.url);
        let old = run({
            let (bucket, path, context) = (bucket.clone(), manifest_path.clone(), context.clone());
            async move { bucket.get(&path).await.map_err(remote(context)) }
        })?;
        if old.is_some() && !replace {
            return Err(StoreError::AlreadyExists(id));
        }
        let enc = codec::encode(model).map_err(|e| StoreError::from_codec(&id, e))?;
        let (summary, write) = write_of(&id, &enc.manifest)?;
        let previous = old.as_deref().and_then(|m| write_of(&id, m).ok()).map(|(_, w)| w).filter(|&w| w != write);
        let folder = bucket.write_folder(&id, write);
        let mut parts = vec![(folder.clone().join(TENSORS), enc.tensors)];
        parts.extend(enc.textures.into_iter().map(|(name, png)| (below(&folder, &name), png)));
        let bytes = enc.manifest.len() as u64 + parts.iter().map(|(_, b)| b.len() as u64).sum::<u64>();
        let (manifest, create) = (enc.manifest, old.is_none());
        let owned_id = id.clone();
        run(async move {
            let uploads = futures_util::stream::iter(parts).map(|(path, body)| {
                let bucket = &bucket;
                async move { bucket.client.put(&path, PutPayload::from(body)).await.map(drop) }
            });
            let uploaded = uploads.buffer_unordered(CONCURRENCY).try_collect::<Vec<_>>().await;
            // The commit; a new id only if nobody else created it meanwhile.
            let committed = match uploaded {
                Ok(_) => {
                    let mode = if create { PutMode::Create } else { PutMode::Overwrite };
                    match bucket.client.put_opts(&manifest_path, PutPayload::from(manifest), PutOptions { mode, ..Default::default() }).await {
                        Ok(_) => Ok(()),
                        Err(object_store::Error::AlreadyExists { .. } | object_store::Error::Precondition { .. }) => Err(StoreError::AlreadyExists(owned_id.clone())),
                        Err(e) => Err(remote(context.clone())(e)),
                    }
                }
                Err(e) => Err(remote(context.clone())(e)),
            };
            if let Err(e) = committed {
                // Best effort: what a failed put uploaded is unreferenced either way.
                let _ = bucket.delete_under(&folder).await;
                return Err(e);
            }
            // Readers that fetched the old manifest read again when its parts vanish; writes
            // of killed earlier puts of this id go once surely abandoned.
            if let Some(previous) = previous {
                bucket.delete_under(&bucket.write_folder(&owned_id, previous)).await.map_err(remote(context.clone()))?;
            }
            bucket.remove_writes(&owned_id, Some(write), Some(DEFAULT_ORPHAN_AGE)).await.map_err(remote(context))
        })?;
        Ok(info_of(&summary, bytes))
    }

    fn get(&self, id: &str) -> Result<ObjectModel, StoreError> {
        validate_id(id)?;
        let mut attempt = 0;
        loop {
            match self.read_once(id) {
                // A replace may have raced this read (the parts it named are gone, or the
                // manifest and tensors are of two writes): read again from the manifest.
                Err(StoreError::Corrupt { .. }) if attempt + 1 < READ_ATTEMPTS => {
                    std::thread::sleep(Duration::from_millis(5 << attempt));
                    attempt += 1;
                }
                other => return other,
            }
        }
    }

    fn list(&self) -> Result<Vec<ObjectInfo>, StoreError> {
        let (bucket, context) = (self.bucket.clone(), format!("listing store {}", self.url));
        let mut out: Vec<ObjectInfo> = run(async move {
            let folders = bucket.client.list_with_delimiter(Some(&bucket.prefix)).await.map_err(remote(context))?;
            let ids = folders.common_prefixes.into_iter().filter_map(|f| f.filename().map(str::to_string)).filter(|id| validate_id(id).is_ok());
            let infos = futures_util::stream::iter(ids).map(|id| {
                let bucket = &bucket;
                async move {
                    match bucket.info(&id).await {
                        Ok(info) => Ok(Some(info)),
                        // Deleted since the listing, or the parts of a put not committed.
                        Err(StoreError::NotFound(_)) => Ok(None),
                        Err(e) => Err(e),
                    }
                }
            });
            Ok(infos.buffer_unordered(CONCURRENCY).try_collect::<Vec<_>>().await?.into_iter().flatten().collect())
        })?;
        out.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(out)
    }

    fn info(&self, id: &str) -> Result<ObjectInfo, StoreError> {
        validate_id(id)?;
        let (bucket, id) = (self.bucket.clone(), id.to_string());
        run(async move { bucket.info(&id).await })
    }

    fn delete(&self, id: &str) -> Result<(), StoreError> {
        validate_id(id)?;
        let (bucket, id, context) = (self.bucket.clone(), id.to_string(), format!("deleting object {id:?}"));
        run(async move {
            let manifest = bucket.manifest(&id);
            if bucket.head(&manifest).await.map_err(remote(context.clone()))?.is_none() {
                return Err(StoreError::NotFound(id));
            }
            // The manifest first: the object disappears at once and as a whole.
            bucket.client.delete(&manifest).await.map_err(remote(context.clone()))?;
            bucket.delete_under(&bucket.folder(&id)).await.map_err(remote(context))
        })
    }

    fn exists(&self, id: &str) -> Result<bool, StoreError> {
        Ok(self.head_manifest(id)?.is_some())
    }

    /// From the manifest's ETag, size and time (a HEAD request): every put writes a new
    /// manifest, which names a new write, so its content and ETag differ.
    fn generation(&self, id: &str) -> Result<Option<u64>, StoreError> {
        use std::hash::{Hash, Hasher};
        Ok(self.head_manifest(id)?.map(|m| {
            let mut h = std::collections::hash_map::DefaultHasher::new();
            (m.e_tag, m.version, m.size, m.last_modified.timestamp_nanos_opt()).hash(&mut h);
            h.finish()
        }))
    }

    fn url(&self) -> String {
        self.url.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_credentials_are_named_as_such() {
        let imds = object_store::Error::Generic { store: "S3", source: "Error performing PUT http://169.254.169.254/latest/api/token - denied".into() };
        let e = remote("reaching store s3://b/p")(imds).to_string();
        assert!(e.contains("no credentials were found") && e.contains("AWS_ACCESS_KEY_ID"), "{e}");
        let other = remote("reaching store s3://b/p")(object_store::Error::Generic { store: "S3", source: "NoSuchBucket".into() }).to_string();
        assert!(!other.contains("credentials"), "{other}");
    }

    #[test]
    fn large_parts_are_split_into_ranges_that_cover_them() {
        // Contiguous, non-overlapping, the last one short; an exact multiple has no empty tail.
        let size = 5 * RANGE_BYTES / 2 + 7;
        let ranges: Vec<_> = ranges_of(size).collect();
        assert_eq!(ranges.len(), 3);
        assert!(ranges.windows(2).all(|w| w[0].end == w[1].start) && ranges[0].start == 0 && ranges[2].end == size);
        assert_eq!(ranges_of(3 * RANGE_BYTES).count(), 3);
        assert_eq!(ranges_of(3 * RANGE_BYTES).last(), Some(2 * RANGE_BYTES..3 * RANGE_BYTES));
    }
}
