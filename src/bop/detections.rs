//! 2D detections in the CNOS / BOP "default detections" JSON format: a list
//! of `{"scene_id", "image_id", "category_id", "bbox": [x, y, w, h], "score",
//! "time", "segmentation": {"counts", "size"}}`. `category_id` is the BOP
//! `obj_id`; `segmentation` may be absent (box-only detector) and `time`
//! may be absent (read as 0 s).
//!
//! The whole file is parsed into a `serde_json::Value` first and the fields
//! are then checked one by one, so that every error can say which entry
//! (0-based index in the list) and which field is wrong.

use std::collections::BTreeMap;
use std::fs;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use image::{GrayImage, RgbImage};
use serde_json::{Map, Value};

use crate::masks::rle::{json_kind, Rle};
use crate::masks::{box_to_mask, mask_from_rle, require_nonempty, BoxMask};

/// Why a detections file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DetectionsError {
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}: invalid JSON: {source}{hint}", path.display())]
    Json { path: PathBuf, source: serde_json::Error, hint: &'static str },
    #[error("{}: expected a JSON list of detections, got {found}", path.display())]
    NotAList { path: PathBuf, found: &'static str },
    /// `reason` starts with the field name, e.g. `"score: expected a finite number, got null"`.
    #[error("{}: entry {index}: {reason}", path.display())]
    Entry { path: PathBuf, index: usize, reason: String },
}

/// One detection of one object in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectionRecord {
    pub scene_id: u32,
    pub image_id: u32,
    /// BOP object id (`category_id` in the file).
    pub obj_id: u32,
    /// `[x, y, w, h]` in pixels.
    pub bbox: [f64; 4],
    pub score: f64,
    /// Detector run time in seconds (0 when the file does not say).
    pub time: f64,
    pub segmentation: Option<Rle>,
}

/// What is wrong with one entry, starting with the field name; the caller
/// adds the file and the entry index.
type FieldError = String;

fn field_error(field: &str, reason: impl std::fmt::Display) -> FieldError {
    format!("{field}: {reason}")
}

/// Reads and validates a detections file.
pub fn read_detections(path: &Path) -> Result<Vec<DetectionRecord>, DetectionsError> {
    let text = fs::read_to_string(path).map_err(|source| DetectionsError::Io { path: path.into(), source })?;
    parse_detections(path, &text)
}

/// Validates the text of a detections file; `path` names it in errors.
pub fn parse_detections(path: &Path, text: &str) -> Result<Vec<DetectionRecord>, DetectionsError> {
    let root: Value = serde_json::from_str(text).map_err(|source| DetectionsError::Json {
        path: path.into(),
        source,
        // Python's json.dump writes NaN/Infinity, which are not JSON.
        hint: if text.contains("NaN") || text.contains("Infinity") { " (the file contains NaN or Infinity, which JSON does not allow)" } else { "" },
    })?;
    let entries = root.as_array().ok_or(DetectionsError::NotAList { path: path.into(), found: json_kind(&root) })?;
    entries.iter().enumerate().map(|(index, entry)| parse_entry(entry).map_err(|reason| DetectionsError::Entry { path: path.into(), index, reason })).collect()
}

fn parse_entry(entry: &Value) -> Result<DetectionRecord, FieldError> {
    let object = entry.as_object().ok_or_else(|| format!("expected an object, got {}", json_kind(entry)))?;
    let segmentation = match object.get("segmentation") {
        None | Some(Value::Null) => None,
        Some(v) => Some(Rle::from_json(v).map_err(|e| field_error("segmentation", e.to_string()))?),
    };
    let time = match object.get("time") {
        None | Some(Value::Null) => 0.0,
        Some(_) => finite(object, "time")?,
    };
    let record = DetectionRecord {
        scene_id: id(object, "scene_id")?,
        image_id: id(object, "image_id")?,
        obj_id: id(object, "category_id")?,
        bbox: bbox(object)?,
        score: finite(object, "score")?,
        time,
        segmentation,
    };
    Ok(record)
}

fn required<'a>(object: &'a Map<String, Value>, field: &'static str) -> Result<&'a Value, FieldError> {
    object.get(field).ok_or_else(|| field_error(field, "missing"))
}

fn id(object: &Map<String, Value>, field: &'static str) -> Result<u32, FieldError> {
    let v = required(object, field)?;
    v.as_u64().and_then(|n| u32::try_from(n).ok()).ok_or_else(|| field_error(field, format!("expected an integer in 0..=4294967295, got {v}")))
}

fn finite(object: &Map<String, Value>, field: &'static str) -> Result<f64, FieldError> {
    let v = required(object, field)?;
    v.as_f64().filter(|x| x.is_finite()).ok_or_else(|| field_error(field, format!("expected a finite number, got {v}")))
}

fn bbox(object: &Map<String, Value>) -> Result<[f64; 4], FieldError> {
    let v = required(object, "bbox")?;
    let items = v.as_array().ok_or_else(|| field_error("bbox", format!("expected [x, y, w, h], got {}", json_kind(v))))?;
    if items.len() != 4 {
        return Err(field_error("bbox", format!("expected 4 values [x, y, w, h], got {}", items.len())));
    }
    let mut out = [0.0; 4];
    for (slot, item) in out.iter_mut().zip(items) {
        *slot = item.as_f64().filter(|x| x.is_finite()).ok_or_else(|| field_error("bbox", format!("expected finite numbers, got {v}")))?;
    }
    if out[2] < 0.0 || out[3] < 0.0 {
        return Err(field_error("bbox", format!("width and height must be non-negative, got {v}")));
    }
    Ok(out)
}

/// Checks what `read_detections` would reject, so that a written file
/// always reads back.
fn check_writable(d: &DetectionRecord) -> Result<(), FieldError> {
    if !d.score.is_finite() {
        return Err(field_error("score", format!("not finite: {}", d.score)));
    }
    if !d.time.is_finite() {
        return Err(field_error("time", format!("not finite: {}", d.time)));
    }
    if d.bbox.iter().any(|x| !x.is_finite()) || d.bbox[2] < 0.0 || d.bbox[3] < 0.0 {
        return Err(field_error("bbox", format!("must be finite with non-negative size: {:?}", d.bbox)));
    }
    if let Some(rle) = &d.segmentation {
        rle.validate().map_err(|e| field_error("segmentation", e.to_string()))?;
    }
    Ok(())
}

fn to_json(d: &DetectionRecord) -> Value {
    let mut object = Map::new();
    object.insert("scene_id".into(), d.scene_id.into());
    object.insert("image_id".into(), d.image_id.into());
    object.insert("category_id".into(), d.obj_id.into());
    object.insert("bbox".into(), d.bbox.iter().copied().collect());
    object.insert("score".into(), d.score.into());
    object.insert("time".into(), d.time.into());
    if let Some(rle) = &d.segmentation {
        object.insert("segmentation".into(), rle.to_json_uncompressed());
    }
    Value::Object(object)
}

/// Writes detections with uncompressed (list) segmentations. The file is
/// written to `<path>.tmp` and renamed, so a crash never leaves half a file.
pub fn write_detections(path: &Path, dets: &[DetectionRecord]) -> Result<(), DetectionsError> {
    for (index, d) in dets.iter().enumerate() {
        check_writable(d).map_err(|reason| DetectionsError::Entry { path: path.into(), index, reason })?;
    }
    let list = Value::Array(dets.iter().map(to_json).collect());
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let io_error = |path: &Path| {
        let path = path.to_path_buf();
        move |source: std::io::Error| DetectionsError::Io { path, source }
    };
    let file = fs::File::create(&tmp).map_err(io_error(&tmp))?;
    let mut writer = BufWriter::new(file);
    serde_json::to_writer(&mut writer, &list).map_err(|e| io_error(&tmp)(e.into()))?;
    writer.flush().map_err(io_error(&tmp))?;
    drop(writer);
    fs::rename(&tmp, path).map_err(io_error(path))
}

impl DetectionRecord {
    /// The detection's mask on `image` (object = 255): the decoded segmentation, which
    /// must have the image's size, or, for a box-only detection, the object segmented
    /// inside the box (or the box filled, as `how` says). An empty mask, a box outside
    /// the image or of zero area is an error: the detection is unusable.
    pub fn mask(&self, image: &RgbImage, how: BoxMask) -> Result<GrayImage, String> {
        let (width, height) = image.dimensions();
        let mask = match &self.segmentation {
            Some(rle) => mask_from_rle(rle, width, height).map_err(|e| format!("segmentation: {e}"))?,
            None => box_to_mask(image, self.bbox, how).map_err(|e| format!("bbox: {e}"))?.mask,
        };
        require_nonempty(mask).map_err(|e| format!("segmentation: {e}"))
    }

    /// The detection as the estimator's candidates: its one mask (`mask`), or for a
    /// box-only detection with `BoxMask::Propose` the box's proposals, each carrying the box.
    pub fn candidates(&self, image: &RgbImage, how: BoxMask, proposals: &crate::masks::ProposalConfig) -> Result<Vec<crate::estimate::Detection>, String> {
        let score = self.score as f32;
        match (&self.segmentation, how) {
            (None, BoxMask::Propose) => {
                let b = crate::masks::box_masks(image, self.bbox, how, proposals).map_err(|e| format!("bbox: {e}"))?;
                Ok(crate::estimate::Detection::from_box_masks(b, score))
            }
            _ => Ok(vec![crate::estimate::Detection::new(self.mask(image, how)?, score)]),
        }
    }
}

/// Detections grouped by `(scene_id, image_id, obj_id)`, best score first.
#[derive(Debug, Default, Clone)]
pub struct DetectionIndex {
    groups: BTreeMap<(u32, u32, u32), Vec<DetectionRecord>>,
}

impl DetectionIndex {
    /// Groups the detections; ties in score keep their order in the input.
    pub fn new(dets: impl IntoIterator<Item = DetectionRecord>) -> Self {
        let mut groups: BTreeMap<(u32, u32, u32), Vec<DetectionRecord>> = BTreeMap::new();
        for d in dets {
            groups.entry((d.scene_id, d.image_id, d.obj_id)).or_default().push(d);
        }
        for group in groups.values_mut() {
            // Scores are finite when read from a file; total_cmp keeps the
            // sort well-defined even for hand-made records.
            group.sort_by(|a, b| b.score.total_cmp(&a.score));
        }
        Self { groups }
    }

    /// Detections of one object in one image, best first (empty if none).
    pub fn get(&self, scene_id: u32, image_id: u32, obj_id: u32) -> &[DetectionRecord] {
        self.groups.get(&(scene_id, image_id, obj_id)).map_or(&[], Vec::as_slice)
    }

    /// Object ids with at least one detection in the image, ascending.
    pub fn objects_in(&self, scene_id: u32, image_id: u32) -> impl Iterator<Item = u32> + '_ {
        self.groups.range((scene_id, image_id, 0)..=(scene_id, image_id, u32::MAX)).map(|(&(_, _, obj), _)| obj)
    }

    /// Number of `(scene, image, object)` groups.
    pub fn len(&self) -> usize {
        self.groups.len()
    }

    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn record(scene_id: u32, image_id: u32, obj_id: u32, score: f64) -> DetectionRecord {
        DetectionRecord { scene_id, image_id, obj_id, bbox: [1.0, 2.0, 3.5, 4.25], score, time: 0.125, segmentation: None }
    }

    fn write_text(dir: &tempfile::TempDir, text: &str) -> PathBuf {
        let path = dir.path().join("dets.json");
        fs::write(&path, text).unwrap();
        path
    }

    fn read_error(text: &str) -> String {
        let dir = tempfile::tempdir().unwrap();
        let path = write_text(&dir, text);
        let err = read_detections(&path).unwrap_err().to_string();
        assert!(err.starts_with(&path.display().to_string()), "error does not name the file: {err}");
        err
    }

    fn valid_entry() -> Value {
        json!({"scene_id": 48, "image_id": 1, "category_id": 2, "bbox": [10.5, 20.0, 30.0, 40.0],
               "score": 0.9, "time": 0.25, "segmentation": {"counts": [2, 2], "size": [2, 2]}})
    }

    /// A list of two valid entries where entry 1 has been modified.
    fn with_bad_second_entry(modify: impl FnOnce(&mut Map<String, Value>)) -> String {
        let mut bad = valid_entry();
        modify(bad.as_object_mut().unwrap());
        Value::Array(vec![valid_entry(), bad]).to_string()
    }

    #[test]
    fn write_then_read_round_trips() {
        let mut a = record(48, 1, 2, 0.75);
        a.segmentation = Some(Rle::new([3, 2], vec![0, 1, 2, 1, 1, 1]).unwrap());
        a.bbox = [0.1, 1e-7, 123.456789, 1.0 / 3.0];
        let b = record(50, 7, 21, -3.5);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.json");
        write_detections(&path, &[a.clone(), b.clone()]).unwrap();
        assert_eq!(read_detections(&path).unwrap(), vec![a, b]);
        assert!(!dir.path().join("out.json.tmp").exists());
        // The list form is what gets written.
        let raw: Value = serde_json::from_str(&fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(raw[0]["segmentation"]["counts"], json!([0, 1, 2, 1, 1, 1]));
        assert!(raw[1].get("segmentation").is_none());
    }

    #[test]
    fn write_rejects_unreadable_records() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.json");
        let mut bad = record(1, 1, 1, f64::NAN);
        let err = write_detections(&path, &[record(1, 1, 1, 0.5), bad.clone()]).unwrap_err().to_string();
        assert!(err.contains("entry 1: score"), "{err}");
        bad.score = 1.0;
        bad.segmentation = Some(Rle { size: [2, 2], counts: vec![1] });
        let err = write_detections(&path, &[bad]).unwrap_err().to_string();
        assert!(err.contains("entry 0: segmentation: counts sum to 1"), "{err}");
        assert!(!path.exists());
    }

    #[test]
    fn reads_compressed_strings_and_optional_fields() {
        let text = json!([
            {"scene_id": 1, "image_id": 2, "category_id": 3, "bbox": [2, 2, 4, 4], "score": 1,
             "segmentation": {"counts": "b04400000>", "size": [8, 8]}},
            {"scene_id": 1, "image_id": 2, "category_id": 3, "bbox": [0, 0, 1, 1], "score": 0.5,
             "time": null, "segmentation": null, "extra": "ignored"}
        ])
        .to_string();
        let dir = tempfile::tempdir().unwrap();
        let dets = read_detections(&write_text(&dir, &text)).unwrap();
        let rle = dets[0].segmentation.as_ref().unwrap();
        assert_eq!(rle.counts, vec![18, 4, 4, 4, 4, 4, 4, 4, 18]);
        assert_eq!(dets[0].time, 0.0);
        assert_eq!(dets[0].score, 1.0);
        assert_eq!(dets[1].segmentation, None);
    }

    #[test]
    fn empty_list_is_fine() {
        let dir = tempfile::tempdir().unwrap();
        assert!(read_detections(&write_text(&dir, "[]")).unwrap().is_empty());
    }

    #[test]
    fn file_level_errors() {
        assert!(read_error(r#"{"scene_id": 1}"#).contains("expected a JSON list of detections, got an object"));
        assert!(read_error("[{").contains("invalid JSON"));
        let nan = read_error(r#"[{"scene_id": 1, "score": NaN}]"#);
        assert!(nan.contains("NaN or Infinity"), "{nan}");
        let missing = read_detections(Path::new("/nonexistent/dets.json")).unwrap_err().to_string();
        assert!(missing.starts_with("/nonexistent/dets.json: "), "{missing}");
    }

    #[test]
    fn entry_errors_name_entry_and_field() {
        type Modify = fn(&mut Map<String, Value>);
        let cases: Vec<(Modify, &str)> = vec![
            (
                |e| {
                    e.remove("scene_id");
                },
                "entry 1: scene_id: missing",
            ),
            (
                |e| {
                    e.remove("category_id");
                },
                "entry 1: category_id: missing",
            ),
            (
                |e| {
                    e.remove("bbox");
                },
                "entry 1: bbox: missing",
            ),
            (
                |e| {
                    e.remove("score");
                },
                "entry 1: score: missing",
            ),
            (
                |e| {
                    e.insert("image_id".into(), json!(-1));
                },
                "entry 1: image_id: expected an integer",
            ),
            (
                |e| {
                    e.insert("scene_id".into(), json!(1.5));
                },
                "entry 1: scene_id: expected an integer",
            ),
            (
                |e| {
                    e.insert("scene_id".into(), json!(5_000_000_000u64));
                },
                "entry 1: scene_id: expected an integer",
            ),
            (
                |e| {
                    e.insert("category_id".into(), json!("2"));
                },
                "entry 1: category_id: expected an integer",
            ),
            (
                |e| {
                    e.insert("score".into(), json!(null));
                },
                "entry 1: score: expected a finite number, got null",
            ),
            (
                |e| {
                    e.insert("score".into(), json!("NaN"));
                },
                "entry 1: score: expected a finite number",
            ),
            (
                |e| {
                    e.insert("time".into(), json!("fast"));
                },
                "entry 1: time: expected a finite number",
            ),
            (
                |e| {
                    e.insert("bbox".into(), json!([1, 2, 3]));
                },
                "entry 1: bbox: expected 4 values [x, y, w, h], got 3",
            ),
            (
                |e| {
                    e.insert("bbox".into(), json!([1, 2, 3, 4, 5]));
                },
                "entry 1: bbox: expected 4 values",
            ),
            (
                |e| {
                    e.insert("bbox".into(), json!([1, "2", 3, 4]));
                },
                "entry 1: bbox: expected finite numbers",
            ),
            (
                |e| {
                    e.insert("bbox".into(), json!([1, 2, -3, 4]));
                },
                "entry 1: bbox: width and height",
            ),
            (
                |e| {
                    e.insert("bbox".into(), json!({"x": 1}));
                },
                "entry 1: bbox: expected [x, y, w, h], got an object",
            ),
            (
                |e| {
                    e.insert("segmentation".into(), json!({"counts": [100, 200], "size": [20, 20]}));
                },
                "entry 1: segmentation: counts sum to 300 but size is 20×20",
            ),
            (
                |e| {
                    e.insert("segmentation".into(), json!({"counts": "b0 4", "size": [8, 8]}));
                },
                "entry 1: segmentation: compressed counts: invalid character ' '",
            ),
            (
                |e| {
                    e.insert("segmentation".into(), json!({"counts": [4]}));
                },
                "entry 1: segmentation: size: missing",
            ),
            (
                |e| {
                    e.insert("segmentation".into(), json!([1, 2]));
                },
                "entry 1: segmentation: expected an object with \"counts\" and \"size\", got a list",
            ),
        ];
        for (modify, expected) in cases {
            let err = read_error(&with_bad_second_entry(modify));
            assert!(err.contains(expected), "got {err:?}, wanted {expected:?}");
        }
        assert!(read_error("[1]").contains("entry 0: expected an object, got a number"));
    }

    #[test]
    fn index_groups_and_sorts_by_descending_score() {
        let mut tie = record(1, 1, 5, 0.9);
        tie.time = 9.0; // equal score: must stay after the first 0.9
        let dets = [record(1, 1, 5, 0.2), record(1, 1, 5, 0.9), record(1, 1, 3, 0.5), record(1, 2, 5, 0.1), tie];
        let index = DetectionIndex::new(dets);
        assert_eq!(index.len(), 3);
        let group = index.get(1, 1, 5);
        assert_eq!(group.iter().map(|d| d.score).collect::<Vec<_>>(), vec![0.9, 0.9, 0.2]);
        assert_eq!(group[1].time, 9.0);
        assert_eq!(index.get(1, 1, 3).len(), 1);
        assert!(index.get(9, 9, 9).is_empty());
        assert_eq!(index.objects_in(1, 1).collect::<Vec<_>>(), vec![3, 5]);
        assert_eq!(index.objects_in(1, 2).collect::<Vec<_>>(), vec![5]);
        assert!(DetectionIndex::default().is_empty());
    }

    #[test]
    fn mask_from_segmentation_checks_size_and_emptiness() {
        let mut d = record(1, 1, 1, 1.0);
        d.segmentation = Some(Rle::new([3, 2], vec![0, 1, 2, 1, 1, 1]).unwrap());
        let mask = d.mask(&RgbImage::new(2, 3), BoxMask::Segment).unwrap();
        assert_eq!(mask.get_pixel(0, 0)[0], 255);
        assert_eq!(mask.get_pixel(0, 1)[0], 0);
        assert_eq!(mask.get_pixel(1, 2)[0], 255);
        let err = d.mask(&RgbImage::new(3, 2), BoxMask::Segment).unwrap_err();
        assert_eq!(err, "segmentation: mask is 2×3 (w×h) but the image is 3×2");
        d.segmentation = Some(Rle::new([3, 2], vec![6]).unwrap());
        assert_eq!(d.mask(&RgbImage::new(2, 3), BoxMask::Segment).unwrap_err(), "segmentation: the mask is empty (no nonzero pixel)");
    }

    #[test]
    fn mask_from_bbox_is_filled_or_segmented_and_checked() {
        let mut d = record(1, 1, 1, 1.0);
        let image = RgbImage::new(10, 10);
        d.bbox = [1.5, 1.0, 2.0, 2.0]; // covers x 1.5..3.5 -> pixels 1..=3, y 1..=2
        let mask = d.mask(&image, BoxMask::Fill).unwrap();
        let on: Vec<(u32, u32)> = mask.enumerate_pixels().filter(|p| p.2[0] == 255).map(|p| (p.0, p.1)).collect();
        assert_eq!(on, vec![(1, 1), (2, 1), (3, 1), (1, 2), (2, 2), (3, 2)]);
        // Too small to segment: the inscribed ellipse, inside the box.
        let segmented = d.mask(&image, BoxMask::Segment).unwrap();
        assert!(segmented.enumerate_pixels().all(|p| p.2[0] == 0 || on.contains(&(p.0, p.1))));

        d.bbox = [20.0, 0.0, 5.0, 5.0];
        assert!(d.mask(&image, BoxMask::Fill).unwrap_err().contains("bbox: box [20.0, 0.0, 5.0, 5.0] ([x, y, w, h]) lies outside the 10×10 image"));
        d.bbox = [2.0, 2.0, 0.0, 3.0];
        assert!(d.mask(&image, BoxMask::Segment).unwrap_err().contains("zero area"));
    }

    #[test]
    fn a_box_proposes_its_first_candidate_with_the_sources_to_come_and_a_mask_stays_one() {
        // A dark square on a light background, boxed with a margin.
        let image = RgbImage::from_fn(80, 60, |x, y| image::Rgb(if (30..50).contains(&x) && (20..40).contains(&y) { [30, 30, 90] } else { [230, 220, 210] }));
        let mut d = record(1, 1, 1, 0.7);
        d.bbox = [26.0, 16.0, 28.0, 28.0];
        // The first cut, carrying the box and the sources still to try (the estimator makes
        // them where its pose does not fit it).
        let all: crate::masks::ProposalConfig = "cut,smooth-cut,wide-ring-cut,ellipse".parse().unwrap();
        let c = d.candidates(&image, BoxMask::Propose, &all).unwrap();
        assert_eq!(c.len(), 1, "{} proposals", c.len());
        let b = crate::masks::PixelBox { x0: 26, y0: 16, x1: 54, y1: 44 };
        assert!(c[0].from_box == Some(b) && c[0].score == 0.7 && c[0].later == all.after_first());
        // The one cut alone: nothing to come.
        assert!(d.candidates(&image, BoxMask::Propose, &crate::masks::ProposalConfig::single()).unwrap()[0].later.is_none());
        // One segmentation, or a given mask: one candidate, without a box.
        let one = d.candidates(&image, BoxMask::Segment, &all).unwrap();
        assert_eq!((one.len(), one[0].from_box), (1, None));
        d.segmentation = Some(crate::masks::Rle::encode(&one[0].mask));
        let given = d.candidates(&image, BoxMask::Propose, &all).unwrap();
        assert_eq!((given.len(), given[0].from_box), (1, None));
        // A bad box is the same error whichever way it becomes masks.
        d.segmentation = None;
        d.bbox = [20.0, 0.0, 0.0, 5.0];
        assert!(d.candidates(&image, BoxMask::Propose, &all).unwrap_err().contains("bbox: box [20.0, 0.0, 0.0, 5.0] ([x, y, w, h]) has zero area"));
    }
}
