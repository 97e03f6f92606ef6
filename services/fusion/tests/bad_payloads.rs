//! Fusion over Zenoh: a payload that does not decode is counted and named (by its key) in
//! health, and fusion goes on fusing the good observations that follow.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use nalgebra::Point3;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use stereoscope_fusion::{FusionConfig, run};
use stereoscope_proto::messages::{
    BlobObservation, Health, Message, Observation, PoseFrame, SCHEMA_VERSION, TrackState,
};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_rig::Context;
use stereoscope_rig::Rig;
use stereoscope_transport::Shutdown;
use stereoscope_transport::net::{self, JsonPublisher, ZenohMode, ZenohSpec};

const RIG: &str = include_str!("../../../deploy/rigs/demo.toml");

fn observation(camera: &str, pixel: (f64, f64), ts: u64) -> Observation {
    Observation {
        schema: SCHEMA_VERSION,
        rig: "demo".into(),
        camera: camera.into(),
        sequence: ts,
        timestamp_ns: ts,
        frame_published_ns: ts,
        published_ns: ts,
        width_px: 320,
        height_px: 240,
        threshold: 100,
        full_frame: false,
        dropped_blobs: 0,
        blobs: vec![BlobObservation {
            track_id: 1,
            status: TrackState::Tracked,
            area_px: 60.0,
            x_px: pixel.0,
            y_px: pixel.1,
            mu20: 300.0,
            mu02: 300.0,
            mu11: 0.0,
            orientation_deg: 0.0,
            roundness: 1.0,
            heading_deg: 0.0,
            directed: false,
            heading_ambiguous: true,
            clipped: false,
            window_px: [0, 0, 319, 239],
            bbox_px: [0, 0, 1, 1],
        }],
    }
}

#[test]
fn undecodable_payload_is_named_and_fusion_goes_on() {
    let text = RIG.replace("[fusion]\n", "[fusion]\nobservations = \"zenoh\"\n");
    let rig = Rig::from_toml(&text).unwrap();
    let port = net::free_loopback_port().unwrap();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let ctx = Context {
        rig_path: "demo.toml".into(),
        rig: rig.clone(),
        host: "local".into(),
        iox_prefix: format!("stsc_f{}_", std::process::id()),
        zenoh: ZenohSpec {
            mode: ZenohMode::Peer,
            connect: vec![],
            listen: vec![endpoint.clone()],
        },
    };
    let shutdown = Shutdown::new();
    let fusion = {
        let s = shutdown.clone();
        std::thread::spawn(move || {
            run(
                FusionConfig {
                    ctx,
                    max_sets: None,
                },
                s,
            )
        })
    };
    let session = net::open(&ZenohSpec {
        mode: ZenohMode::Peer,
        connect: vec![endpoint],
        listen: vec![],
    })
    .unwrap();
    let (htx, hrx) = mpsc::channel();
    let _h = net::subscribe(
        &session,
        &keys::health("demo", "local", "fusion"),
        move |_, b| {
            if let Ok(h) = Health::from_json(b) {
                let _ = htx.send(h);
            }
        },
    )
    .unwrap();
    let (ptx, prx) = mpsc::channel();
    let _p = net::subscribe(&session, &keys::poses("demo"), move |_, b| {
        if let Ok(p) = PoseFrame::from_json(b) {
            let _ = ptx.send(p);
        }
    })
    .unwrap();
    let cam0 = JsonPublisher::new(&session, &keys::observations("demo", "cam0")).unwrap();
    let cam1 = JsonPublisher::new(&session, &keys::observations("demo", "cam1")).unwrap();
    let point = Point3::new(0.05, -0.03, 0.6);
    let px = |c: usize| {
        let p = rig.cameras[c].camera.project(&point).unwrap();
        (p.x, p.y)
    };
    let end = Instant::now() + Duration::from_secs(20);
    let pose = loop {
        assert!(Instant::now() < end, "no pose from the good observations");
        cam0.put_bytes(b"{\"schema\": 1, \"rig\": tru".to_vec())
            .unwrap();
        let ts = stereoscope_proto::messages::now_ns();
        cam0.put(&observation("cam0", px(0), ts)).unwrap();
        cam1.put(&observation("cam1", px(1), ts)).unwrap();
        if let Ok(p) = prx.recv_timeout(Duration::from_millis(200))
            && p.cameras.len() == 2
            && p.poses.len() == 1
        {
            break p;
        }
    };
    let got = pose.poses[0].position_m;
    let err =
        ((got[0] - point.x).powi(2) + (got[1] - point.y).powi(2) + (got[2] - point.z).powi(2))
            .sqrt();
    assert!(err < 1e-6, "{got:?}");
    // Until a health report counts a rejected payload (bounded): sent again each time, in
    // case the first ones went out before fusion's subscription was in place.
    let end = Instant::now() + Duration::from_secs(20);
    let health = loop {
        assert!(
            Instant::now() < end,
            "no health report with the bad payload rejected in 20 s"
        );
        cam0.put_bytes(b"{\"schema\": 1, \"rig\": tru".to_vec())
            .unwrap();
        if let Ok(h) = hrx.recv_timeout(Duration::from_millis(500))
            && h.rejected > 0
        {
            break h;
        }
    };
    let e = health.last_error.unwrap();
    assert!(
        e.contains("stereoscope/demo/observations/cam0") && e.contains("JSON"),
        "{e}"
    );
    shutdown.request();
    assert!(fusion.join().unwrap().unwrap() >= 1);
}
