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
//! Settings come from the usual `AWS_*` variables (`AWS_ACCESS_KEY_ID`,
//! `AWS_SECRET_ACCESS_KEY`, `AWS_REGION`, `AWS_ENDPOINT_URL`, `AWS_ALLOW_HTTP`, ...) and
//! from the URL's query, which wins: any of object_store's S3 keys without the `aws_`
//! prefix (`endpoint`, `region`, `allow_http`, `virtual_hosted_style_request`, ...), plus
//! `max_retries` and `retry_timeout_s`. Keys given in the query are not echoed back by
//! `url()` when they are secrets.
//!
//! object_store is async; the store's trait is not (its callers run on blocking threads or
//! the CLI's main thread), so each call runs on one process-wide runtime and waits.

use super::codec;
use super::{info_of, validate_id, ObjectInfo, ObjectStore as Store, StoreError};
use crate::onboard::ObjectModel;
use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use object_store::path::Path;
use object_store::{ObjectStore, ObjectStoreExt, PutMode, PutOptions, PutPayload, RetryConfig};
use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

const MANIFEST: &str = "manifest.json";
const TENSORS: &str = "tensors.safetensors";
/// Reads of one object attempted before a torn read (a replace racing it) is reported.
const READ_ATTEMPTS: u32 = 6;
/// Parts without a manifest younger than this may belong to a put still under way.
pub const DEFAULT_ORPHAN_AGE: Duration = Duration::from_secs(3600);
/// Query keys that are secrets: accepted, never shown in `url()` or errors.
const SECRET_KEYS: [&str; 3] = ["secret_access_key", "session_token", "token"];

pub struct S3Store {
    client: Arc<dyn ObjectStore>,
    /// The folder under the bucket that holds the objects (may be empty: the bucket's root).
    prefix: Path,
    /// The URL as opened, secrets masked.
    url: String,
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

/// The store's settings, parsed from the URL.
struct Settings {
    bucket: String,
    prefix: String,
    options: Vec<(String, String)>,
    retry: RetryConfig,
}

fn parse_url(url: &str) -> Result<Settings, StoreError> {
    let bad = |why: &str| StoreError::BadUrl(format!("{}: {why}", mask_secrets(url)));
    let rest = url.strip_prefix("s3://").ok_or_else(|| bad("expected s3://BUCKET[/PREFIX]"))?;
    let (location, query) = rest.split_once('?').unwrap_or((rest, ""));
    let (bucket, prefix) = location.split_once('/').unwrap_or((location, ""));
    // S3's bucket naming rules, the part a URL can get wrong.
    if bucket.len() < 3 || bucket.len() > 63 || !bucket.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-' || b == b'.') {
        return Err(bad("the bucket name must be 3-63 characters of a-z 0-9 - ."));
    }
    let prefix = prefix.trim_matches('/');
    if prefix.split('/').any(|seg| seg == "." || seg == "..") || prefix.contains("//") {
        return Err(bad("the prefix must not contain empty, '.' or '..' segments"));
    }
    let mut retry = RetryConfig { max_retries: 3, retry_timeout: Duration::from_secs(30), ..Default::default() };
    let mut options = Vec::new();
    for pair in query.split('&').filter(|p| !p.is_empty()) {
        let (k, v) = pair.split_once('=').ok_or_else(|| bad(&format!("query part {pair:?} is not KEY=VALUE")))?;
        let v = percent_decode(v).ok_or_else(|| bad(&format!("the value of {k} is not valid percent-encoding")))?;
        match k {
            "max_retries" => retry.max_retries = v.parse().map_err(|_| bad("max_retries must be a whole number"))?,
            "retry_timeout_s" => retry.retry_timeout = v.parse::<f64>().ok().filter(|s| s.is_finite() && *s >= 0.0).map(Duration::from_secs_f64).ok_or_else(|| bad("retry_timeout_s must be a number of seconds"))?,
            "bucket" => return Err(bad("the bucket is the URL's host, not an option")),
            _ => {
                config_key(k).ok_or_else(|| bad(&format!("unknown option {k:?} (object_store's S3 keys without 'aws_', e.g. endpoint, region, allow_http; or max_retries, retry_timeout_s)")))?;
                options.push((k.to_string(), v));
            }
        }
    }
    Ok(Settings { bucket: bucket.to_string(), prefix: prefix.to_string(), options, retry })
}

fn config_key(k: &str) -> Option<AmazonS3ConfigKey> {
    format!("aws_{k}").parse().or_else(|_| k.parse()).ok()
}

fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// The URL with the values of secret query keys replaced by `***`.
fn mask_secrets(url: &str) -> String {
    let Some((base, query)) = url.split_once('?') else { return url.to_string() };
    let parts: Vec<String> = query
        .split('&')
        .map(|p| match p.split_once('=') {
            Some((k, _)) if SECRET_KEYS.contains(&k) => format!("{k}=***"),
            _ => p.to_string(),
        })
        .collect();
    format!("{base}?{}", parts.join("&"))
}

/// An object_store error as a store error about `what`.
fn remote(what: impl Into<String>) -> impl FnOnce(object_store::Error) -> StoreError {
    let context = what.into();
    move |e| StoreError::Remote { context, message: e.to_string() }
}

/// `base/rel`, `rel` split at its slashes (a texture's name is `textures/NAME.png`; one
/// `Path` part would encode the slash).
fn below(base: &Path, rel: &str) -> Path {
    rel.split('/').fold(base.clone(), |p, segment| p.join(segment))
}

/// How long ago S3 says a key was written (zero for clocks that disagree).
fn age(meta: &object_store::ObjectMeta) -> Duration {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs() as i64).unwrap_or(0);
    Duration::from_secs(now.saturating_sub(meta.last_modified.timestamp()).max(0) as u64)
}

fn is_not_found(e: &object_store::Error) -> bool {
    matches!(e, object_store::Error::NotFound { .. })
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
        store.remove_orphans(orphan_age)?;
        Ok(store)
    }

    /// Opens the bucket for reading only: nothing is removed (a writer elsewhere may be
    /// mid-put); the bucket must answer.
    pub fn open_read_only(url: &str) -> Result<Self, StoreError> {
        let store = Self::connect(url)?;
        store.check_reachable()?;
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
        Ok(Self { client: Arc::new(client), prefix: Path::from(settings.prefix.as_str()), url: mask_secrets(url) })
    }

    /// One LIST of at most a page: fails when the endpoint, bucket or credentials are wrong.
    fn check_reachable(&self) -> Result<(), StoreError> {
        let (client, prefix, context) = (self.client.clone(), self.prefix.clone(), format!("reaching store {}", self.url));
        run(async move {
            client.list_with_delimiter(Some(&prefix)).await.map_err(remote(context))?;
            Ok(())
        })
    }

    fn object_folder(&self, id: &str) -> Result<Path, StoreError> {
        validate_id(id)?;
        Ok(self.prefix.clone().join(id))
    }

    fn manifest_path(&self, id: &str) -> Result<Path, StoreError> {
        Ok(self.object_folder(id)?.join(MANIFEST))
    }

    fn write_folder(&self, id: &str, write: u64) -> Result<Path, StoreError> {
        Ok(self.object_folder(id)?.join("parts").join(format!("{write:016x}")))
    }

    /// The manifest's bytes, `None` when the object does not exist.
    fn read_manifest(&self, id: &str) -> Result<Option<Vec<u8>>, StoreError> {
        let (client, path, context) = (self.client.clone(), self.manifest_path(id)?, format!("reading object {id:?}"));
        run(async move {
            match client.get(&path).await {
                Ok(r) => Ok(Some(r.bytes().await.map_err(remote(context))?.to_vec())),
                Err(e) if is_not_found(&e) => Ok(None),
                Err(e) => Err(remote(context)(e)),
            }
        })
    }

    /// The write a manifest names (every manifest this store writes names one).
    fn write_of(id: &str, manifest: &[u8]) -> Result<(codec::ManifestSummary, u64), StoreError> {
        let summary = codec::summary(manifest).map_err(|e| StoreError::from_codec(id, e))?;
        let write = summary.generation.ok_or_else(|| StoreError::Corrupt { object: id.into(), message: "its manifest names no write".into() })?;
        Ok((summary, write))
    }

    /// One attempt at reading an object: the manifest, then the parts it names.
    fn read_once(&self, id: &str) -> Result<ObjectModel, StoreError> {
        let manifest = self.read_manifest(id)?.ok_or_else(|| StoreError::NotFound(id.into()))?;
        let (_, write) = Self::write_of(id, &manifest)?;
        let folder = self.write_folder(id, write)?;
        let part = |name: &str| -> Result<Vec<u8>, StoreError> {
            let (client, path, context) = (self.client.clone(), below(&folder, name), format!("reading object {id:?}"));
            let missing = StoreError::Corrupt { object: id.into(), message: format!("its part {name} is missing") };
            run(async move {
                match client.get(&path).await {
                    Ok(r) => Ok(r.bytes().await.map_err(remote(context))?.to_vec()),
                    Err(e) if is_not_found(&e) => Err(missing),
                    Err(e) => Err(remote(context)(e)),
                }
            })
        };
        let tensors = part(TENSORS)?;
        let mut texture = |name: &str| part(name).map_err(|e| e.to_string());
        let model = codec::decode(&manifest, &tensors, &mut texture).map_err(|e| StoreError::from_codec(id, e))?;
        if model.object_id != id {
            return Err(StoreError::Corrupt { object: id.into(), message: format!("its manifest holds object {:?}", model.object_id) });
        }
        Ok(model)
    }

    /// Every key under `folder` with its size and age.
    fn list_under(&self, folder: Path, what: String) -> Result<Vec<object_store::ObjectMeta>, StoreError> {
        let client = self.client.clone();
        run(async move {
            use futures_util::TryStreamExt;
            client.list(Some(&folder)).try_collect::<Vec<_>>().await.map_err(remote(what))
        })
    }

    fn delete_keys(&self, keys: Vec<Path>, what: String) -> Result<(), StoreError> {
        if keys.is_empty() {
            return Ok(());
        }
        let client = self.client.clone();
        run(async move {
            use futures_util::{StreamExt, TryStreamExt};
            let stream = futures_util::stream::iter(keys.into_iter().map(Ok)).boxed();
            client.delete_stream(stream).try_collect::<Vec<_>>().await.map_err(remote(what))?;
            Ok(())
        })
    }

    fn info_from(&self, id: &str, manifest: &[u8]) -> Result<ObjectInfo, StoreError> {
        let (summary, write) = Self::write_of(id, manifest)?;
        let parts = self.list_under(self.write_folder(id, write)?, format!("listing object {id:?}"))?;
        let bytes = manifest.len() as u64 + parts.iter().map(|m| m.size).sum::<u64>();
        Ok(info_of(&summary, bytes))
    }

    /// Removes the parts of writes under `id` other than `keep`; with `min_age`, only those
    /// older than it (another writer may be uploading younger ones).
    fn remove_writes(&self, id: &str, keep: Option<u64>, min_age: Option<Duration>) -> Result<(), StoreError> {
        let parts = self.object_folder(id)?.join("parts");
        let keep = keep.map(|w| format!("{w:016x}"));
        let stale: Vec<Path> = self
            .list_under(parts.clone(), format!("listing the writes of object {id:?}"))?
            .into_iter()
            .filter(|m| {
                let write = m.location.prefix_match(&parts).and_then(|mut segs| segs.next()).map(|s| s.as_ref().to_string());
                let old_enough = min_age.is_none_or(|min| age(m) >= min);
                write != keep && old_enough
            })
            .map(|m| m.location)
            .collect();
        self.delete_keys(stale, format!("removing old writes of object {id:?}"))
    }

    /// Ids with parts but no manifest whose newest part is older than `age`: puts killed
    /// before their commit. One listing of the whole prefix.
    fn remove_orphans(&self, min_age: Duration) -> Result<(), StoreError> {
        let all = self.list_under(self.prefix.clone(), format!("reaching store {}", self.url))?;
        // Per id: whether it has a manifest, and the age of its youngest key.
        let mut ids: std::collections::BTreeMap<String, (bool, Duration)> = Default::default();
        for m in &all {
            let Some(id) = m.location.prefix_match(&self.prefix).and_then(|mut segs| segs.next()).map(|s| s.as_ref().to_string()) else { continue };
            if validate_id(&id).is_err() {
                continue;
            }
            let entry = ids.entry(id).or_insert((false, Duration::MAX));
            entry.0 |= m.location.filename() == Some(MANIFEST) && m.location.parts_count() == self.prefix.parts_count() + 2;
            entry.1 = entry.1.min(age(m));
        }
        for (id, (has_manifest, youngest)) in ids {
            if !has_manifest && youngest >= min_age {
                let keys = all.iter().filter(|m| m.location.prefix_match(&self.prefix).and_then(|mut s| s.next()).is_some_and(|s| s.as_ref() == id)).map(|m| m.location.clone()).collect();
                self.delete_keys(keys, format!("removing the parts of an abandoned put of {id:?}"))?;
            }
        }
        Ok(())
    }
}

impl Store for S3Store {
    fn put(&self, model: &ObjectModel, replace: bool) -> Result<ObjectInfo, StoreError> {
        let id = model.object_id.clone();
        let manifest_path = self.manifest_path(&id)?;
        let old = self.read_manifest(&id)?;
        if old.is_some() && !replace {
            return Err(StoreError::AlreadyExists(id));
        }
        let enc = codec::encode(model).map_err(|e| StoreError::from_codec(&id, e))?;
        let (summary, write) = Self::write_of(&id, &enc.manifest)?;
        let folder = self.write_folder(&id, write)?;
        let mut parts = vec![(folder.clone().join(TENSORS), enc.tensors)];
        parts.extend(enc.textures.into_iter().map(|(name, png)| (below(&folder, &name), png)));
        let bytes = enc.manifest.len() as u64 + parts.iter().map(|(_, b)| b.len() as u64).sum::<u64>();
        let (client, manifest) = (self.client.clone(), enc.manifest);
        let context = format!("putting object {id:?} into {}", self.url);
        let created_only = old.is_none();
        let committed = run(async move {
            for (path, body) in parts {
                client.put(&path, PutPayload::from(body)).await.map_err(remote(context.clone()))?;
            }
            // The commit. A new id only if nobody else created it meanwhile.
            let mode = if created_only { PutMode::Create } else { PutMode::Overwrite };
            match client.put_opts(&manifest_path, PutPayload::from(manifest), PutOptions { mode, ..Default::default() }).await {
                Ok(_) => Ok(true),
                Err(object_store::Error::AlreadyExists { .. } | object_store::Error::Precondition { .. }) => Ok(false),
                Err(e) => Err(remote(context)(e)),
            }
        });
        match committed {
            Ok(true) => {}
            outcome => {
                // Best effort: what a failed put uploaded is unreferenced either way.
                let _ = self.remove_writes_only(&id, write);
                outcome?;
                return Err(StoreError::AlreadyExists(id));
            }
        }
        // Readers that fetched the old manifest retry when its parts vanish.
        let previous = old.as_deref().and_then(|m| Self::write_of(&id, m).ok()).map(|(_, w)| w);
        if let Some(previous) = previous.filter(|&p| p != write) {
            self.remove_writes_only(&id, previous)?;
        }
        // Writes of killed earlier puts of this id, when they are surely abandoned.
        self.remove_writes(&id, Some(write), Some(DEFAULT_ORPHAN_AGE))?;
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
        let (client, prefix, context) = (self.client.clone(), self.prefix.clone(), format!("listing store {}", self.url));
        let folders = run(async move { client.list_with_delimiter(Some(&prefix)).await.map_err(remote(context)) })?;
        let mut out = Vec::new();
        for folder in folders.common_prefixes {
            let Some(id) = folder.filename().map(str::to_string) else { continue };
            if validate_id(&id).is_err() {
                continue;
            }
            match self.info(&id) {
                Ok(info) => out.push(info),
                // Deleted since the listing, or parts of a put not committed yet.
                Err(StoreError::NotFound(_)) => {}
                Err(e) => return Err(e),
            }
        }
        out.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(out)
    }

    fn info(&self, id: &str) -> Result<ObjectInfo, StoreError> {
        let manifest = self.read_manifest(id)?.ok_or_else(|| StoreError::NotFound(id.into()))?;
        self.info_from(id, &manifest)
    }

    fn delete(&self, id: &str) -> Result<(), StoreError> {
        let path = self.manifest_path(id)?;
        if self.read_manifest(id)?.is_none() {
            return Err(StoreError::NotFound(id.into()));
        }
        // The manifest first: the object disappears at once and as a whole.
        let (client, context) = (self.client.clone(), format!("deleting object {id:?}"));
        run(async move { client.delete(&path).await.map_err(remote(context)) })?;
        let keys = self.list_under(self.object_folder(id)?, format!("listing object {id:?}"))?.into_iter().map(|m| m.location).collect();
        self.delete_keys(keys, format!("removing the parts of object {id:?}"))
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

impl S3Store {
    fn head_manifest(&self, id: &str) -> Result<Option<object_store::ObjectMeta>, StoreError> {
        let (client, path, context) = (self.client.clone(), self.manifest_path(id)?, format!("looking up object {id:?}"));
        run(async move {
            match client.head(&path).await {
                Ok(m) => Ok(Some(m)),
                Err(e) if is_not_found(&e) => Ok(None),
                Err(e) => Err(remote(context)(e)),
            }
        })
    }

    /// Removes one write's parts.
    fn remove_writes_only(&self, id: &str, write: u64) -> Result<(), StoreError> {
        let keys = self.list_under(self.write_folder(id, write)?, format!("listing a write of object {id:?}"))?.into_iter().map(|m| m.location).collect();
        self.delete_keys(keys, format!("removing a write of object {id:?}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_parse_into_bucket_prefix_and_options() {
        let s = parse_url("s3://my-bucket/a/b/?endpoint=http%3A%2F%2F127.0.0.1%3A9000&allow_http=true&max_retries=1&retry_timeout_s=2.5").unwrap();
        assert_eq!((s.bucket.as_str(), s.prefix.as_str()), ("my-bucket", "a/b"));
        assert_eq!(s.options, [("endpoint".to_string(), "http://127.0.0.1:9000".to_string()), ("allow_http".to_string(), "true".to_string())]);
        assert_eq!((s.retry.max_retries, s.retry.retry_timeout), (1, Duration::from_millis(2500)));
        assert_eq!(parse_url("s3://bkt").unwrap().prefix, "");
    }

    #[test]
    fn bad_urls_say_what_is_wrong() {
        for (url, says) in [
            ("s3://", "bucket name"),
            ("s3://Upper/x", "bucket name"),
            ("s3://b/x", "bucket name"),
            ("s3://bkt/a/../b", "prefix"),
            ("s3://bkt/a//b", "prefix"),
            ("s3://bkt/x?frobnicate=1", "unknown option \"frobnicate\""),
            ("s3://bkt/x?endpoint", "KEY=VALUE"),
            ("s3://bkt/x?max_retries=many", "max_retries"),
            ("s3://bkt/x?retry_timeout_s=-1", "retry_timeout_s"),
            ("s3://bkt/x?region=%zz", "percent-encoding"),
            ("s3://bkt/x?bucket=other", "host"),
        ] {
            match parse_url(url) {
                Err(StoreError::BadUrl(m)) => assert!(m.contains(says), "{url}: {m}"),
                other => panic!("{url}: expected BadUrl, got {:?}", other.map(|s| s.bucket)),
            }
        }
    }

    #[test]
    fn secrets_are_masked_in_what_is_shown() {
        let url = "s3://bkt/p?access_key_id=AK&secret_access_key=SECRET&session_token=TOK&region=x";
        let shown = mask_secrets(url);
        assert!(!shown.contains("SECRET") && !shown.contains("TOK"), "{shown}");
        assert!(shown.contains("access_key_id=AK") && shown.contains("region=x"), "{shown}");
        match parse_url("s3://bkt/p?secret_access_key=SECRET&what=1") {
            Err(StoreError::BadUrl(m)) => assert!(!m.contains("SECRET"), "{m}"),
            _ => panic!("unknown option accepted"),
        }
    }
}
