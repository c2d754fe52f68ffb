//! Template retrieval: rank templates by global-descriptor cosine (plus, optionally, the
//! silhouette overlap of query and template crops), then keep a viewpoint-diverse top k
//! with geodesic non-maximum suppression over the full rotation.

use crate::geometry::geodesic_distance;
use crate::onboard::model::silhouette_iou;
use crate::onboard::ObjectModel;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RetrievalConfig {
    /// Templates kept (125 in the paper).
    pub k: usize,
    /// Minimum rotation distance between two kept templates, degrees; 0 disables NMS.
    pub nms_degrees: f64,
    /// Keep every template (ablation: no retrieval at all).
    pub all_templates: bool,
    /// Weight of the silhouette IoU added to the cosine similarity. 0 by default: on the
    /// generated HOPE benchmark it did not help
    /// (docs/benchmarks/estimation-verification.md, "Silhouette in retrieval").
    pub silhouette_weight: f32,
}

impl Default for RetrievalConfig {
    fn default() -> Self {
        Self { k: 125, nms_degrees: 20.0, all_templates: false, silhouette_weight: 0.0 }
    }
}

/// A retrieved template and its ranking score.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Retrieved {
    pub template: usize,
    pub score: f32,
    pub cosine: f32,
    pub silhouette_iou: f32,
}

/// Ranked templates; `query_silhouette` is the bit-packed query crop mask.
pub fn retrieve(model: &ObjectModel, query_global: &[f32], query_silhouette: &[u64], cfg: &RetrievalConfig) -> Vec<Retrieved> {
    let mut ranked: Vec<Retrieved> = (0..model.template_count())
        .map(|t| {
            let cosine: f32 = model.global_descriptor(t).iter().zip(query_global).map(|(a, b)| a * b).sum();
            let silhouette_iou = if cfg.silhouette_weight != 0.0 { silhouette_iou(model.silhouette_words(t), query_silhouette) } else { 0.0 };
            Retrieved { template: t, score: cosine + cfg.silhouette_weight * silhouette_iou, cosine, silhouette_iou }
        })
        .collect();
    ranked.sort_by(|a, b| b.score.total_cmp(&a.score));
    if cfg.all_templates {
        return ranked;
    }
    if cfg.nms_degrees <= 0.0 {
        ranked.truncate(cfg.k);
        return ranked;
    }
    let min_dist = cfg.nms_degrees.to_radians();
    let mut kept: Vec<Retrieved> = Vec::with_capacity(cfg.k);
    for r in ranked {
        if kept.len() >= cfg.k {
            break;
        }
        let rot = &model.templates[r.template].pose.rotation;
        if kept.iter().all(|k| geodesic_distance(&model.templates[k.template].pose.rotation, rot) >= min_dist) {
            kept.push(r);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_of_packed_silhouettes() {
        assert_eq!(silhouette_iou(&[0b0011], &[0b0101]), 1.0 / 3.0);
        assert_eq!(silhouette_iou(&[0, 0], &[0, 0]), 0.0);
        assert_eq!(silhouette_iou(&[u64::MAX], &[u64::MAX]), 1.0);
    }
}
