//! Video files for `b2tf track --video` (feature `video`): frames encoded by OpenH264 into a
//! raw Annex-B stream and an MP4 decode back to themselves, lazily; files that are missing,
//! not video, without an H.264 track or cut short are named, never a panic.
#![cfg(feature = "video")]

#[path = "common/h264.rs"]
mod h264;

use b2tfpose::video::FrameSource;
use std::path::Path;

/// `n` frames of a smooth colour ramp with a checkered square moving across it. Its edges
/// stay on even rows and columns: 4:2:0 shares one colour between 2×2 pixels, and a
/// saturated edge through such a block alone costs ~15 dB.
fn synthetic(n: usize, w: u32, h: u32) -> Vec<image::RgbImage> {
    (0..n)
        .map(|t| {
            image::RgbImage::from_fn(w, h, |x, y| {
                let (sx, sy) = (x as i64 - 40 - 6 * t as i64, y as i64 - 60 - 4 * t as i64);
                if (0..64).contains(&sx) && (0..48).contains(&sy) {
                    let check = if (sx / 8 + sy / 8) % 2 == 0 { 220 } else { 40 };
                    image::Rgb([check, 255 - check, 90])
                } else {
                    image::Rgb([(x * 255 / w) as u8, (y * 255 / h) as u8, (128.0 + 60.0 * ((x as f64 + 3.0 * t as f64) / 12.0).sin()) as u8])
                }
            })
        })
        .collect()
}

fn decode(path: &Path) -> Vec<anyhow::Result<b2tfpose::video::Frame>> {
    FrameSource::open(path).unwrap().collect()
}

#[test]
fn annex_b_and_mp4_decode_back_to_the_frames() {
    // 320×240, and 200×150: not whole macroblocks, the stream crops 208×160.
    for (n, w, h) in [(24, 320, 240), (6, 200, 150)] {
        round_trip(&synthetic(n, w, h));
    }
}

fn round_trip(frames: &[image::RgbImage]) {
    let clip = h264::encode(frames);
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("clip.h264");
    std::fs::write(&raw, &clip.annex_b).unwrap();
    let mp4 = dir.path().join("clip.mp4");
    h264::write_mp4(&clip, &mp4);
    let mov = dir.path().join("clip.MOV");
    std::fs::copy(&mp4, &mov).unwrap();
    for path in [&raw, &mp4, &mov] {
        let started = std::time::Instant::now();
        let decoded = decode(path);
        let ms = started.elapsed().as_secs_f64() * 1e3 / decoded.len() as f64;
        assert_eq!(decoded.len(), frames.len(), "{}", path.display());
        let mut worst = f64::INFINITY;
        for (i, (d, f)) in decoded.iter().zip(frames).enumerate() {
            let d = d.as_ref().unwrap();
            let name = path.file_name().unwrap().to_string_lossy();
            assert_eq!((d.index, d.name.as_str(), d.overlay_name.as_str()), (i, format!("{name}#{i}").as_str(), format!("{i:06}.png").as_str()));
            assert_eq!(d.image.dimensions(), f.dimensions());
            worst = worst.min(h264::psnr(&d.image, f));
        }
        // Measured: 40.7 dB at worst (QP 8–20, BT.601 limited range both ways).
        eprintln!("{}: {} frames of {:?}, {ms:.2} ms each, worst PSNR {worst:.1} dB", path.display(), decoded.len(), frames[0].dimensions());
        assert!(worst > 32.0, "{}: PSNR {worst:.1} dB", path.display());
    }
}

fn error_of(path: &Path) -> String {
    match FrameSource::open(path) {
        Ok(frames) => frames.filter_map(Result::err).map(|e| format!("{e:#}")).next().unwrap_or_else(|| panic!("{}: no error", path.display())),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn bad_video_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let at = |name: &str| dir.path().join(name);

    // Missing: a video name, and a name that is neither.
    let e = error_of(&at("missing.mp4"));
    assert!(e.contains("cannot open the video file") && e.contains("missing.mp4"), "{e}");
    let e = error_of(&at("missing"));
    assert!(e.contains("no such folder or file"), "{e}");
    std::fs::write(at("clip.avi"), b"RIFF").unwrap();
    let e = error_of(&at("clip.avi"));
    assert!(e.contains("neither a folder of frames nor a video file"), "{e}");

    // Text under a video's name.
    std::fs::write(at("notes.mp4"), "hello, this is not a video\n".repeat(20)).unwrap();
    let e = error_of(&at("notes.mp4"));
    assert!(e.contains("notes.mp4 is not a readable MP4/QuickTime file"), "{e}");
    std::fs::write(at("notes.h264"), "hello\n").unwrap();
    let e = error_of(&at("notes.h264"));
    assert!(e.contains("notes.h264 is not an H.264 Annex-B stream"), "{e}");

    // An MP4 with an audio track only.
    let aac = mp4::MediaConfig::AacConfig(mp4::AacConfig::default());
    h264::write_track(&at("audio.mp4"), mp4::TrackType::Audio, aac, vec![vec![0x21, 0x10, 0x04]; 3]);
    let e = error_of(&at("audio.mp4"));
    assert!(e.contains("audio.mp4 has no H.264 video track (tracks: aac)"), "{e}");

    // Cut short. The MP4 writer puts the index (moov) last: a cut file has none.
    let frames = synthetic(6, 160, 120);
    let clip = h264::encode(&frames);
    h264::write_mp4(&clip, &at("clip.mp4"));
    let whole = std::fs::read(at("clip.mp4")).unwrap();
    std::fs::write(at("cut.mp4"), &whole[..whole.len() * 3 / 4]).unwrap();
    let e = error_of(&at("cut.mp4"));
    assert!(e.contains("cut.mp4 is not a readable MP4/QuickTime file"), "{e}");
    // A raw stream cut inside its last frame: the frames before it, then an error naming
    // the frame (OpenH264 refuses the cut slice).
    let last = clip.frames.last().unwrap().iter().map(|n| n.len() + 4).sum::<usize>();
    std::fs::write(at("cut.h264"), &clip.annex_b[..clip.annex_b.len() - last / 2]).unwrap();
    let decoded = decode(&at("cut.h264"));
    assert_eq!(decoded.len(), 6);
    for (d, f) in decoded[..5].iter().zip(&frames) {
        assert!(h264::psnr(&d.as_ref().unwrap().image, f) > 32.0);
    }
    let e = format!("{:#}", decoded[5].as_ref().err().unwrap());
    assert!(e.contains("cut.h264: cannot decode frame 5 (the stream is cut or corrupt)"), "{e}");
    // A stream cut before its first picture: no frame at all.
    std::fs::write(at("header.h264"), &clip.annex_b[..clip.sps.len() + clip.pps.len() + 8]).unwrap();
    assert!(decode(&at("header.h264")).is_empty());
}

/// Random bytes changed in an MP4 and a raw stream: every file ends in frames or errors,
/// never a panic or a hang (the `mp4` crate looped forever on a child box under 8 bytes
/// before its boxes were checked; 3000 files measured, 400 kept here).
#[test]
fn corrupted_files_end_in_errors() {
    let frames = synthetic(6, 160, 120);
    let clip = h264::encode(&frames);
    let dir = tempfile::tempdir().unwrap();
    let mp4 = dir.path().join("clip.mp4");
    h264::write_mp4(&clip, &mp4);
    let whole = std::fs::read(&mp4).unwrap();
    let mut seed = 12345u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let (mut good, mut bad) = (0, 0);
    for i in 0..400 {
        let (name, base) = if i % 2 == 0 { ("m.mp4", &whole) } else { ("m.h264", &clip.annex_b) };
        let mut data = base.clone();
        for _ in 0..1 + rnd() % 8 {
            let at = (rnd() as usize) % data.len();
            data[at] = rnd() as u8;
        }
        let path = dir.path().join(name);
        std::fs::write(&path, &data).unwrap();
        for r in FrameSource::open(&path).into_iter().flatten() {
            if r.is_ok() {
                good += 1
            } else {
                bad += 1
            }
        }
    }
    eprintln!("{good} frames, {bad} errors");
    assert!(good > 0 && bad > 0);

    // The hang itself: `tkhd` (inside `trak`) claiming 4 bytes.
    let mut data = whole.clone();
    let at = data.windows(4).position(|w| w == b"tkhd").unwrap() - 4;
    data[at..at + 4].copy_from_slice(&4u32.to_be_bytes());
    std::fs::write(&mp4, &data).unwrap();
    let e = error_of(&mp4);
    assert!(e.contains("not a readable MP4/QuickTime file") && e.contains("box 'tkhd'") && e.contains("claims 4 bytes"), "{e}");
}
