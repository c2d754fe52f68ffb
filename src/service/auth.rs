//! Optional API keys: with keys configured, every request but the health endpoints needs
//! `Authorization: Bearer <key>` (HTTP) or `authorization` metadata (gRPC), and a key
//! with the scope the endpoint needs (scopes.rs). Keys are compared through their SHA-256
//! digests in constant time, so neither the contents nor the length of a key leaks through
//! timing, and they are never logged: logs and metrics name a key by its identity, the
//! `name=` it was given or `key-` and the first 8 hex digits of its digest.
//!
//! The key file: one key per line, `#` comments (whole lines, or after the key and its
//! attributes), blank lines ignored; after the key, optional attributes separated by
//! spaces:
//!
//! ```text
//! # a bare key: every scope (what every key meant before scopes)
//! 7f3a…
//! # an estimating client, and an onboarding job
//! 91bc… scopes=read name=cell-7
//! 0d2e… scopes=read,write name=onboarder
//! 55aa… scopes=admin name=prometheus
//! ```
//!
//! Keys cannot contain spaces. Keys given as a comma list (`--api-keys`) are bare: every
//! scope.

use super::scopes::Scopes;
use sha2::{Digest, Sha256};
use std::sync::Arc;

/// Who a request comes from, once its key is known: the non-secret identity and the scopes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    pub identity: Arc<str>,
    pub scopes: Scopes,
}

#[derive(Clone)]
struct Entry {
    digest: [u8; 32],
    caller: Caller,
    /// Where it was given ("line 4", "--api-keys"), for the duplicate error.
    origin: String,
}

#[derive(Clone, Default)]
pub struct ApiKeys {
    entries: Arc<Vec<Entry>>,
}

/// Shows how many keys and their identities, never the keys or their digests.
impl std::fmt::Debug for ApiKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ids: Vec<String> = self.entries.iter().map(|e| format!("{} ({:?})", e.caller.identity, e.caller.scopes)).collect();
        write!(f, "ApiKeys({} keys: {})", ids.len(), ids.join(", "))
    }
}

fn valid_name(n: &str) -> bool {
    (1..=64).contains(&n.len()) && n.bytes().all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
}

/// One key line (already trimmed, not a comment): the key and its caller. Errors never
/// quote the key.
fn parse_line(line: &str) -> Result<(String, Option<Scopes>, Option<String>), String> {
    let mut words = line.split_whitespace();
    let key = words.next().unwrap_or_default().to_string();
    let (mut scopes, mut name) = (None, None);
    for w in words.take_while(|w| !w.starts_with('#')) {
        match w.split_once('=') {
            Some(("scopes", v)) if scopes.is_none() => scopes = Some(Scopes::parse(v)?),
            Some(("name", v)) if name.is_none() => {
                if !valid_name(v) {
                    return Err(format!("name {v:?} must be 1 to 64 characters of A-Z a-z 0-9 - _ ."));
                }
                name = Some(v.to_string());
            }
            Some((a @ ("scopes" | "name"), _)) => return Err(format!("{a}= given twice")),
            Some((a, _)) if !a.is_empty() && a.bytes().all(|b| b.is_ascii_lowercase()) => return Err(format!("unknown attribute {a:?} (attributes: scopes=, name=)")),
            _ => return Err("text after the key that is not an attribute (scopes=…, name=…); keys cannot contain spaces".into()),
        }
    }
    Ok((key, scopes, name))
}

impl ApiKeys {
    /// Bare keys, each with every scope.
    pub fn new(keys: impl IntoIterator<Item = String>) -> Self {
        let mut b = Builder::default();
        for k in keys {
            let _ = b.add(k.trim(), Scopes::all(), None, "a key".into());
        }
        b.done()
    }

    /// Keys from a file (format in the module doc) and/or a comma-separated list of bare
    /// keys. A bad line is refused with its number.
    pub fn load(file: Option<&std::path::Path>, list: Option<&str>) -> Result<Self, String> {
        let mut b = Builder::default();
        if let Some(f) = file {
            let text = std::fs::read_to_string(f).map_err(|e| format!("API key file {}: {e}", f.display()))?;
            for (i, line) in text.lines().enumerate() {
                let line = line.trim();
                if line.is_empty() || line.starts_with('#') {
                    continue;
                }
                let at = |e: String| format!("API key file {} line {}: {e}", f.display(), i + 1);
                let (key, scopes, name) = parse_line(line).map_err(at)?;
                b.add(&key, scopes.unwrap_or_else(Scopes::all), name, format!("line {}", i + 1)).map_err(at)?;
            }
        }
        if let Some(l) = list {
            for k in l.split(',') {
                b.add(k.trim(), Scopes::all(), None, "--api-keys".into()).map_err(|e| format!("--api-keys: {e}"))?;
            }
        }
        Ok(b.done())
    }

    pub fn enabled(&self) -> bool {
        !self.entries.is_empty()
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The caller whose key an `Authorization` header value (`Bearer <key>`) carries.
    pub fn authenticate(&self, value: Option<&str>) -> Option<Caller> {
        let key = value.and_then(|v| v.strip_prefix("Bearer ").or_else(|| v.strip_prefix("bearer ")))?;
        let d: [u8; 32] = Sha256::digest(key.trim().as_bytes()).into();
        // Every stored key is compared, each in constant time, whichever matches.
        let mut found = None;
        for e in self.entries.iter() {
            let equal = e.digest.iter().zip(&d).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0;
            found = if equal { Some(e) } else { found };
        }
        found.map(|e| e.caller.clone())
    }
}

#[derive(Default)]
struct Builder {
    entries: Vec<Entry>,
}

impl Builder {
    /// Adds one key; an empty one is skipped, the same key again with the same scopes and
    /// name is kept once, with others it is refused.
    fn add(&mut self, key: &str, scopes: Scopes, name: Option<String>, origin: String) -> Result<(), String> {
        if key.is_empty() {
            return Ok(());
        }
        let digest: [u8; 32] = Sha256::digest(key.as_bytes()).into();
        let identity: Arc<str> = name.unwrap_or_else(|| format!("key-{}", digest[..4].iter().map(|b| format!("{b:02x}")).collect::<String>())).into();
        let caller = Caller { identity, scopes };
        if let Some(seen) = self.entries.iter().find(|e| e.digest == digest) {
            if seen.caller == caller {
                return Ok(());
            }
            return Err(format!("the same key as {} with other scopes or name", seen.origin));
        }
        self.entries.push(Entry { digest, caller, origin });
        Ok(())
    }

    fn done(self) -> ApiKeys {
        ApiKeys { entries: Arc::new(self.entries) }
    }
}

#[cfg(test)]
mod tests {
    use super::super::scopes::Scope;
    use super::*;

    #[test]
    fn accepts_only_known_bearer_keys() {
        let keys = ApiKeys::new(["alpha".to_string(), " beta ".to_string(), String::new()]);
        assert_eq!(keys.len(), 2);
        let a = keys.authenticate(Some("Bearer alpha")).unwrap();
        assert_eq!(a.scopes, Scopes::all());
        assert!(a.identity.starts_with("key-") && a.identity.len() == 12, "{}", a.identity);
        assert!(keys.authenticate(Some("Bearer beta")).is_some());
        assert!(keys.authenticate(Some("Bearer alph")).is_none() && keys.authenticate(Some("alpha")).is_none() && keys.authenticate(None).is_none());
        assert!(!ApiKeys::default().enabled());
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("keys");
        std::fs::write(&f, "# ops\nk1\n\nk2\n").unwrap();
        let keys = ApiKeys::load(Some(&f), Some("k3")).unwrap();
        assert_eq!(keys.len(), 3);
        assert!(ApiKeys::load(Some(&dir.path().join("none")), None).unwrap_err().contains("none"));
    }

    #[test]
    fn key_lines_with_scopes_and_names() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("keys");
        std::fs::write(&f, "bare\n  reader   scopes=read name=cell-7  # the camera cell\nwriter scopes=write,read #\nbare\n").unwrap();
        let keys = ApiKeys::load(Some(&f), Some("bare")).unwrap();
        assert_eq!(keys.len(), 3);
        let r = keys.authenticate(Some("Bearer reader")).unwrap();
        assert_eq!((&*r.identity, r.scopes), ("cell-7", Scopes::parse("read").unwrap()));
        let w = keys.authenticate(Some("Bearer writer")).unwrap();
        assert!(w.scopes.has(Scope::Write) && w.scopes.has(Scope::Read) && !w.scopes.has(Scope::Admin));
        assert_eq!(keys.authenticate(Some("Bearer bare")).unwrap().scopes, Scopes::all());
        // Identities show in Debug; keys never do.
        let shown = format!("{keys:?}");
        assert!(shown.contains("cell-7 (read)") && !shown.contains("reader") && !shown.contains("writer"), "{shown}");
    }

    #[test]
    fn bad_key_lines_are_refused_with_their_number_and_without_the_key() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("keys");
        let err = |text: &str| {
            std::fs::write(&f, text).unwrap();
            ApiKeys::load(Some(&f), None).unwrap_err()
        };
        for (text, line, says) in [
            ("ok\nsecret1 scopes=read,delete\n", 2, "\"delete\""),
            ("# c\n\nsecret1 scopes=\n", 3, "no scope"),
            ("secret1 scope=read\n", 1, "unknown attribute \"scope\""),
            ("secret1 two words\n", 1, "cannot contain spaces"),
            ("secret1 name=a/b\n", 1, "name \"a/b\""),
            ("secret1 name=a name=b\n", 1, "twice"),
            ("secret1 scopes=read\nx\nsecret1 scopes=write\n", 3, "as line 1"),
        ] {
            let e = err(text);
            assert!(e.contains(&format!("line {line}:")) && e.contains(says), "{text:?}: {e}");
            assert!(!e.contains("secret1"), "{e}");
        }
        std::fs::write(&f, "k scopes=read\n").unwrap();
        assert!(ApiKeys::load(Some(&f), Some("k")).unwrap_err().contains("--api-keys"));
    }
}
