//! `--pose` values: 12 comma-separated numbers (R row-major, then t in metres) or a JSON
//! file `{"R": [9 numbers], "t": [3 numbers, metres]}`.

use crate::geometry::Pose;
use anyhow::{anyhow, bail, Context, Result};

pub fn parse_pose(arg: &str) -> Result<Pose> {
    let values: Vec<f64> = if std::path::Path::new(arg).is_file() {
        let text = std::fs::read_to_string(arg).with_context(|| format!("cannot read pose file {arg}"))?;
        let v: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("pose file {arg}: invalid JSON"))?;
        let list = |key: &str, n: usize| -> Result<Vec<f64>> {
            let a = v.get(key).and_then(|a| a.as_array()).filter(|a| a.len() == n).ok_or_else(|| anyhow!("pose file {arg}: \"{key}\" must have {n} numbers"))?;
            a.iter().map(|x| x.as_f64().ok_or_else(|| anyhow!("pose file {arg}: \"{key}\" has a non-number"))).collect()
        };
        let mut r = list("R", 9)?;
        r.extend(list("t", 3)?);
        r
    } else {
        arg.split(',').map(|s| s.trim().parse::<f64>().map_err(|_| anyhow!("--pose: {s:?} is not a number"))).collect::<Result<_>>()?
    };
    if values.len() != 12 {
        bail!("--pose needs 12 numbers (R row-major, t in metres), got {}", values.len());
    }
    if values.iter().any(|v| !v.is_finite()) {
        bail!("--pose has a non-finite number");
    }
    let r: [f64; 9] = values[..9].try_into().expect("9 values");
    let m = nalgebra::Matrix3::from_row_slice(&r);
    let orth = (m.transpose() * m - nalgebra::Matrix3::identity()).norm();
    if orth > 1e-3 || m.determinant() < 0.0 {
        bail!("--pose: R is not a rotation (‖RᵀR − I‖ = {orth:.2e}, det = {:.3})", m.determinant());
    }
    Ok(Pose::from_row_major(&r, [values[9], values[10], values[11]]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        let p = parse_pose("1,0,0, 0,1,0, 0,0,1, 0.1,0.2,0.5").unwrap();
        assert_eq!(p.translation.z, 0.5);
        assert!(parse_pose("1,0,0").unwrap_err().to_string().contains("12 numbers"));
        assert!(parse_pose("2,0,0,0,1,0,0,0,1,0,0,1").unwrap_err().to_string().contains("not a rotation"));
        assert!(parse_pose("1,0,0,0,1,0,0,0,1,0,0,x").unwrap_err().to_string().contains("not a number"));
    }
}
