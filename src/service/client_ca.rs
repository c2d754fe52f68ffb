//! mTLS: the CA certificates (`--tls-client-ca`, PEM) that client certificates must chain
//! to. Each one is checked at start to be a CA (basicConstraints cA=TRUE), so a server or
//! client certificate given by mistake is refused with a clear message rather than becoming
//! a trust anchor that no client certificate chains to. The check reads just enough DER.

use rustls_pki_types::pem::PemObject;
use rustls_pki_types::CertificateDer;
use std::path::Path;

/// Reads and checks the CA file, naming it and the certificate that is wrong.
pub fn load(path: &Path) -> Result<Vec<u8>, String> {
    let pem = std::fs::read(path).map_err(|e| format!("TLS client CA {}: {e}", path.display()))?;
    certificates(&pem).map_err(|e| format!("TLS client CA {}: {e}", path.display()))?;
    Ok(pem)
}

/// The CA certificates of a PEM, each checked to be a CA.
pub fn certificates(pem: &[u8]) -> Result<Vec<CertificateDer<'static>>, String> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(pem).collect::<Result<_, _>>().map_err(|e| format!("not a PEM file of certificates: {e}"))?;
    if certs.is_empty() {
        return Err("no certificate in it (expected the PEM of one or more CA certificates)".into());
    }
    for (i, c) in certs.iter().enumerate() {
        match is_ca(c) {
            Some(true) => {}
            Some(false) => return Err(format!("certificate {} is not a CA certificate (no basicConstraints with cA=TRUE): give the CA that issued the client certificates", i + 1)),
            None => return Err(format!("certificate {} cannot be read as X.509", i + 1)),
        }
    }
    Ok(certs)
}

/// One DER element: (tag, contents, what follows).
fn tlv(input: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&tag, rest) = input.split_first()?;
    let (&first, rest) = rest.split_first()?;
    let (len, rest) = if first < 0x80 {
        (first as usize, rest)
    } else {
        let n = (first & 0x7f) as usize;
        if n == 0 || n > 4 || rest.len() < n {
            return None;
        }
        (rest[..n].iter().fold(0usize, |acc, b| acc << 8 | *b as usize), &rest[n..])
    };
    (rest.len() >= len).then(|| (tag, &rest[..len], &rest[len..]))
}

/// Whether the certificate's basicConstraints says cA=TRUE; `None`: not readable.
fn is_ca(der: &[u8]) -> Option<bool> {
    const SEQUENCE: u8 = 0x30;
    const EXTENSIONS: u8 = 0xa3; // [3] EXPLICIT in TBSCertificate
    const BASIC_CONSTRAINTS: &[u8] = &[0x55, 0x1d, 0x13]; // 2.5.29.19
    let (SEQUENCE, cert, _) = tlv(der)? else { return None };
    let (SEQUENCE, mut tbs, _) = tlv(cert)? else { return None };
    while !tbs.is_empty() {
        let (tag, body, rest) = tlv(tbs)?;
        tbs = rest;
        if tag != EXTENSIONS {
            continue;
        }
        let (SEQUENCE, mut exts, _) = tlv(body)? else { return None };
        while !exts.is_empty() {
            let (_, ext, rest) = tlv(exts)?;
            exts = rest;
            let (0x06, oid, mut fields) = tlv(ext)? else { return None };
            if oid != BASIC_CONSTRAINTS {
                continue;
            }
            // critical BOOLEAN DEFAULT FALSE, then the OCTET STRING holding the value.
            let (mut tag, mut value, after) = tlv(fields)?;
            if tag == 0x01 {
                fields = after;
                (tag, value, _) = tlv(fields)?;
            }
            if tag != 0x04 {
                return None;
            }
            // BasicConstraints ::= SEQUENCE { cA BOOLEAN DEFAULT FALSE, pathLen INTEGER OPTIONAL }
            let (SEQUENCE, bc, _) = tlv(value)? else { return None };
            return Some(matches!(tlv(bc), Some((0x01, [v], _)) if *v != 0));
        }
    }
    // No extensions or no basicConstraints: not a CA (X.509 v3 requires it for CAs).
    Some(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tells_ca_certificates_from_others() {
        let ca_key = rcgen::KeyPair::generate().unwrap();
        let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Constrained(0));
        let ca = params.self_signed(&ca_key).unwrap();
        let leaf = rcgen::CertificateParams::new(vec!["localhost".to_string()]).unwrap().self_signed(&rcgen::KeyPair::generate().unwrap()).unwrap();
        let mut explicit = rcgen::CertificateParams::new(vec!["x".to_string()]).unwrap();
        explicit.is_ca = rcgen::IsCa::ExplicitNoCa;
        let explicit = explicit.self_signed(&rcgen::KeyPair::generate().unwrap()).unwrap();
        assert_eq!(is_ca(ca.der()), Some(true));
        assert_eq!(is_ca(leaf.der()), Some(false));
        assert_eq!(is_ca(explicit.der()), Some(false));
        assert_eq!(is_ca(&ca.der()[..40]), None);
        assert_eq!(certificates(ca.pem().as_bytes()).unwrap().len(), 1);
        let two = format!("{}{}", ca.pem(), leaf.pem());
        assert!(certificates(two.as_bytes()).unwrap_err().contains("certificate 2 is not a CA"));
        assert!(certificates(ca_key.serialize_pem().as_bytes()).unwrap_err().contains("no certificate"));
        assert!(certificates(b"hello").unwrap_err().contains("no certificate"));
        let dir = tempfile::tempdir().unwrap();
        assert!(load(&dir.path().join("missing.pem")).unwrap_err().contains("missing.pem"));
    }
}
