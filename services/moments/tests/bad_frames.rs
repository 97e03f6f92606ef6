//! The worker rejects a frame whose header disagrees with its payload, says which frame and
//! why (log and health), and goes on with the next frame.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::mpsc;
use std::time::{Duration, Instant};
use stereoscope_moments::{MomentsConfig, run};
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::{Health, Message, Observation};
use stereoscope_proto::names::{iox as iox_names, zenoh as keys};
use stereoscope_rig::Rig;
use stereoscope_service::Context;
use stereoscope_transport::Shutdown;
use stereoscope_transport::iox::{FramePublisher, MessageSubscriber, node};
use stereoscope_transport::net::{self, ZenohMode, ZenohSpec};

const RIG: &str = include_str!("../../../deploy/rigs/demo.toml");

#[test]
fn inconsistent_frame_is_rejected_and_the_next_one_processed() {
    let rig = Rig::from_toml(RIG).unwrap();
    let prefix = format!("stsc_m{}_", std::process::id());
    let port = net::free_loopback_port().unwrap();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let ctx = Context {
        rig_path: "demo.toml".into(),
        rig,
        host: "local".into(),
        iox_prefix: prefix.clone(),
        zenoh: ZenohSpec {
            mode: ZenohMode::Peer,
            connect: vec![],
            listen: vec![endpoint.clone()],
            tls: None,
            access_control: None,
        },
    };
    let n = node(&prefix, "test-writer").unwrap();
    let frames = FramePublisher::new(&n, &iox_names::frames("demo", "cam0"), 320 * 240).unwrap();
    let obs = MessageSubscriber::new(&n, &iox_names::observations("demo", "cam0")).unwrap();
    let shutdown = Shutdown::new();
    let worker = {
        let s = shutdown.clone();
        std::thread::spawn(move || {
            run(
                MomentsConfig {
                    ctx,
                    camera: "cam0".into(),
                    max_frames: None,
                },
                s,
            )
        })
    };
    let session = {
        let spec = ZenohSpec {
            mode: ZenohMode::Peer,
            connect: vec![endpoint],
            listen: vec![],
            tls: None,
            access_control: None,
        };
        net::open(&spec).unwrap()
    };
    let (tx, rx) = mpsc::channel();
    let _h = net::subscribe(
        &session,
        &keys::health("demo", "local", "moments/cam0"),
        move |_, b| {
            if let Ok(h) = Health::from_json(b) {
                let _ = tx.send(h);
            }
        },
    )
    .unwrap();

    let mut img = vec![20u8; 320 * 240];
    for y in 100..110 {
        for x in 150..160 {
            img[y * 320 + x] = 200;
        }
    }
    let good = FrameHeader::new("cam0", PixelFormat::Gray8, 320, 240).unwrap();
    // The header claims 320×240 but only 239 rows came. Sent alone, again until the worker's
    // health reports it rejected (a worker takes the newest frame waiting, so a bad frame
    // followed at once by a good one could be skipped unread).
    let mut bad = good;
    bad.sequence = 1;
    let end = Instant::now() + Duration::from_secs(20);
    let health = 'rejected: loop {
        assert!(
            Instant::now() < end,
            "no health report with the bad frame rejected in 20 s"
        );
        frames.publish_unchecked(bad, &img[..320 * 239]).unwrap();
        let until = Instant::now() + Duration::from_millis(300);
        while let Some(left) = until.checked_duration_since(Instant::now()) {
            match rx.recv_timeout(left) {
                Ok(h) if h.rejected > 0 => break 'rejected h,
                Ok(_) => {}
                Err(_) => break,
            }
        }
    };
    // Then good frames: the worker goes on and tracks the blob.
    let mut seen_good = false;
    let mut seq = 2;
    while !seen_good {
        assert!(
            Instant::now() < end,
            "no observation of a good frame in 20 s"
        );
        let mut g = good;
        g.sequence = seq;
        seq += 1;
        frames.publish_unchecked(g, &img).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        while let Some(o) = obs.try_next::<Observation>().unwrap() {
            let o = o.unwrap();
            assert_ne!(o.sequence, 1, "the inconsistent frame was processed");
            if o.blobs.len() == 1 {
                assert!((o.blobs[0].x_px - 154.5).abs() < 0.01, "{o:?}");
                seen_good = true;
            }
        }
    }
    let e = health.last_error.unwrap();
    assert!(
        e.contains("frame 1 of cam0") && e.contains("payload has 76480"),
        "{e}"
    );
    shutdown.request();
    assert!(worker.join().unwrap().unwrap() >= 1);
    // The worker, stopping while this test's writer node lived, left the prefix alone; the
    // last user releases it, and nothing of the test stays in /dev/shm.
    drop((frames, obs));
    drop(n);
    assert!(stereoscope_transport::iox::release_prefix(&prefix).unwrap());
    let left: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|f| f.starts_with(&prefix))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
