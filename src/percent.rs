//! `%XX` escapes in text from outside (glTF buffer URIs, S3 store URLs' query values).

/// What to do with a `%` not followed by two hex digits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Malformed {
    /// Keep it as it is (glTF files in the wild hold such URIs).
    Keep,
    /// An error.
    Refuse,
}

/// `%XX` escapes to bytes; the result must be UTF-8.
pub fn decode(s: &str, malformed: Malformed) -> Result<String, String> {
    let (bytes, mut out) = (s.as_bytes(), Vec::with_capacity(s.len()));
    let mut i = 0;
    while i < bytes.len() {
        let hex = bytes.get(i + 1..i + 3).and_then(|h| std::str::from_utf8(h).ok()).and_then(|h| u8::from_str_radix(h, 16).ok());
        match (bytes[i], hex) {
            (b'%', Some(b)) => {
                out.push(b);
                i += 3;
            }
            (b'%', None) if malformed == Malformed::Refuse => return Err(format!("{s:?} holds a '%' that is not followed by two hex digits")),
            (b, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| format!("{s:?} is not UTF-8 once percent-decoded"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_decode_and_malformed_ones_follow_the_policy() {
        assert_eq!(decode("a%20b%2Fc", Malformed::Refuse).unwrap(), "a b/c");
        assert_eq!(decode("100%zz", Malformed::Keep).unwrap(), "100%zz");
        assert!(decode("100%zz", Malformed::Refuse).is_err());
        assert!(decode("%4", Malformed::Refuse).is_err());
        assert!(decode("%FF", Malformed::Keep).unwrap_err().contains("not UTF-8"));
    }
}
