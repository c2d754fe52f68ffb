//! Pose estimates in the BOP results CSV format (BOP'19 onwards,
//! `bop_toolkit_lib/inout.py`, `load_bop_results` / `save_bop_results`):
//!
//! ```text
//! scene_id,im_id,obj_id,score,R,t,time
//! 48,1,2,0.9,r11 r12 r13 r21 r22 r23 r31 r32 r33,tx ty tz,0.25
//! ```
//!
//! `R` is row-major, `t` is in **millimetres** (our [`Pose`] is in metres),
//! `time` is in seconds, -1 meaning unknown. Floats are printed with Rust's
//! shortest round-trip `Display`, so R and t read back exactly (t up to the
//! ×1000 / ÷1000 unit change).
//!
//! Long runs append one image at a time through [`ResultsWriter`], so that a
//! killed run can resume: [`done_images`] tells which images are in the file.
//!
//! `R` is kept as written, as the toolkit scores it (see `rotation.rs`): results made
//! from real ground truth are orthonormal only to about 10⁻², and only matrices that
//! are no rotation at all are refused.

use std::collections::BTreeSet;
use std::fs::{self, File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::rotation::{check_rotation, pose_as_given, LooseRotations};
use crate::geometry::Pose;

pub const HEADER: &str = "scene_id,im_id,obj_id,score,R,t,time";

const MM_PER_M: f64 = 1000.0;

#[derive(Debug, thiserror::Error)]
pub enum ResultsError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: line 1: expected the header {HEADER:?}, found {found:?}", path.display())]
    Header { path: PathBuf, found: String },
    /// A line of the file (1-based, the header is line 1).
    #[error("{}: line {line}: {reason}", path.display())]
    Line { path: PathBuf, line: usize, reason: String },
    /// A row given to a writer (0-based index in the slice).
    #[error("{}: row {index} to write: {reason}", path.display())]
    Row { path: PathBuf, index: usize, reason: String },
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> ResultsError + '_ {
    move |source| ResultsError::Io { path: path.to_path_buf(), source }
}

/// One pose estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct ResultRow {
    pub scene_id: u32,
    pub im_id: u32,
    pub obj_id: u32,
    pub score: f64,
    /// Object → camera; translation in metres. Read from a file, the rotation is the
    /// file's matrix unchanged.
    pub pose: Pose,
    /// Seconds for the whole image, or -1 when unknown.
    pub time: f64,
}

impl ResultRow {
    fn image(&self) -> (u32, u32) {
        (self.scene_id, self.im_id)
    }
}

/// Reads a results file. Lines may end in CRLF, fields may carry spaces and
/// the final newline is optional. A last line cut short by a killed writer
/// is an error here; [`ResultsWriter::open`] repairs such a file. Rotations
/// that are rotations only roughly are accepted and summed up in one line
/// added to `warnings`.
pub fn read_results(path: &Path, warnings: &mut Vec<String>) -> Result<Vec<ResultRow>, ResultsError> {
    parse_results(path, &fs::read_to_string(path).map_err(io_error(path))?, warnings)
}

/// Parses the text of a results file; `path` names it in errors and warnings.
pub fn parse_results(path: &Path, text: &str, warnings: &mut Vec<String>) -> Result<Vec<ResultRow>, ResultsError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut lines: Vec<&str> = text.split('\n').collect();
    let unterminated_last = !text.ends_with('\n');
    if !unterminated_last {
        lines.pop(); // the empty string after the final '\n'
    }
    let header = lines.first().map_or("", |l| l.trim());
    if header != HEADER {
        return Err(ResultsError::Header { path: path.into(), found: header.into() });
    }
    let body_len = lines.len() - 1;
    let mut loose = LooseRotations::default();
    let rows = lines
        .iter()
        .enumerate()
        .skip(1)
        .map(|(i, line)| {
            let (row, deviation) = parse_row(line).map_err(|mut reason| {
                if unterminated_last && i == body_len {
                    reason.push_str(
                        " (the last line has no newline: probably cut short by a killed run; \
                         ResultsWriter::open repairs the file)",
                    );
                }
                ResultsError::Line { path: path.into(), line: i + 1, reason }
            })?;
            loose.note(deviation, || format!("line {}", i + 1));
            Ok(row)
        })
        .collect::<Result<_, _>>()?;
    warnings.extend(loose.warning(path, "R"));
    Ok(rows)
}

/// `(scene_id, im_id)` of every image with at least one row; empty when the
/// file does not exist yet. Call after [`ResultsWriter::open`], which
/// repairs a torn last line that this would report as an error. Only which
/// images are there matters here, so rough rotations go unremarked.
pub fn done_images(path: &Path) -> Result<BTreeSet<(u32, u32)>, ResultsError> {
    if !path.exists() {
        return Ok(BTreeSet::new());
    }
    Ok(read_results(path, &mut Vec::new())?.iter().map(ResultRow::image).collect())
}

/// Writes the whole file to `<path>.tmp`, then renames it over `path`, so
/// readers never see half a file.
pub fn write_results(path: &Path, rows: &[ResultRow]) -> Result<(), ResultsError> {
    let mut text = format!("{HEADER}\n");
    text.push_str(&format_rows(path, rows)?);
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    fs::write(&tmp, text).map_err(io_error(&tmp))?;
    fs::rename(&tmp, path).map_err(io_error(path))
}

/// Appends results image by image to a file that survives being killed.
///
/// Each [`ResultsWriter::append_image`] issues one write for all rows of one
/// image, so an interrupted run normally leaves whole images; if it leaves a
/// torn (newline-less) last line, [`ResultsWriter::open`] repairs it.
#[derive(Debug)]
pub struct ResultsWriter {
    path: PathBuf,
    file: File,
}

impl ResultsWriter {
    /// Creates the file with its header, or opens an existing one after
    /// checking its header. If the file does not end in '\n' the last write
    /// was cut short: the torn line is removed together with the trailing
    /// rows of the last complete line's image, because they may be the
    /// first rows of the same, unfinished image (this may drop one complete
    /// image, which the caller then simply recomputes).
    pub fn open(path: &Path) -> Result<ResultsWriter, ResultsError> {
        let mut file = OpenOptions::new().read(true).append(true).create(true).open(path).map_err(io_error(path))?;
        let mut content = Vec::new();
        file.read_to_end(&mut content).map_err(io_error(path))?;
        let keep = repaired_length(path, &content)?;
        if keep < content.len() {
            file.set_len(keep as u64).map_err(io_error(path))?;
            file.seek(SeekFrom::End(0)).map_err(io_error(path))?;
        }
        if keep == 0 {
            file.write_all(format!("{HEADER}\n").as_bytes()).map_err(io_error(path))?;
        } else if content[keep - 1] != b'\n' {
            // A complete header without its newline.
            file.write_all(b"\n").map_err(io_error(path))?;
        }
        file.flush().map_err(io_error(path))?;
        Ok(ResultsWriter { path: path.to_path_buf(), file })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends all rows of one image in a single write. Rows of different
    /// images are refused: the repair in [`ResultsWriter::open`] relies on
    /// an image's rows being contiguous. No rows, nothing written.
    pub fn append_image(&mut self, rows: &[ResultRow]) -> Result<(), ResultsError> {
        let Some(first) = rows.first() else { return Ok(()) };
        if let Some((index, other)) = rows.iter().enumerate().find(|(_, r)| r.image() != first.image()) {
            return Err(ResultsError::Row {
                path: self.path.clone(),
                index,
                reason: format!("image (scene {}, im {}) differs from row 0's (scene {}, im {}); append one image at a time", other.scene_id, other.im_id, first.scene_id, first.im_id),
            });
        }
        let text = format_rows(&self.path, rows)?;
        self.file.write_all(text.as_bytes()).map_err(io_error(&self.path))?;
        self.file.flush().map_err(io_error(&self.path))
    }
}

/// How many bytes of an existing file to keep (see [`ResultsWriter::open`]).
fn repaired_length(path: &Path, content: &[u8]) -> Result<usize, ResultsError> {
    let header_end = content.iter().position(|&b| b == b'\n');
    let first_line = String::from_utf8_lossy(&content[..header_end.unwrap_or(content.len())]);
    let first_line = first_line.trim_start_matches('\u{feff}').trim();
    match header_end {
        // Empty file, or a header cut short while being written.
        None if HEADER.starts_with(first_line) && first_line != HEADER => return Ok(0),
        _ if first_line != HEADER => {
            return Err(ResultsError::Header { path: path.into(), found: first_line.into() });
        }
        None => return Ok(content.len()),
        Some(_) if content.ends_with(b"\n") => return Ok(content.len()),
        Some(_) => {}
    }
    // Torn last line: keep up to the last newline, then drop the trailing
    // block of rows sharing the last complete row's image.
    let complete_end = content.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    let mut lines: Vec<&[u8]> = content[..complete_end].split_inclusive(|&b| b == b'\n').collect();
    if let Some(image) = lines.last().and_then(|l| image_key(l)) {
        // The header never parses as an image key, so it is never dropped.
        while lines.last().and_then(|l| image_key(l)) == Some(image) {
            lines.pop();
        }
    }
    Ok(lines.iter().map(|l| l.len()).sum())
}

/// `(scene_id, im_id)` from the first two fields of a row, if they parse.
fn image_key(line: &[u8]) -> Option<(u32, u32)> {
    let line = String::from_utf8_lossy(line);
    let mut fields = line.split(',');
    let scene = fields.next()?.trim().parse().ok()?;
    let image = fields.next()?.trim().parse().ok()?;
    Some((scene, image))
}

/// Formats rows as CSV lines, checking that each reads back (non-finite
/// numbers, a time other than ≥ 0 or -1, an invalid rotation are refused).
fn format_rows(path: &Path, rows: &[ResultRow]) -> Result<String, ResultsError> {
    let mut text = String::new();
    for (index, row) in rows.iter().enumerate() {
        let line = format_row(row);
        parse_row(&line).map_err(|reason| ResultsError::Row { path: path.into(), index, reason })?;
        text.push_str(&line);
        text.push('\n');
    }
    Ok(text)
}

fn format_row(row: &ResultRow) -> String {
    let join = |values: &[f64]| values.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(" ");
    let t_mm: Vec<f64> = row.pose.translation.iter().map(|v| v * MM_PER_M).collect();
    format!("{},{},{},{},{},{},{}", row.scene_id, row.im_id, row.obj_id, row.score, join(&row.pose.rotation_row_major()), join(&t_mm), row.time)
}

/// Parses one data line, with how far its R is from a rotation; the error names
/// the field.
fn parse_row(line: &str) -> Result<(ResultRow, f64), String> {
    if line.trim().is_empty() {
        return Err("empty line".into());
    }
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    let [scene_id, im_id, obj_id, score, r, t, time] = fields[..] else {
        return Err(format!("expected 7 comma-separated fields ({HEADER}), got {}", fields.len()));
    };
    // Parsed in column order so that the first bad field is the one reported.
    let scene_id = parse_id("scene_id", scene_id)?;
    let im_id = parse_id("im_id", im_id)?;
    let obj_id = parse_id("obj_id", obj_id)?;
    let score = parse_float("score", score)?;
    let r: [f64; 9] = parse_floats("R", r)?;
    let deviation = check_rotation("R", &r)?;
    let t_mm: [f64; 3] = parse_floats("t", t)?;
    let time = parse_float("time", time)?;
    if time < 0.0 && time != -1.0 {
        return Err(format!("time: expected seconds ≥ 0, or -1 for unknown, got {time}"));
    }
    let pose = pose_as_given(&r, t_mm.map(|v| v / MM_PER_M));
    Ok((ResultRow { scene_id, im_id, obj_id, score, pose, time }, deviation))
}

fn parse_id(field: &str, text: &str) -> Result<u32, String> {
    text.parse().map_err(|_| format!("{field}: expected an integer in 0..=4294967295, got {text:?}"))
}

fn parse_float(field: &str, text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(format!("{field}: expected a finite number, got {text:?}")),
    }
}

fn parse_floats<const N: usize>(field: &str, text: &str) -> Result<[f64; N], String> {
    let items: Vec<&str> = text.split_whitespace().collect();
    if items.len() != N {
        return Err(format!("{field}: expected {N} values, got {}", items.len()));
    }
    let mut out = [0.0; N];
    for (i, (slot, item)) in out.iter_mut().zip(&items).enumerate() {
        *slot = parse_float(&format!("{field}: value {}", i + 1), item)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    fn row(scene_id: u32, im_id: u32, obj_id: u32, angle: f64) -> ResultRow {
        let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
        ResultRow {
            scene_id,
            im_id,
            obj_id,
            score: 0.123456789012345,
            pose: Pose::new(Rotation3::from_scaled_axis(axis * angle), Vector3::new(0.0123456789, -0.987654321, 1.000000001 * angle)),
            time: 1.5,
        }
    }

    const ROW_TEXT: &str = "1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,0.25";

    fn write_file(dir: &tempfile::TempDir, text: &str) -> PathBuf {
        let path = dir.path().join("results.csv");
        fs::write(&path, text).unwrap();
        path
    }

    fn read_error(text: &str) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(&dir, text);
        let err = read_results(&path, &mut Vec::new()).unwrap_err().to_string();
        assert!(err.starts_with(&path.display().to_string()), "error does not name the file: {err}");
        err
    }

    fn assert_close(a: &ResultRow, b: &ResultRow) {
        assert_eq!((a.scene_id, a.im_id, a.obj_id, a.score, a.time), (b.scene_id, b.im_id, b.obj_id, b.score, b.time));
        for (x, y) in a.pose.rotation_row_major().iter().zip(b.pose.rotation_row_major()) {
            assert!((x - y).abs() <= 1e-12, "R {x} vs {y}");
        }
        for (x, y) in a.pose.translation.iter().zip(b.pose.translation.iter()) {
            assert!((x - y).abs() <= 1e-12 * x.abs().max(1e-3), "t {x} vs {y}");
        }
    }

    #[test]
    fn write_then_read_round_trips() {
        let rows: Vec<ResultRow> = (0..20).map(|i| row(i / 5, i, i % 3 + 1, 0.37 * i as f64)).collect();
        let mut unknown_time = row(9, 9, 9, 3.0);
        unknown_time.time = -1.0;
        let rows = [rows, vec![unknown_time]].concat();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.csv");
        write_results(&path, &rows).unwrap();
        assert!(!dir.path().join("results.csv.tmp").exists());
        let text = fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("scene_id,im_id,obj_id,score,R,t,time\n"));
        let back = read_results(&path, &mut Vec::new()).unwrap();
        assert_eq!(back.len(), rows.len());
        for (a, b) in rows.iter().zip(&back) {
            assert_close(a, b);
        }
        assert_eq!(back[20].time, -1.0);
    }

    #[test]
    fn translation_is_written_in_millimetres() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.csv");
        let r = ResultRow { scene_id: 48, im_id: 1, obj_id: 2, score: 0.5, pose: Pose::new(Rotation3::identity(), Vector3::new(0.1, -0.25, 1.5)), time: 0.25 };
        write_results(&path, &[r]).unwrap();
        let text = fs::read_to_string(&path).unwrap();
        assert_eq!(text, "scene_id,im_id,obj_id,score,R,t,time\n48,1,2,0.5,1 0 0 0 1 0 0 0 1,100 -250 1500,0.25\n");
    }

    #[test]
    fn accepts_crlf_spaces_bom_and_missing_final_newline() {
        let dir = tempfile::tempdir().unwrap();
        let text = "\u{feff}scene_id,im_id,obj_id,score,R,t,time\r\n 1 , 2 ,3, 0.5 , 1 0 0  0 1 0 0 0 1 ,10 20 30 , 0.25 \r\n1,2,4,0.5,1 0 0 0 1 0 0 0 1,10 20 30,-1";
        let rows = read_results(&write_file(&dir, text), &mut Vec::new()).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!((rows[0].scene_id, rows[0].im_id, rows[0].obj_id), (1, 2, 3));
        assert_eq!(rows[0].pose.translation, Vector3::new(0.01, 0.02, 0.03));
        assert_eq!(rows[1].time, -1.0);
    }

    /// LM-O's ground truth as the toolkit's tests ship it in a results file
    /// (`gt-pbrreal-rgb-mmodel_lmo-test_lmo.csv`): its determinant is 1.0137.
    const LMO_ROW: &str = "2,804,5,1.0,-0.4265835 -0.90545594 0.08228724 -0.2176405 0.01298762 -0.98068271 0.88320192 -0.43448076 -0.20156121,48.26725767 4.67927793 1202.38701337,1.0";

    #[test]
    fn rough_rotations_are_kept_as_written_with_one_warning() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!("{HEADER}\n{ROW_TEXT}\n{LMO_ROW}\n1,2,3,0.5,1.0002 0 0 0 0.9999 0 0 0 1,0 0 0,1\n");
        let path = write_file(&dir, &text);
        let mut warnings = Vec::new();
        let rows = read_results(&path, &mut warnings).unwrap();
        let lmo = [-0.4265835, -0.90545594, 0.08228724, -0.2176405, 0.01298762, -0.98068271, 0.88320192, -0.43448076, -0.20156121];
        assert_eq!(rows[1].pose.rotation_row_major(), lmo);
        assert_eq!(rows[2].pose.rotation_row_major(), [1.0002, 0.0, 0.0, 0.0, 0.9999, 0.0, 0.0, 0.0, 1.0]);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let w = &warnings[0];
        assert!(w.starts_with(&path.display().to_string()) && w.contains("2 of 3 R matrices") && w.contains("1.4e-2 (line 3)"), "{w}");
        // `bop run` resumes from such a file too.
        assert_eq!(done_images(&path).unwrap(), BTreeSet::from([(1, 2), (2, 804)]));
        // The identity alone is not worth a word.
        warnings.clear();
        read_results(&write_file(&dir, &format!("{HEADER}\n{ROW_TEXT}\n")), &mut warnings).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
    }

    #[test]
    fn header_errors() {
        assert!(read_error("").contains("line 1: expected the header"));
        assert!(read_error("scene_id,im_id,obj_id,score,R,t\n").contains("found \"scene_id,im_id,obj_id,score,R,t\""));
        assert!(read_error(&format!("{ROW_TEXT}\n")).contains("line 1: expected the header"));
    }

    #[test]
    fn line_errors_name_line_and_field() {
        let cases = [
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30", "expected 7 comma-separated fields"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,0.25,7", "expected 7 comma-separated fields (scene_id,im_id,obj_id,score,R,t,time), got 8"),
            ("-1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,0.25", "scene_id: expected an integer"),
            ("1,x,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,0.25", "im_id: expected an integer"),
            ("1,2,3.0,0.5,1 0 0 0 1 0 0 0 1,10 20 30,0.25", "obj_id: expected an integer"),
            ("1,2,3,NaN,1 0 0 0 1 0 0 0 1,10 20 30,0.25", "score: expected a finite number, got \"NaN\""),
            ("1,2,3,,1 0 0 0 1 0 0 0 1,10 20 30,0.25", "score: expected a finite number"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0,10 20 30,0.25", "R: expected 9 values, got 8"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1 0,10 20 30,0.25", "R: expected 9 values, got 10"),
            ("1,2,3,0.5,1 0 0 0 one 0 0 0 1,10 20 30,0.25", "R: value 5: expected a finite number, got \"one\""),
            ("1,2,3,0.5,1 0 0 0 inf 0 0 0 1,10 20 30,0.25", "R: value 5: expected a finite number"),
            ("1,2,3,0.5,2 0 0 0 1 0 0 0 1,10 20 30,0.25", "R: not a rotation: determinant is 2"),
            ("1,2,3,0.5,1 0 0 0 -1 0 0 0 1,10 20 30,0.25", "R: not a rotation: determinant is -1"),
            ("1,2,3,0.5,1 0.5 0 0 1 0 0 0 1,10 20 30,0.25", "R: not a rotation: R·Rᵀ differs"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20,0.25", "t: expected 3 values, got 2"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 1e999,0.25", "t: value 3: expected a finite number"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,soon", "time: expected a finite number"),
            ("1,2,3,0.5,1 0 0 0 1 0 0 0 1,10 20 30,-2", "time: expected seconds ≥ 0, or -1 for unknown"),
            ("", "empty line"),
        ];
        for (bad, expected) in cases {
            let err = read_error(&format!("{HEADER}\n{ROW_TEXT}\n{bad}\n{ROW_TEXT}\n"));
            assert!(err.contains(&format!("line 3: {expected}")), "{bad:?}: got {err:?}, wanted {expected:?}");
        }
    }

    #[test]
    fn torn_last_line_is_an_error_that_mentions_the_repair() {
        let err = read_error(&format!("{HEADER}\n{ROW_TEXT}\n1,2,4,0.5,1 0 0 0"));
        assert!(err.contains("line 3: expected 7 comma-separated fields"), "{err}");
        assert!(err.contains("ResultsWriter::open repairs"), "{err}");
    }

    #[test]
    fn writer_creates_appends_and_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.csv");
        assert!(done_images(&path).unwrap().is_empty());
        let mut writer = ResultsWriter::open(&path).unwrap();
        writer.append_image(&[row(1, 1, 1, 0.1), row(1, 1, 2, 0.2)]).unwrap();
        writer.append_image(&[]).unwrap();
        drop(writer);
        let mut writer = ResultsWriter::open(&path).unwrap();
        writer.append_image(&[row(1, 2, 1, 0.3)]).unwrap();
        drop(writer);
        assert_eq!(read_results(&path, &mut Vec::new()).unwrap().len(), 3);
        assert_eq!(done_images(&path).unwrap(), BTreeSet::from([(1, 1), (1, 2)]));
    }

    #[test]
    fn writer_refuses_rows_of_several_images_and_bad_rows() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.csv");
        let mut writer = ResultsWriter::open(&path).unwrap();
        let err = writer.append_image(&[row(1, 1, 1, 0.1), row(1, 2, 1, 0.1)]).unwrap_err().to_string();
        assert!(err.contains("row 1 to write: image (scene 1, im 2) differs"), "{err}");
        let mut bad = row(1, 1, 1, 0.1);
        bad.score = f64::INFINITY;
        let err = writer.append_image(&[row(1, 1, 2, 0.1), bad.clone()]).unwrap_err().to_string();
        assert!(err.contains("row 1 to write: score: expected a finite number"), "{err}");
        bad.score = 1.0;
        bad.pose.translation.x = f64::NAN;
        assert!(write_results(&path, &[bad]).unwrap_err().to_string().contains("row 0 to write: t: value 1"));
        assert_eq!(fs::read_to_string(&path).unwrap(), format!("{HEADER}\n"));
    }

    #[test]
    fn open_repairs_torn_last_line_and_drops_the_unfinished_image() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("results.csv");
        write_results(&path, &[row(1, 1, 1, 0.1), row(1, 2, 1, 0.2), row(1, 2, 2, 0.3)]).unwrap();
        let whole = fs::read_to_string(&path).unwrap();
        let first_image_end = whole.find('\n').unwrap() + 1;
        let first_image_end = first_image_end + whole[first_image_end..].find('\n').unwrap() + 1;
        // Cut the file in the middle of image (1, 2)'s second row.
        fs::write(&path, &whole[..whole.len() - 20]).unwrap();
        assert!(read_results(&path, &mut Vec::new()).is_err());
        let mut writer = ResultsWriter::open(&path).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), whole[..first_image_end]);
        assert_eq!(done_images(&path).unwrap(), BTreeSet::from([(1, 1)]));
        writer.append_image(&[row(1, 2, 1, 0.2), row(1, 2, 2, 0.3)]).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), whole);
    }

    #[test]
    fn open_repairs_torn_first_row_and_torn_header() {
        let dir = tempfile::tempdir().unwrap();
        let path = write_file(&dir, &format!("{HEADER}\n1,2"));
        ResultsWriter::open(&path).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), format!("{HEADER}\n"));

        fs::write(&path, "scene_id,im_id,ob").unwrap();
        ResultsWriter::open(&path).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), format!("{HEADER}\n"));

        fs::write(&path, HEADER).unwrap();
        ResultsWriter::open(&path).unwrap().append_image(&[row(3, 4, 5, 0.5)]).unwrap();
        assert_eq!(done_images(&path).unwrap(), BTreeSet::from([(3, 4)]));

        fs::write(&path, "").unwrap();
        ResultsWriter::open(&path).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), format!("{HEADER}\n"));
    }

    #[test]
    fn open_keeps_a_complete_file_and_rejects_a_wrong_header() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!("{HEADER}\r\n{ROW_TEXT}\r\n");
        let path = write_file(&dir, &text);
        ResultsWriter::open(&path).unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), text);

        fs::write(&path, "a,b,c\n").unwrap();
        let err = ResultsWriter::open(&path).unwrap_err().to_string();
        assert!(err.contains("line 1: expected the header") && err.contains("found \"a,b,c\""), "{err}");
        assert_eq!(fs::read_to_string(&path).unwrap(), "a,b,c\n");
    }
}
