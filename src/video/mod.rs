//! Video input: the frames of a folder of images or of an H.264 file (`.mp4` / `.m4v` /
//! `.mov`, or a raw `.h264` / `.264` stream), read one at a time. Outside the CLI so that
//! the service can take video too; `b2tf track --video` reads through it.

#[cfg(feature = "video")]
pub mod h264;
pub mod source;

pub use source::{frame_paths, Frame, FrameSource};

use std::path::Path;

/// The file names a video file may have.
pub const VIDEO_EXTENSIONS: &str = ".mp4, .m4v, .mov (H.264), .h264, .264 (Annex-B)";

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Container {
    /// ISO base media file (MP4, M4V) or QuickTime (MOV) with an `avc1` track.
    Mp4,
    /// A raw H.264 elementary stream: NAL units after 00 00 01 start codes.
    AnnexB,
}

/// The container of a video file, from its extension (whether or not this build reads
/// it); None: not a video file's name.
pub fn container_of(path: &Path) -> Option<Container> {
    match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
        "mp4" | "m4v" | "mov" => Some(Container::Mp4),
        "h264" | "264" => Some(Container::AnnexB),
        _ => None,
    }
}
