//! The caller's detections as the estimator's candidate masks: a detection is one mask,
//! or a box's mask proposals (`masks::proposals`) that count as one candidate.

use crate::masks::{BoxMasks, PixelBox, ProposalConfig};
use image::GrayImage;

/// A segmentation of the object in the image, with the detector's confidence.
#[derive(Clone, Debug)]
pub struct Detection {
    pub mask: GrayImage,
    pub score: f32,
    /// The caller's box, where the mask is one of several proposed from a box
    /// (`masks::proposals`): the proposals of one box count as one candidate, and their
    /// poses are judged by how well they fill the box as well as by their own mask.
    pub from_box: Option<PixelBox>,
    /// The box's proposal sources still to try, on its first proposal: the estimator makes
    /// their masks only where this one's pose does not fit it
    /// (`EstimateConfig::sure_proposal_iou`).
    pub later: Option<ProposalConfig>,
}

impl Detection {
    /// A mask the caller (or its detector) made.
    pub fn new(mask: GrayImage, score: f32) -> Self {
        Self { mask, score, from_box: None, later: None }
    }

    /// A box-only detection's masks: proposals carry the box, a single mask made from
    /// the box (`BoxMask::Segment`/`Fill`) stands alone as if the caller had sent it.
    pub fn from_box_masks(b: BoxMasks, score: f32) -> Vec<Self> {
        let from_box = b.proposed.then_some(b.bbox);
        let mut later = b.later.filter(|_| b.proposed);
        b.masks.into_iter().map(|mask| Self { mask, score, from_box, later: later.take() }).collect()
    }
}

/// `detections` and, with depth, one more proposal per box from the depth
/// (`masks::depth_proposal`), scored and boxed like that box's others. The added ones come
/// after the caller's; [`box_owner`] maps them back.
pub fn with_depth_proposals(detections: &[Detection], depth: &crate::depth::DepthImage, k: &crate::geometry::Intrinsics) -> Vec<Detection> {
    let mut out = detections.to_vec();
    let mut boxes: Vec<(PixelBox, f32)> = Vec::new();
    for d in detections {
        if let Some(b) = d.from_box.filter(|b| !boxes.iter().any(|(seen, _)| seen == b)) {
            boxes.push((b, d.score));
        }
    }
    for (b, score) in boxes {
        if let Some(mask) = crate::masks::depth_proposal::depth_proposal(depth, k, &b) {
            out.push(Detection { mask, score, from_box: Some(b), later: None });
        }
    }
    out
}

/// The index among the first `given` of `detections` that `index` stands for: itself, or
/// for an added proposal the first of the caller's proposals of the same box.
pub fn box_owner(detections: &[Detection], given: usize, index: usize) -> usize {
    if index < given {
        return index;
    }
    let b = detections[index].from_box;
    detections[..given].iter().position(|d| d.from_box.is_some() && d.from_box == b).unwrap_or(index)
}

/// The mask and score that stand for a detection's candidates (its first mask) where a
/// detection needs one mask: grouping into instances, and as another instance's occluder.
pub fn representative(candidates: &[Detection]) -> (&GrayImage, f64) {
    (&candidates[0].mask, candidates[0].score as f64)
}

/// Several detections' candidates in one list, with the caller's detection each came from,
/// so that the estimate's `mask_index` can be answered as the caller's detection index.
#[derive(Clone, Debug, Default)]
pub struct Candidates {
    pub masks: Vec<Detection>,
    owner: Vec<usize>,
}

impl Candidates {
    /// `detections` as (the caller's index, its candidates).
    pub fn gather<'a>(detections: impl IntoIterator<Item = (usize, &'a [Detection])>) -> Self {
        let mut out = Self::default();
        for (index, c) in detections {
            out.push(index, c.iter().cloned());
        }
        out
    }

    pub fn push(&mut self, index: usize, candidates: impl IntoIterator<Item = Detection>) {
        for c in candidates {
            self.masks.push(c);
            self.owner.push(index);
        }
    }

    /// The caller's detection that candidate `mask_index` came from.
    pub fn owner_of(&self, mask_index: Option<usize>) -> Option<usize> {
        mask_index.and_then(|m| self.owner.get(m).copied())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(from_box: Option<PixelBox>) -> Detection {
        Detection { mask: GrayImage::new(1, 1), score: 0.5, from_box, later: None }
    }

    #[test]
    fn a_depth_proposal_comes_after_the_callers_and_answers_as_its_box() {
        let (a, b) = (PixelBox { x0: 2, y0: 2, x1: 8, y1: 8 }, PixelBox { x0: 10, y0: 2, x1: 16, y1: 8 });
        // A flat patch at 0.5 m in box b, nothing measured elsewhere.
        let values: Vec<f32> = (0..20 * 10).map(|i| if (10..16).contains(&(i % 20)) && (2..8).contains(&(i / 20)) { 0.5 } else { 0.0 }).collect();
        let depth = crate::depth::DepthImage::from_metres(20, 10, values).unwrap();
        let k = crate::geometry::Intrinsics::new(20.0, 20.0, 10.0, 5.0, 20, 10).unwrap();
        let given = vec![det(None), det(Some(a)), det(Some(b)), det(Some(b))];
        let given: Vec<Detection> = given.into_iter().map(|d| Detection { mask: GrayImage::new(20, 10), ..d }).collect();
        let all = with_depth_proposals(&given, &depth, &k);
        assert_eq!(all.len(), 5, "one proposal, for the box with depth");
        assert_eq!(all[4].from_box, Some(b));
        assert_eq!(all[4].mask.pixels().filter(|p| p[0] > 0).count(), 36);
        assert_eq!((box_owner(&all, 4, 4), box_owner(&all, 4, 3), box_owner(&all, 4, 0)), (2, 3, 0));
    }

    #[test]
    fn box_proposals_carry_the_box_and_one_box_mask_stands_alone() {
        let b = PixelBox { x0: 1, y0: 2, x1: 5, y1: 6 };
        let proposed = Detection::from_box_masks(BoxMasks { bbox: b, proposed: true, masks: vec![GrayImage::new(2, 2); 3], later: None }, 0.7);
        assert_eq!(proposed.len(), 3);
        assert!(proposed.iter().all(|d| d.from_box == Some(b) && d.score == 0.7));
        let single = Detection::from_box_masks(BoxMasks { bbox: b, proposed: false, masks: vec![GrayImage::new(2, 2)], later: None }, 0.7);
        assert_eq!((single.len(), single[0].from_box), (1, None));
    }

    #[test]
    fn candidates_answer_the_callers_detection() {
        let b = PixelBox { x0: 0, y0: 0, x1: 1, y1: 1 };
        let first = vec![det(None)];
        let second = vec![det(Some(b)), det(Some(b)), det(Some(b))];
        let c = Candidates::gather([(4, first.as_slice()), (7, second.as_slice())]);
        assert_eq!(c.masks.len(), 4);
        assert_eq!(c.owner_of(Some(0)), Some(4));
        assert_eq!(c.owner_of(Some(3)), Some(7));
        assert_eq!(c.owner_of(Some(9)), None);
        assert_eq!(c.owner_of(None), None);
    }
}
