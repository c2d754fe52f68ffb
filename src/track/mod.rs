//! Video: tracking an object's pose frame to frame with the contour refiner on a colour
//! posterior (no retrieval or PnP per frame), for camera-rate poses once a first estimate
//! is known.

pub mod check;
pub mod colour;
pub mod outline_colours;
pub mod photometric;
pub mod search;
pub mod sequence;
pub mod sequence_bop;
pub mod session;
pub mod tracker;

pub use session::{FrameDetection, SessionConfig, SessionError, TrackMode, TrackOutcome, TrackSession};
pub use tracker::{TrackStep, TrackTimings, Tracker, TrackerConfig};
