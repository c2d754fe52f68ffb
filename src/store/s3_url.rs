//! The `s3://BUCKET[/PREFIX][?OPTIONS]` URL: bucket and prefix checked, options parsed
//! (object_store's S3 keys without `aws_`, plus `max_retries` and `retry_timeout_s`), and
//! secrets masked wherever the URL is shown.

use super::StoreError;
use object_store::aws::AmazonS3ConfigKey;
use object_store::RetryConfig;
use std::time::Duration;

/// Query keys that are secrets: accepted, never shown in `url()` or errors.
const SECRET_KEYS: [&str; 3] = ["secret_access_key", "session_token", "token"];

pub(super) struct Settings {
    pub bucket: String,
    pub prefix: String,
    /// object_store configuration keys and values, in the query's order.
    pub options: Vec<(String, String)>,
    pub retry: RetryConfig,
}

pub(super) fn parse_url(url: &str) -> Result<Settings, StoreError> {
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
        let v = crate::percent::decode(v, crate::percent::Malformed::Refuse).map_err(|_| bad(&format!("the value of {k} is not valid percent-encoding")))?;
        match k {
            "max_retries" => retry.max_retries = v.parse().map_err(|_| bad("max_retries must be a whole number"))?,
            "retry_timeout_s" => {
                retry.retry_timeout = v.parse::<f64>().ok().filter(|s| s.is_finite() && *s >= 0.0).map(Duration::from_secs_f64).ok_or_else(|| bad("retry_timeout_s must be a number of seconds"))?
            }
            "bucket" => return Err(bad("the bucket is the URL's host, not an option")),
            _ => {
                config_key(k).ok_or_else(|| bad(&format!("unknown option {k:?} (object_store's S3 keys without 'aws_', e.g. endpoint, region, allow_http; or max_retries, retry_timeout_s)")))?;
                options.push((k.to_string(), v));
            }
        }
    }
    Ok(Settings { bucket: bucket.to_string(), prefix: prefix.to_string(), options, retry })
}

pub(super) fn config_key(k: &str) -> Option<AmazonS3ConfigKey> {
    format!("aws_{k}").parse().or_else(|_| k.parse()).ok()
}

/// The URL with the values of secret query keys replaced by `***`.
pub(super) fn mask_secrets(url: &str) -> String {
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
