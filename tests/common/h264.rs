//! H.264 test clips (feature `video`): frames encoded by OpenH264 at a high bitrate into a
//! raw Annex-B stream, and the same access units written into an MP4 by the `mp4` crate.
#![allow(dead_code)]

use openh264::encoder::{BitRate, Encoder, EncoderConfig, FrameRate, QpRange, RateControlMode};
use openh264::formats::{RgbSliceU8, YUVBuffer};
use openh264::OpenH264API;
use std::path::Path;

pub struct Clip {
    pub width: u32,
    pub height: u32,
    /// The whole stream with start codes.
    pub annex_b: Vec<u8>,
    /// Per frame, its NAL units without start codes (SPS and PPS left out).
    pub frames: Vec<Vec<Vec<u8>>>,
    pub sps: Vec<u8>,
    pub pps: Vec<u8>,
}

pub fn encode(frames: &[image::RgbImage]) -> Clip {
    let (width, height) = frames[0].dimensions();
    // Every frame kept (no skipping), at a fine quantiser (QP 8–20) and a bitrate well above
    // what 320×240 needs.
    let config =
        EncoderConfig::new().bitrate(BitRate::from_bps(8_000_000)).max_frame_rate(FrameRate::from_hz(30.0)).rate_control_mode(RateControlMode::Quality).qp(QpRange::new(8, 20)).skip_frames(false);
    let mut encoder = Encoder::with_api_config(OpenH264API::from_source(), config).unwrap();
    let mut clip = Clip { width, height, annex_b: Vec::new(), frames: Vec::new(), sps: Vec::new(), pps: Vec::new() };
    for f in frames {
        let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(f.as_raw(), (width as usize, height as usize)));
        let bits = encoder.encode(&yuv).unwrap();
        bits.write_vec(&mut clip.annex_b);
        let mut nals = Vec::new();
        for layer in (0..bits.num_layers()).filter_map(|l| bits.layer(l)) {
            for nal in (0..layer.nal_count()).filter_map(|n| layer.nal_unit(n)) {
                let zeros = nal.iter().take_while(|&&b| b == 0).count();
                let nal = nal[zeros + 1..].to_vec();
                match nal[0] & 0x1f {
                    7 => clip.sps = nal,
                    8 => clip.pps = nal,
                    _ => nals.push(nal),
                }
            }
        }
        clip.frames.push(nals);
    }
    clip
}

/// The clip as an MP4 with one `avc1` track (25 frames/s), NAL units length-prefixed.
pub fn write_mp4(clip: &Clip, path: &Path) {
    let avc = mp4::AvcConfig { width: clip.width as u16, height: clip.height as u16, seq_param_set: clip.sps.clone(), pic_param_set: clip.pps.clone() };
    let samples = clip.frames.iter().map(|nals| nals.iter().flat_map(|nal| [&(nal.len() as u32).to_be_bytes()[..], nal].concat()).collect()).collect();
    write_track(path, mp4::TrackType::Video, mp4::MediaConfig::AvcConfig(avc), samples);
}

/// An MP4 holding one track of `samples`, one per tick of a 25 Hz clock.
pub fn write_track(path: &Path, track_type: mp4::TrackType, media_conf: mp4::MediaConfig, samples: Vec<Vec<u8>>) {
    use mp4::{Mp4Config, Mp4Sample, Mp4Writer, TrackConfig};
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let brand = |b: &str| b.parse().unwrap();
    let config = Mp4Config { major_brand: brand("isom"), minor_version: 512, compatible_brands: vec![brand("isom"), brand("avc1")], timescale: 1000 };
    let mut writer = Mp4Writer::write_start(file, &config).unwrap();
    writer.add_track(&TrackConfig { track_type, timescale: 25, language: "und".into(), media_conf }).unwrap();
    for (i, bytes) in samples.into_iter().enumerate() {
        let sample = Mp4Sample { start_time: i as u64, duration: 1, rendering_offset: 0, is_sync: i == 0, bytes: bytes.into() };
        writer.write_sample(1, &sample).unwrap();
    }
    writer.write_end().unwrap();
}

/// Peak signal-to-noise ratio of two images of one size, in dB.
pub fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let se: f64 = a.as_raw().iter().zip(b.as_raw()).map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2)).sum();
    let mse = se / a.as_raw().len() as f64;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}
