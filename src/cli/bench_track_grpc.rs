//! `b2tf bench track --grpc`: one generated sequence through a server's `Track` stream, the
//! way a camera client sends it: the first frame with the object's mask, the rest bare,
//! sent ahead as fast as the stream takes them.

use crate::geometry::{Intrinsics, Pose};
use crate::service::client::png_bytes;
use crate::service::proto as pb;
use crate::service::proto::pose_service_client::PoseServiceClient;
use crate::track::sequence::Frame;
use anyhow::{anyhow, bail, Context, Result};
use std::time::{Duration, Instant};

#[derive(Default)]
pub struct StreamStats {
    pub tracked: usize,
    pub reinitialised: usize,
    pub lost: usize,
    server_ms: Vec<f64>,
    frames: usize,
    seconds: f64,
}

impl StreamStats {
    pub fn server_ms_median(&self) -> f64 {
        let mut v = self.server_ms.clone();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    }

    /// Frames after the first (which is a full estimate) per second of wall time.
    pub fn frames_per_second(&self) -> f64 {
        self.frames as f64 / self.seconds.max(1e-9)
    }
}

fn frame(f: &Frame, k: &Intrinsics, detection: Option<pb::Detection>) -> pb::TrackFrame {
    pb::TrackFrame {
        image: Some(pb::Image { data: Some(pb::image::Data::RawRgb8(f.rgb.as_raw().clone())), width: f.rgb.width(), height: f.rgb.height() }),
        intrinsics: Some(pb::Intrinsics { fx: k.fx, fy: k.fy, cx: k.cx, cy: k.cy, width: k.width, height: k.height }),
        detections: detection.into_iter().collect(),
        frame_index: None,
        options: None,
        ..Default::default()
    }
}

/// Streams `seq` and returns the pose the server gave for every frame.
pub fn stream_sequence(grpc: &str, object_id: &str, seq: &[Frame], first_mask: &image::GrayImage, k: &Intrinsics, stats: &mut StreamStats) -> Result<Vec<Option<Pose>>> {
    let runtime = tokio::runtime::Builder::new_current_thread().enable_all().build()?;
    runtime.block_on(async {
        let mut client = connect(grpc).await?;
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let detection = pb::Detection { object_id: object_id.into(), mask: Some(pb::detection::Mask::MaskPng(png_bytes(first_mask)?)), bbox: None, score: None };
        tx.send(frame(&seq[0], k, Some(detection))).await?;
        let mut answers = client.track(tokio_stream::wrappers::ReceiverStream::new(rx)).await?.into_inner();
        let first = answers.message().await?.ok_or_else(|| anyhow!("the stream ended at once"))?;
        if let Some(e) = first.error {
            bail!("first frame: {} {}", e.code, e.message);
        }
        let pose_of = |a: &pb::TrackFrameResult| {
            a.objects.first().and_then(|o| o.pose.as_ref()).map(|p| Pose::from_row_major(&[p.r[0], p.r[1], p.r[2], p.r[3], p.r[4], p.r[5], p.r[6], p.r[7], p.r[8]], [p.t[0], p.t[1], p.t[2]]))
        };
        let mut poses = vec![pose_of(&first)];
        let t = Instant::now();
        let frames: Vec<pb::TrackFrame> = seq[1..].iter().map(|f| frame(f, k, None)).collect();
        let sender = tokio::spawn(async move {
            for f in frames {
                if tx.send(f).await.is_err() {
                    break;
                }
            }
        });
        for _ in 1..seq.len() {
            let a = answers.message().await?.ok_or_else(|| anyhow!("the stream ended early"))?;
            if let Some(e) = &a.error {
                bail!("frame {}: {} {}", a.frame_index, e.code, e.message);
            }
            use pb::tracked_object::Mode;
            match a.objects.first().map(|o| o.mode()) {
                Some(Mode::Tracked) => stats.tracked += 1,
                Some(Mode::Reinitialised) => stats.reinitialised += 1,
                _ => stats.lost += 1,
            }
            stats.server_ms.push(a.total_ms);
            poses.push(pose_of(&a));
        }
        stats.frames += seq.len() - 1;
        stats.seconds += t.elapsed().as_secs_f64();
        sender.await?;
        Ok(poses)
    })
}

async fn connect(grpc: &str) -> Result<PoseServiceClient<tonic::transport::Channel>> {
    let t = Instant::now();
    loop {
        match PoseServiceClient::connect(format!("http://{grpc}")).await {
            Ok(c) => return Ok(c.max_decoding_message_size(64 << 20)),
            Err(e) if t.elapsed() > Duration::from_secs(60) => return Err(e).context("connecting to the server's gRPC port"),
            Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
        }
    }
}
