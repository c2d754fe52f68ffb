//! The caller's detections as the estimator's candidate masks: a detection is one mask,
//! or a box's mask proposals (`masks::proposals`) that count as one candidate.

use crate::masks::{BoxMasks, PixelBox};
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
}

impl Detection {
    /// A mask the caller (or its detector) made.
    pub fn new(mask: GrayImage, score: f32) -> Self {
        Self { mask, score, from_box: None }
    }

    /// A box-only detection's masks: proposals carry the box, a single mask made from
    /// the box (`BoxMask::Segment`/`Fill`) stands alone as if the caller had sent it.
    pub fn from_box_masks(b: BoxMasks, score: f32) -> Vec<Self> {
        let from_box = b.proposed.then_some(b.bbox);
        b.masks.into_iter().map(|mask| Self { mask, score, from_box }).collect()
    }
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
        Detection { mask: GrayImage::new(1, 1), score: 0.5, from_box }
    }

    #[test]
    fn box_proposals_carry_the_box_and_one_box_mask_stands_alone() {
        let b = PixelBox { x0: 1, y0: 2, x1: 5, y1: 6 };
        let proposed = Detection::from_box_masks(BoxMasks { bbox: b, proposed: true, masks: vec![GrayImage::new(2, 2); 3] }, 0.7);
        assert_eq!(proposed.len(), 3);
        assert!(proposed.iter().all(|d| d.from_box == Some(b) && d.score == 0.7));
        let single = Detection::from_box_masks(BoxMasks { bbox: b, proposed: false, masks: vec![GrayImage::new(2, 2)] }, 0.7);
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
