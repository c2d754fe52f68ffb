//! The BOP benchmark (bop.felk.cvut.cz): dataset layout and reading, default detections
//! (RLE masks), the results CSV, the BOP'19 pose errors (VSD, MSSD, MSPD) with symmetries
//! and their Average Recall, the BOP'22 2D detection and segmentation AP (COCO), the
//! runner that feeds a dataset through the estimator, and a generator of synthetic BOP
//! datasets.

pub mod coco_ap;
pub mod coco_iou;
pub mod dataset;
pub mod detection_eval;
pub mod detection_gt;
pub mod detections;
pub mod eval_models;
pub mod evaluate;
pub mod format;
pub mod pose_errors;
pub mod results_csv;
pub mod rotation;
pub mod run;
pub mod scene_dataset;
pub mod scene_write;
pub mod scoring;
pub mod synth;
pub mod synth_masks;
pub mod vsd_render;

pub use dataset::{load_depth_mm, load_models_info, load_rgb, load_scene_cameras, load_scene_gt, load_split_gt, load_targets, model_path, DatasetError, GtInstance, ImageCamera, ImageGt};
pub use format::{scene_dir, CameraRecord, GtInfoRecord, GtRecord, ModelInfo, TargetRecord, TEST_SPLIT};
