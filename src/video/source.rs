//! The frames of a video: a folder of PNG / JPEG frames in name order, or (feature
//! `video`) an H.264 video file (`super::h264`). Either way one frame is read at a time.

use super::container_of;
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// One frame: its index from 0, the name the JSON lines give it (the file's name in a
/// folder, `clip.mp4#12` in a video file) and the name of its overlay image.
pub struct Frame {
    pub index: usize,
    pub name: String,
    pub overlay_name: String,
    pub image: image::RgbImage,
}

/// The frames of a folder or a video file, in order.
pub struct FrameSource {
    inner: Inner,
    next: usize,
}

enum Inner {
    Folder(std::vec::IntoIter<PathBuf>),
    #[cfg(feature = "video")]
    // Boxed: the decoder state is large and a folder source needs none of it.
    Video {
        file_name: String,
        frames: Box<super::h264::H264Frames>,
    },
}

impl FrameSource {
    pub fn open(path: &Path) -> Result<Self> {
        let inner = if path.is_dir() {
            Inner::Folder(frame_paths(path)?.into_iter())
        } else if !path.exists() && container_of(path).is_none() {
            bail!("--video {}: no such folder or file", path.display());
        } else {
            Self::open_video(path)?
        };
        Ok(Self { inner, next: 0 })
    }

    #[cfg(feature = "video")]
    fn open_video(path: &Path) -> Result<Inner> {
        let Some(container) = container_of(path) else {
            bail!("--video {}: neither a folder of frames nor a video file ({})", path.display(), super::VIDEO_EXTENSIONS);
        };
        let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(Inner::Video { file_name, frames: Box::new(super::h264::H264Frames::open(path, container)?) })
    }

    #[cfg(not(feature = "video"))]
    fn open_video(path: &Path) -> Result<Inner> {
        bail!("--video {}: not a folder of frames; video files need b2tf built with the `video` feature", path.display());
    }
}

impl Iterator for FrameSource {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Result<Frame>> {
        let index = self.next;
        let frame = match &mut self.inner {
            Inner::Folder(paths) => {
                let path = paths.next()?;
                let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                let overlay_name = Path::new(&name).with_extension("png").to_string_lossy().into_owned();
                image::open(&path).with_context(|| format!("cannot read frame {}", path.display())).map(|i| Frame { index, name, overlay_name, image: i.to_rgb8() })
            }
            #[cfg(feature = "video")]
            Inner::Video { file_name, frames } => {
                let image = frames.next()?;
                image.map(|image| Frame { index, name: format!("{file_name}#{index}"), overlay_name: format!("{index:06}.png"), image })
            }
        };
        self.next += 1;
        Some(frame)
    }
}

/// The frames of `dir` (PNG / JPEG), sorted by file name.
pub fn frame_paths(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut frames: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the frames folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().and_then(|e| e.to_str()).is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg")))
        .collect();
    frames.sort();
    if frames.is_empty() {
        bail!("no PNG or JPEG frames in {}", dir.display());
    }
    Ok(frames)
}
