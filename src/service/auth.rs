//! Optional API keys: with keys configured, every request but the health endpoints needs
//! `Authorization: Bearer <key>` (HTTP) or `authorization` metadata (gRPC). Keys are
//! compared through their SHA-256 digests in constant time, so neither the contents nor the
//! length of a key leaks through timing, and they are never logged.

use sha2::{Digest, Sha256};

#[derive(Clone, Default)]
pub struct ApiKeys {
    digests: Vec<[u8; 32]>,
}

/// Shows how many keys, never their digests.
impl std::fmt::Debug for ApiKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ApiKeys({} keys)", self.digests.len())
    }
}

impl ApiKeys {
    pub fn new(keys: impl IntoIterator<Item = String>) -> Self {
        Self { digests: keys.into_iter().map(|k| k.trim().to_string()).filter(|k| !k.is_empty()).map(|k| Sha256::digest(k.as_bytes()).into()).collect() }
    }

    /// Keys from a file (one per line, `#` comments) and/or a comma-separated list.
    pub fn load(file: Option<&std::path::Path>, list: Option<&str>) -> Result<Self, String> {
        let mut keys: Vec<String> = Vec::new();
        if let Some(f) = file {
            let text = std::fs::read_to_string(f).map_err(|e| format!("API key file {}: {e}", f.display()))?;
            keys.extend(text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).map(String::from));
        }
        if let Some(l) = list {
            keys.extend(l.split(',').map(|k| k.trim().to_string()));
        }
        Ok(Self::new(keys))
    }

    pub fn enabled(&self) -> bool {
        !self.digests.is_empty()
    }

    pub fn len(&self) -> usize {
        self.digests.len()
    }

    pub fn is_empty(&self) -> bool {
        self.digests.is_empty()
    }

    /// Whether an `Authorization` header value (`Bearer <key>`) carries a known key.
    pub fn accepts_header(&self, value: Option<&str>) -> bool {
        let Some(key) = value.and_then(|v| v.strip_prefix("Bearer ").or_else(|| v.strip_prefix("bearer "))) else {
            return false;
        };
        let d: [u8; 32] = Sha256::digest(key.trim().as_bytes()).into();
        // Every stored key is compared, each in constant time.
        self.digests.iter().fold(false, |found, k| found | (k.iter().zip(&d).fold(0u8, |acc, (a, b)| acc | (a ^ b)) == 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accepts_only_known_bearer_keys() {
        let keys = ApiKeys::new(["alpha".to_string(), " beta ".to_string(), String::new()]);
        assert_eq!(keys.len(), 2);
        assert!(keys.accepts_header(Some("Bearer alpha")) && keys.accepts_header(Some("Bearer beta")));
        assert!(!keys.accepts_header(Some("Bearer alph")) && !keys.accepts_header(Some("alpha")) && !keys.accepts_header(None));
        assert!(!ApiKeys::default().enabled());
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("keys");
        std::fs::write(&f, "# ops\nk1\n\nk2\n").unwrap();
        let keys = ApiKeys::load(Some(&f), Some("k3")).unwrap();
        assert_eq!(keys.len(), 3);
        assert!(ApiKeys::load(Some(&dir.path().join("none")), None).unwrap_err().contains("none"));
    }
}
