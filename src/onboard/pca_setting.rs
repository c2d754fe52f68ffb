//! Whether onboarding compresses patch descriptors with a PCA, and to how many components.
//!
//! `auto` (the default) keeps the descriptors of narrow backbones (the embedded one's 64
//! dims) as they are, and compresses wide ones (ViT-S's 384, ViT-L's 1024) to at most 256
//! components, as FoundPose does for DINOv2 ViT-L, and fewer where an object has so many
//! patches that 256 would pass the size budget (docs/onnx_backbone.md has the figures).

use std::fmt;
use std::str::FromStr;

/// Largest component count `auto` keeps, and the descriptor size above which it compresses.
pub const AUTO_MAX_COMPONENTS: usize = 256;
/// Fewest components `auto` goes down to, whatever the patch count.
pub const AUTO_MIN_COMPONENTS: usize = 64;
/// Bytes of stored f16 descriptors `auto` aims under, so that a whole object (descriptors,
/// 3D points, silhouettes, contour model) stays under 400 MB.
pub const AUTO_DESCRIPTOR_BUDGET: usize = 360_000_000;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PcaSetting {
    #[default]
    Auto,
    /// Keep every dimension (f16).
    Off,
    /// Keep this many components.
    Components(usize),
}

impl PcaSetting {
    /// What records without the setting meant.
    pub fn off() -> Self {
        PcaSetting::Off
    }

    /// Refuses a component count the backbone's `dim`-value descriptors cannot give (before
    /// onboarding starts rather than after it).
    pub fn check(self, dim: usize) -> Result<(), String> {
        match self {
            PcaSetting::Components(k) if k > dim => Err(format!("PCA: cannot keep {k} components of the backbone's {dim}-dimensional patch descriptors")),
            _ => Ok(()),
        }
    }

    /// Components to keep for a model of `patches` descriptors of `dim` values (None: all).
    pub fn resolve(self, dim: usize, patches: usize) -> Option<usize> {
        match self {
            PcaSetting::Off => None,
            PcaSetting::Components(k) => Some(k),
            PcaSetting::Auto if dim <= AUTO_MAX_COMPONENTS => None,
            PcaSetting::Auto => {
                let fits = AUTO_DESCRIPTOR_BUDGET / (2 * patches.max(1));
                // Multiples of 32 keep the GEMM kernels' panels full.
                Some((fits / 32 * 32).clamp(AUTO_MIN_COMPONENTS, AUTO_MAX_COMPONENTS))
            }
        }
    }
}

impl fmt::Display for PcaSetting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PcaSetting::Auto => f.write_str("auto"),
            PcaSetting::Off => f.write_str("off"),
            PcaSetting::Components(k) => write!(f, "{k}"),
        }
    }
}

impl FromStr for PcaSetting {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(PcaSetting::Auto),
            "off" | "none" => Ok(PcaSetting::Off),
            t => match t.parse::<usize>() {
                Ok(0) => Err("PCA components must be at least 1 (\"off\" keeps every dimension)".into()),
                Ok(k) => Ok(PcaSetting::Components(k)),
                Err(_) => Err(format!("PCA setting {t:?} is not \"auto\", \"off\" or a number of components")),
            },
        }
    }
}

/// Stored and sent as JSON: "auto", null (keep all: what older records' `pca_dim: null`
/// meant) or a number of components.
impl serde::Serialize for PcaSetting {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            PcaSetting::Auto => s.serialize_str("auto"),
            PcaSetting::Off => s.serialize_none(),
            PcaSetting::Components(k) => s.serialize_u64(*k as u64),
        }
    }
}

impl<'de> serde::Deserialize<'de> for PcaSetting {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Number(u64),
            Text(String),
        }
        match Option::<Raw>::deserialize(d)? {
            None => Ok(PcaSetting::Off),
            Some(Raw::Number(k)) => PcaSetting::from_str(&k.to_string()).map_err(serde::de::Error::custom),
            Some(Raw::Text(t)) => PcaSetting::from_str(&t).map_err(serde::de::Error::custom),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_compresses_only_wide_descriptors_and_stays_in_budget() {
        assert_eq!(PcaSetting::Auto.resolve(64, 816_160), None);
        assert_eq!(PcaSetting::Auto.resolve(256, 816_160), None);
        // ViT-L on a small object: the full 256.
        assert_eq!(PcaSetting::Auto.resolve(1024, 300_000), Some(256));
        // ViT-L on the sample box (816k patches): 256 would be 418 MB of descriptors.
        let k = PcaSetting::Auto.resolve(1024, 816_160).unwrap();
        assert_eq!(k, 192);
        assert!(k * 2 * 816_160 <= AUTO_DESCRIPTOR_BUDGET);
        // Never below the floor, even past the budget.
        assert_eq!(PcaSetting::Auto.resolve(1024, 10_000_000), Some(AUTO_MIN_COMPONENTS));
        assert_eq!(PcaSetting::Off.resolve(1024, 816_160), None);
        assert_eq!(PcaSetting::Components(32).resolve(64, 10), Some(32));
        assert!(PcaSetting::Components(64).check(64).is_ok());
        assert!(PcaSetting::Components(65).check(64).unwrap_err().contains("65 components of the backbone's 64-dimensional"));
        assert!(PcaSetting::Auto.check(8).is_ok() && PcaSetting::Off.check(8).is_ok());
    }

    #[test]
    fn parses_and_round_trips_through_text_and_json() {
        for (text, v) in [("auto", PcaSetting::Auto), ("off", PcaSetting::Off), ("none", PcaSetting::Off), ("48", PcaSetting::Components(48))] {
            assert_eq!(text.parse::<PcaSetting>().unwrap(), v);
            let json = serde_json::to_string(&v).unwrap();
            assert_eq!(serde_json::from_str::<PcaSetting>(&json).unwrap(), v, "{json}");
        }
        assert_eq!(PcaSetting::Components(48).to_string().parse::<PcaSetting>().unwrap(), PcaSetting::Components(48));
        // Older records wrote `pca_dim: null` (keep all) or a number.
        assert_eq!(serde_json::from_str::<PcaSetting>("null").unwrap(), PcaSetting::Off);
        assert_eq!(serde_json::from_str::<PcaSetting>("16").unwrap(), PcaSetting::Components(16));
        for bad in ["0", "-3", "half", ""] {
            assert!(bad.parse::<PcaSetting>().is_err(), "{bad}");
        }
        assert!(serde_json::from_str::<PcaSetting>("0").unwrap_err().to_string().contains("at least 1"));
        assert!(serde_json::from_str::<PcaSetting>("\"lots\"").is_err());
    }
}
