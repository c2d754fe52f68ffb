//! Object masks from whatever a caller has: PNG bytes, run-length encodings, or only a
//! box, which is segmented (GrabCut-style) rather than filled, because a filled rectangle
//! poisons everything that uses the outline (silhouette retrieval, selection IoU,
//! refiners). Also the grouping of one object's detections into instances.
//!
//! The service, the CLI and the BOP runner all decode detections here, so this module
//! sits below them and depends on nothing of the crate above `image`/`nalgebra`.

pub mod components;
pub mod decode;
pub mod depth_proposal;
pub mod gmm;
pub mod instances;
pub mod maxflow;
pub mod outline_matte;
pub mod pixel_box;
pub mod proposals;
pub mod rle;
pub mod segment;
pub mod union;

pub use decode::{box_masks, box_to_mask, box_to_mask_with, mask_from_png, mask_from_rle, require_nonempty, BoxMask, BoxMasks};
pub use instances::{group_instances, mask_iou};
pub use pixel_box::PixelBox;
pub use proposals::{more_proposals, propose, propose_first, Proposal, ProposalConfig, ProposalKind};
pub use rle::{Rle, RleError};
pub use segment::{ellipse_in_box, segment_box, Method, SegmentConfig, Segmentation};
pub use union::{occluders, union, OtherMasks};

use crate::limits::ImageRefused;

/// Value of an object pixel in every mask made here.
pub const OBJECT: u8 = 255;

/// Why a mask could not be made from the input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaskError {
    #[error("box {bbox:?} ([x, y, w, h]) has a non-finite value")]
    NonFiniteBox { bbox: [f64; 4] },
    #[error("box {bbox:?} ([x, y, w, h]) has zero area: width and height must be positive")]
    ZeroAreaBox { bbox: [f64; 4] },
    #[error("box {bbox:?} ([x, y, w, h]) lies outside the {width}×{height} image")]
    BoxOutsideImage { bbox: [f64; 4], width: u32, height: u32 },
    #[error("mask is {mask_width}×{mask_height} (w×h) but the image is {width}×{height}")]
    SizeMismatch { mask_width: u32, mask_height: u32, width: u32, height: u32 },
    #[error("the mask is empty (no nonzero pixel)")]
    Empty,
    #[error("not a readable PNG/JPEG image: {0}")]
    Unreadable(String),
    /// Over [`crate::limits::REQUEST_IMAGE`]: refused from the header, before decoding.
    #[error("mask {0}")]
    TooLarge(ImageRefused),
    #[error(transparent)]
    Rle(#[from] RleError),
}

impl From<ImageRefused> for MaskError {
    fn from(e: ImageRefused) -> Self {
        match e {
            ImageRefused::Unreadable(m) => MaskError::Unreadable(m),
            too_large => MaskError::TooLarge(too_large),
        }
    }
}
