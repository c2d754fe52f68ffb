//! Camera files: `{"K": [[fx,0,cx],[0,fy,cy],[0,0,1]], "resolution": [h, w]}` (the
//! MegaPose example format) or BOP's `{"cam_K": [9 values], "width": w, "height": h}`.
//! Where the image is known, BOP's form may leave out the size (real BOP files do), and a
//! whole BOP `scene_camera.json` (entries keyed by image id) gives its first image's camera.

use crate::geometry::Intrinsics;
use anyhow::{anyhow, bail, Context, Result};
use std::path::Path;

pub fn load_camera(path: &Path) -> Result<Intrinsics> {
    load_camera_for(path, None)
}

/// A camera for images of `size` (width, height): BOP's form may leave the size out.
pub fn load_camera_for(path: &Path, size: Option<(u32, u32)>) -> Result<Intrinsics> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read camera file {}", path.display()))?;
    parse_camera_for(&text, size).with_context(|| format!("camera file {}", path.display()))
}

pub fn parse_camera(text: &str) -> Result<Intrinsics> {
    parse_camera_for(text, None)
}

/// The entry of the lowest image id when `v` is a BOP `scene_camera.json`.
fn first_scene_camera(v: &serde_json::Value) -> Option<&serde_json::Value> {
    let map = v.as_object().filter(|m| !m.is_empty() && m.keys().all(|k| !k.is_empty() && k.bytes().all(|b| b.is_ascii_digit())))?;
    map.iter().min_by_key(|(k, _)| k.parse::<u64>().unwrap_or(u64::MAX)).map(|(_, c)| c)
}

pub fn parse_camera_for(text: &str, size: Option<(u32, u32)>) -> Result<Intrinsics> {
    let whole: serde_json::Value = serde_json::from_str(text).context("invalid JSON")?;
    let v = first_scene_camera(&whole).unwrap_or(&whole);
    let num = |x: &serde_json::Value, what: &str| x.as_f64().ok_or_else(|| anyhow!("{what} is not a number"));
    let (k, w, h): ([f64; 9], f64, f64) = if let Some(k) = v.get("K") {
        let rows = k.as_array().filter(|r| r.len() == 3).ok_or_else(|| anyhow!("\"K\" must be a 3×3 array"))?;
        let mut m = [0f64; 9];
        for (i, r) in rows.iter().enumerate() {
            let r = r.as_array().filter(|r| r.len() == 3).ok_or_else(|| anyhow!("\"K\" row {i} must have 3 numbers"))?;
            for (j, x) in r.iter().enumerate() {
                m[i * 3 + j] = num(x, &format!("K[{i}][{j}]"))?;
            }
        }
        let res = v.get("resolution").and_then(|r| r.as_array()).filter(|r| r.len() == 2).ok_or_else(|| anyhow!("\"resolution\" must be [height, width]"))?;
        (m, num(&res[1], "resolution width")?, num(&res[0], "resolution height")?)
    } else if let Some(k) = v.get("cam_K") {
        let a = k.as_array().filter(|a| a.len() == 9).ok_or_else(|| anyhow!("\"cam_K\" must have 9 numbers"))?;
        let mut m = [0f64; 9];
        for (i, x) in a.iter().enumerate() {
            m[i] = num(x, &format!("cam_K[{i}]"))?;
        }
        match (v.get("width"), v.get("height"), size) {
            (Some(w), Some(h), _) => (m, num(w, "width")?, num(h, "height")?),
            (None, None, Some((w, h))) => (m, w as f64, h as f64),
            (None, _, _) => bail!("BOP camera needs \"width\" (or an image to take it from)"),
            (_, None, _) => bail!("BOP camera needs \"height\" (or an image to take it from)"),
        }
    } else {
        bail!("expected \"K\" + \"resolution\" or \"cam_K\" + \"width\" + \"height\"");
    };
    if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        bail!("K must be [[fx,0,cx],[0,fy,cy],[0,0,1]] (no skew), got {k:?}");
    }
    if !(w >= 1.0 && h >= 1.0 && w.fract() == 0.0 && h.fract() == 0.0 && w <= 65535.0 && h <= 65535.0) {
        bail!("image size must be positive whole numbers, got {w}×{h}");
    }
    Ok(Intrinsics::new(k[0], k[4], k[2], k[5], w as u32, h as u32)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_formats() {
        let a = parse_camera(r#"{"K": [[600.0, 0.0, 320.0], [0.0, 610.0, 240.0], [0.0, 0.0, 1.0]], "resolution": [480, 640]}"#).unwrap();
        assert_eq!((a.fx, a.fy, a.cx, a.cy, a.width, a.height), (600.0, 610.0, 320.0, 240.0, 640, 480));
        let b = parse_camera(r#"{"cam_K": [600, 0, 320, 0, 610, 240, 0, 0, 1], "width": 640, "height": 480, "depth_scale": 0.1}"#).unwrap();
        assert_eq!(a, b);
        // A whole scene_camera.json, its entries without a size: the first image's camera,
        // sized by the image.
        let scene = r#"{"7": {"cam_K": [1, 0, 1, 0, 1, 1, 0, 0, 1]}, "3": {"cam_K": [600, 0, 320, 0, 610, 240, 0, 0, 1], "depth_scale": 0.1}}"#;
        assert_eq!(parse_camera_for(scene, Some((640, 480))).unwrap(), a);
        let e = format!("{:#}", parse_camera(scene).unwrap_err());
        assert!(e.contains("width") && e.contains("image"), "{e}");
    }

    #[test]
    fn bad_cameras_say_what_is_wrong() {
        for (text, needle) in [
            ("{", "invalid JSON"),
            (r#"{"foo": 1}"#, "expected"),
            (r#"{"K": [[1,0,0],[0,1,0]], "resolution": [1, 1]}"#, "3×3"),
            (r#"{"cam_K": [-5, 0, 1, 0, 5, 1, 0, 0, 1], "width": 4, "height": 4}"#, "focal"),
            (r#"{"cam_K": [5, 0, 1, 0, 5, 1, 0, 0, 1], "width": 0, "height": 4}"#, "size"),
            (r#"{"cam_K": [5, 1, 1, 0, 5, 1, 0, 0, 1], "width": 4, "height": 4}"#, "skew"),
            (r#"{"cam_K": [5, 0, 1, 0, 5, 1, 0, 0, 1], "height": 4}"#, "width"),
        ] {
            let e = format!("{:#}", parse_camera(text).unwrap_err());
            assert!(e.contains(needle), "{text}: {e}");
        }
    }
}
