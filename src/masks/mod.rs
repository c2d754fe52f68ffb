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
pub mod proposals;
pub mod rle;
pub mod segment;
pub mod union;

pub use decode::{box_masks, box_to_mask, box_to_mask_with, mask_from_png, mask_from_rle, require_nonempty, BoxMask, BoxMasks, MaskError, PixelBox};
pub use instances::{group_instances, mask_iou};
pub use proposals::{propose, Proposal, ProposalConfig, ProposalKind};
pub use rle::{Rle, RleError};
pub use segment::{ellipse_in_box, segment_box, Method, SegmentConfig, Segmentation};
pub use union::union;
