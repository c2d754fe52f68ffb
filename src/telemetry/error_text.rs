//! One line for an error and its causes, as `{:#}` writes them, without a cause said twice:
//! an error type that prints its source in its own message (`"{path}: {source}"`, the
//! `thiserror` habit) and also names it as its source would otherwise show the same words
//! twice ("…: No such file or directory (os error 2): No such file or directory (os error 2)").

/// The error, then each cause whose text the line does not hold yet, joined by ": ".
pub fn error_text(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.is_empty() {
            line = text;
        } else if !line.contains(&text) {
            line.push_str(": ");
            line.push_str(&text);
        }
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("{path}: {source}")]
    struct Unreadable {
        path: String,
        source: std::io::Error,
    }

    #[test]
    fn a_source_in_its_errors_own_message_is_said_once_and_other_causes_kept() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(Unreadable { path: "dets.json".into(), source: io }).context("reading the boxes");
        assert_eq!(format!("{e:#}"), "reading the boxes: dets.json: no such file: no such file");
        assert_eq!(error_text(&e), "reading the boxes: dets.json: no such file");
        let plain = anyhow::anyhow!("bad flag").context("parsing");
        assert_eq!(error_text(&plain), "parsing: bad flag");
    }
}
