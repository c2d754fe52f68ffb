//! `b2tf demo --server grpc://HOST:PORT`: the demo as a client of a running service, the
//! way a factory cell uses it. Onboards the generated sample through the gRPC API (once;
//! later runs find it), renders a photo-like scene of it locally, estimates its pose
//! through the API, prints the pose and its error against the truth and writes the overlay;
//! then asks the server's detector to find the object with no mask.

use super::demo_scene::{make_scene, report, sample_mesh, DemoArgs};
use crate::service::client::{one_mask_request, png_bytes, BearerKey, Client};
use crate::service::proto as pb;
use crate::service::proto::pose_service_client::PoseServiceClient;
use anyhow::{bail, Context, Result};
use std::time::{Duration, Instant};
use tonic::transport::{Certificate, Channel, ClientTlsConfig};

const OBJECT_ID: &str = "demo-box";

pub fn run(a: &DemoArgs) -> Result<()> {
    tokio::runtime::Builder::new_multi_thread().enable_all().build()?.block_on(run_async(a))
}

async fn connect(server: &str, ca_cert: Option<&std::path::Path>) -> Result<Channel> {
    let (url, tls) = if let Some(rest) = server.strip_prefix("grpcs://").or_else(|| server.strip_prefix("https://")) {
        (format!("https://{rest}"), true)
    } else if let Some(rest) = server.strip_prefix("grpc://").or_else(|| server.strip_prefix("http://")) {
        (format!("http://{rest}"), false)
    } else {
        bail!("--server {server:?}: expected grpc://HOST:PORT or grpcs://HOST:PORT");
    };
    let mut endpoint = Channel::from_shared(url.clone()).with_context(|| format!("--server {server:?}"))?.connect_timeout(Duration::from_secs(10));
    if tls {
        let Some(ca) = ca_cert else { bail!("grpcs:// needs --ca-cert (the PEM certificate to trust)") };
        let pem = std::fs::read(ca).with_context(|| format!("--ca-cert {}", ca.display()))?;
        endpoint = endpoint.tls_config(ClientTlsConfig::new().ca_certificate(Certificate::from_pem(pem)))?;
    }
    endpoint.connect().await.with_context(|| format!("cannot reach the service at {server}"))
}

/// Waits until the service says it is SERVING (warmed up).
async fn wait_ready(channel: &Channel) -> Result<()> {
    use tonic_health::pb::{health_check_response::ServingStatus, health_client::HealthClient, HealthCheckRequest};
    let t = Instant::now();
    loop {
        let status = HealthClient::new(channel.clone()).check(HealthCheckRequest { service: "b2tfpose.v1.PoseService".into() }).await?.into_inner().status();
        if status == ServingStatus::Serving {
            return Ok(());
        }
        if t.elapsed() > Duration::from_secs(120) {
            bail!("the service did not become ready within 120 s");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

async fn run_async(a: &DemoArgs) -> Result<()> {
    let server = a.server.as_deref().unwrap_or_default();
    let channel = connect(server, a.ca_cert.as_deref()).await?;
    wait_ready(&channel).await?;
    let key = BearerKey::new(a.api_key.as_deref()).map_err(|e| anyhow::anyhow!("--api-key: {e}"))?;
    let mut client: Client = PoseServiceClient::with_interceptor(channel, key).max_decoding_message_size(64 << 20);

    let mesh = sample_mesh();
    let info = match client.get_object(pb::GetObjectRequest { object_id: OBJECT_ID.into() }).await {
        Ok(info) => {
            println!("{OBJECT_ID} is already onboarded on {server}");
            info.into_inner()
        }
        Err(s) if s.code() == tonic::Code::NotFound => onboard(&mut client, &mesh, &a.out).await?,
        Err(s) => bail!("GetObject: {s}"),
    };
    println!("demo object: {} templates, diameter {:.0} mm", info.templates, info.diameter_m * 1e3);

    let renderer = super::open_renderer(1)?;
    let scene = make_scene(&mesh, &renderer, a.seed, &a.out)?;
    let k = &scene.k;
    let request = one_mask_request(OBJECT_ID, png_bytes(&scene.photo)?, png_bytes(&scene.mask)?, k, !a.no_rrc);
    let t = Instant::now();
    let resp = client.estimate(request).await.map_err(|s| anyhow::anyhow!("Estimate: {s}"))?.into_inner();
    let round_trip_ms = t.elapsed().as_secs_f64() * 1e3;
    let Some(result) = resp.results.first() else { bail!("the service returned no result") };
    std::fs::write(a.out.join("result.json"), serde_json::to_vec_pretty(&result_json(&resp))?)?;
    let Some(p) = &result.pose else {
        println!("no pose: {}", result.reason);
        return Ok(());
    };
    let pose = crate::geometry::Pose::from_row_major(&p.r.clone().try_into().map_err(|_| anyhow::anyhow!("pose.r must hold 9 values"))?, [p.t[0], p.t[1], p.t[2]]);
    println!("pose from {server}: quaternion (w, x, y, z) = [{:.4}, {:.4}, {:.4}, {:.4}]", p.quaternion_wxyz[0], p.quaternion_wxyz[1], p.quaternion_wxyz[2], p.quaternion_wxyz[3]);
    report(&scene.truth, &pose, result.score, info.diameter_m, resp.total_ms);
    println!("round trip {round_trip_ms:.0} ms (server {:.0} ms)", resp.total_ms);
    let overlay = crate::render::overlay::draw_overlay(&scene.photo, &renderer, &mesh, &pose, k, [0, 255, 0])?;
    overlay.save(a.out.join("overlay.png"))?;
    println!("wrote {}/{{scene,mask,overlay}}.png and result.json", a.out.display());
    detect_by_id(&mut client, &scene.photo, &scene.mask, k).await
}

/// The same photo with the object id alone: what the server's detector finds.
async fn detect_by_id(client: &mut Client, photo: &image::RgbImage, mask: &image::GrayImage, k: &crate::geometry::Intrinsics) -> Result<()> {
    let request = pb::DetectRequest {
        image: Some(pb::Image { data: Some(pb::image::Data::Encoded(png_bytes(photo)?)), width: 0, height: 0 }),
        intrinsics: Some(k.into()),
        objects: vec![OBJECT_ID.into()],
        options: None,
        depth: None,
    };
    let found = client.detect(request).await.map_err(|s| anyhow::anyhow!("Detect: {s}"))?.into_inner();
    let truth = crate::detect::detector::bbox_of(mask);
    match (found.detections.first(), truth) {
        (Some(d), Some(t)) => {
            let b = d.bbox.unwrap_or_default();
            let iou = crate::detect::nms::box_iou(&[b.x, b.y, b.width, b.height], &t);
            println!("detected with no mask (Detect): box [{:.0}, {:.0}, {:.0}, {:.0}], score {:.2}, IoU {iou:.2} with the true box, {:.0} ms", b.x, b.y, b.width, b.height, d.score, found.total_ms);
        }
        _ => println!("the server's detector did not find {OBJECT_ID} with no mask: {}", found.reason),
    }
    Ok(())
}

/// Uploads the sample (OBJ + MTL + PNG) and follows the operation to its end.
async fn onboard(client: &mut Client, mesh: &crate::mesh::Mesh, out: &std::path::Path) -> Result<pb::ObjectInfo> {
    let dir = out.join("sample");
    crate::mesh::write_obj::write_obj(mesh, &dir, "box")?;
    let read = |n: &str| std::fs::read(dir.join(n)).with_context(|| format!("reading {n}"));
    let request = pb::OnboardRequest {
        object_id: OBJECT_ID.into(),
        mesh: Some(pb::Mesh {
            data: read("box.obj")?,
            format: "obj".into(),
            units: "m".into(),
            resources: vec![pb::Resource { name: "box.mtl".into(), data: read("box.mtl")? }, pb::Resource { name: "box_m0.png".into(), data: read("box_m0.png")? }],
        }),
        options: None,
        replace: false,
    };
    let op = client.onboard(request).await.map_err(|s| anyhow::anyhow!("Onboard: {s}"))?.into_inner();
    println!("onboarding {OBJECT_ID} through the API (operation {}, {} templates)", op.id, op.templates_total);
    let started = Instant::now();
    let mut stream = client.watch_operation(pb::GetOperationRequest { id: op.id.clone() }).await?.into_inner();
    let mut last_tenth = 0;
    let mut last = op;
    while let Some(o) = stream.message().await? {
        let tenth = (o.templates_done * 10).checked_div(o.templates_total).unwrap_or(0);
        if tenth > last_tenth {
            println!("  {}%", tenth * 10);
            last_tenth = tenth;
        }
        last = o;
    }
    match last.state() {
        pb::operation::State::Succeeded => {
            println!("onboarded in {:.1} s", started.elapsed().as_secs_f64());
            last.object.context("the finished operation names no object")
        }
        state => bail!("onboarding ended {state:?}: {}", last.error),
    }
}

/// An answer's symmetries as the HTTP API writes them (`KnownSymmetries`' JSON form).
fn symmetries_json(s: &pb::Symmetries) -> serde_json::Value {
    serde_json::json!({
        "source": s.source,
        "discrete": s.discrete.iter().map(|d| &d.matrix).collect::<Vec<_>>(),
        "continuous": s.continuous.iter().map(|c| serde_json::json!({"axis": c.axis, "offset": c.offset_m})).collect::<Vec<_>>(),
    })
}

fn pose_json(p: &pb::Pose) -> serde_json::Value {
    serde_json::json!({"R": p.r, "t": p.t, "quaternion_wxyz": p.quaternion_wxyz})
}

/// The response as JSON: poses (R row-major, t in metres, quaternion), score, timings,
/// symmetries and the diagnostics document.
fn result_json(r: &pb::EstimateResponse) -> serde_json::Value {
    let results: Vec<serde_json::Value> = r
        .results
        .iter()
        .map(|i| {
            serde_json::json!({
                "object_id": i.object_id,
                "instance": i.instance,
                "pose": i.pose.as_ref().map(pose_json),
                "score": i.score,
                "reason": (!i.reason.is_empty()).then_some(&i.reason),
                "timings_ms": i.timings_ms,
                "symmetries": i.symmetries.as_ref().map(symmetries_json),
                "arbitrary_rotation_about_axis": i.arbitrary_rotation_about_axis,
                "runner_up": i.runner_up.as_ref().map(|u| serde_json::json!({"pose": u.pose.as_ref().map(pose_json), "margin": u.margin, "distance_over_diameter": u.distance_over_diameter, "close_call": u.close_call})),
                "diagnostics": serde_json::from_str::<serde_json::Value>(&i.diagnostics_json).unwrap_or_default(),
            })
        })
        .collect();
    serde_json::json!({ "results": results, "total_ms": r.total_ms })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::symmetry::{ContinuousSymmetry, DiscreteSymmetry, KnownSymmetries, ObjectSymmetries, SymmetrySource};

    /// The demo's result.json writes symmetries as the HTTP API does: they read back as
    /// the object's own.
    #[test]
    fn symmetries_in_the_result_read_back_as_the_objects() {
        let half_turn = DiscreteSymmetry::from_row_major_4x4(&[-1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.01, 0.0, 0.0, 0.0, 1.0]);
        let known = KnownSymmetries {
            source: SymmetrySource::Mesh,
            symmetries: ObjectSymmetries { discrete: vec![half_turn], continuous: vec![ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.0, 0.02] }] },
        };
        let json = symmetries_json(&crate::service::grpc_convert::symmetries(known.clone()));
        let back: KnownSymmetries = serde_json::from_value(json).unwrap();
        assert_eq!(back, known);
    }
}
