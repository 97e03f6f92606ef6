//! Fusion over Zenoh: a payload that does not decode is counted and named (by its key) in
//! health, and fusion goes on fusing the good observations that follow.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use nalgebra::Point3;
use std::sync::mpsc;
use std::time::{Duration, Instant};
use stereoscope_fusion::{FusionConfig, run};
use stereoscope_proto::messages::{
    BlobObservation, Health, Message, Observation, PoseFrame, SCHEMA_VERSION, TrackState, limits,
};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_rig::Rig;
use stereoscope_service::Context;
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
        dark: false,
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
            merged: false,
            window_px: [0, 0, 319, 239],
            bbox_px: [0, 0, 1, 1],
        }],
    }
}

/// Fusion of the demo rig (all observations over Zenoh) in a thread, and a peer session with
/// its health, its poses and a publisher per camera.
struct Harness {
    rig: Rig,
    shutdown: Shutdown,
    fusion: std::thread::JoinHandle<Result<u64, stereoscope_fusion::FusionError>>,
    health: mpsc::Receiver<Health>,
    poses: mpsc::Receiver<PoseFrame>,
    cams: [JsonPublisher; 2],
    _subs: Vec<net::NetSubscriber>,
    session: zenoh::Session,
}

impl Harness {
    fn start(tag: char) -> Harness {
        let text = RIG.replace("[fusion]\n", "[fusion]\nobservations = \"zenoh\"\n");
        let rig = Rig::from_toml(&text).unwrap();
        let port = net::free_loopback_port().unwrap();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let ctx = Context {
            rig_path: "demo.toml".into(),
            rig: rig.clone(),
            host: "local".into(),
            iox_prefix: format!("stsc_f{}{tag}_", std::process::id()),
            zenoh: ZenohSpec {
                mode: ZenohMode::Peer,
                connect: vec![],
                listen: vec![endpoint.clone()],
                tls: None,
                access_control: None,
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
            tls: None,
            access_control: None,
        })
        .unwrap();
        let (htx, health) = mpsc::channel();
        let h = net::subscribe(
            &session,
            &keys::health("demo", "local", "fusion"),
            move |_, b| {
                if let Ok(h) = Health::from_json(b) {
                    let _ = htx.send(h);
                }
            },
        )
        .unwrap();
        let (ptx, poses) = mpsc::channel();
        let p = net::subscribe(&session, &keys::poses("demo"), move |_, b| {
            if let Ok(p) = PoseFrame::from_json(b) {
                let _ = ptx.send(p);
            }
        })
        .unwrap();
        let cams = [
            JsonPublisher::new(&session, &keys::observations("demo", "cam0")).unwrap(),
            JsonPublisher::new(&session, &keys::observations("demo", "cam1")).unwrap(),
        ];
        Harness {
            rig,
            shutdown,
            fusion,
            health,
            poses,
            cams,
            _subs: vec![h, p],
            session,
        }
    }

    /// Where `point` falls in camera `c`.
    fn px(&self, c: usize, point: &Point3<f64>) -> (f64, f64) {
        let p = self.rig.cameras[c].camera.project(point).unwrap();
        (p.x, p.y)
    }

    /// Sends `before` (hostile input) then a good observation of `point` from each camera,
    /// until a two-camera pose frame of one object comes back (bounded); returns it.
    fn pose_despite(&self, point: &Point3<f64>, before: &dyn Fn(&Self)) -> PoseFrame {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            assert!(Instant::now() < end, "no pose from the good observations");
            before(self);
            let ts = stereoscope_proto::messages::now_ns();
            self.cams[0]
                .put(&observation("cam0", self.px(0, point), ts))
                .unwrap();
            self.cams[1]
                .put(&observation("cam1", self.px(1, point), ts))
                .unwrap();
            if let Ok(p) = self.poses.recv_timeout(Duration::from_millis(200))
                && p.cameras.len() == 2
                && p.poses.len() == 1
            {
                return p;
            }
        }
    }

    /// The first health report (within 20 s) for which `done` holds, sending `again` before
    /// each wait (in case the first ones went out before fusion's subscription was in place).
    fn health_until(&self, again: &dyn Fn(&Self), done: impl Fn(&Health) -> bool) -> Health {
        let end = Instant::now() + Duration::from_secs(20);
        loop {
            assert!(Instant::now() < end, "no such health report in 20 s");
            again(self);
            if let Ok(h) = self.health.recv_timeout(Duration::from_millis(500))
                && done(&h)
            {
                return h;
            }
        }
    }

    fn stop(self) -> u64 {
        self.shutdown.request();
        drop(self.session);
        self.fusion.join().unwrap().unwrap()
    }
}

fn assert_at(pose: &PoseFrame, point: &Point3<f64>) {
    let got = pose.poses[0].position_m;
    let err =
        ((got[0] - point.x).powi(2) + (got[1] - point.y).powi(2) + (got[2] - point.z).powi(2))
            .sqrt();
    assert!(err < 1e-6, "{got:?}");
}

#[test]
fn undecodable_payload_is_named_and_fusion_goes_on() {
    let h = Harness::start('a');
    let point = Point3::new(0.05, -0.03, 0.6);
    let garbage = |h: &Harness| {
        h.cams[0]
            .put_bytes(b"{\"schema\": 1, \"rig\": tru".to_vec())
            .unwrap()
    };
    let pose = h.pose_despite(&point, &garbage);
    assert_at(&pose, &point);
    let health = h.health_until(&garbage, |h| h.rejected > 0);
    let e = health.last_error.unwrap();
    assert!(
        e.contains("stereoscope/demo/observations/cam0") && e.contains("JSON"),
        "{e}"
    );
    assert!(h.stop() >= 1);
}

/// The attacks a host on the network could make on fusion: an observation stamped an hour
/// ahead (it used to stop pose output for good), one of another rig, one with a blob more than
/// the limit, one with a NaN, a 10 MB payload and a 10 MB rig name. Each is refused before it changes
/// anything and counted by reason; poses from the good observations keep coming, and the
/// health report stays small.
#[test]
fn hostile_observations_are_refused_by_reason_and_poses_go_on() {
    let h = Harness::start('b');
    let point = Point3::new(0.05, -0.03, 0.6);
    let hour_ns = 3_600_000_000_000;
    let attacks = |h: &Harness| {
        let now = stereoscope_proto::messages::now_ns();
        let future = observation("cam0", h.px(0, &point), now + hour_ns);
        h.cams[0].put(&future).unwrap();
        let mut foreign = observation("cam0", h.px(0, &point), now);
        foreign.rig = "other".into();
        h.cams[0].put(&foreign).unwrap();
        let mut many = observation("cam1", h.px(1, &point), now);
        many.blobs = vec![many.blobs[0].clone(); limits::MAX_BLOBS + 1];
        h.cams[1].put(&many).unwrap();
        // JSON has no NaN: a NaN written out is not JSON (non-finite floats that do
        // decode, from postcard on iceoryx2, are `invalid`: proto's unit tests).
        let nan = String::from_utf8(observation("cam1", h.px(1, &point), now).to_json())
            .unwrap()
            .replacen("\"x_px\":", "\"x_px\":NaN,\"y\":", 1);
        h.cams[1].put_bytes(nan.into_bytes()).unwrap();
        h.cams[0].put_bytes(vec![b' '; 10 << 20]).unwrap();
        let mut long_name = observation("cam0", h.px(0, &point), now);
        long_name.rig = "r".repeat(10 << 20);
        h.cams[0].put(&long_name).unwrap();
    };
    let pose = h.pose_despite(&point, &attacks);
    assert_at(&pose, &point);
    // Still posing after the attacks, not stuck waiting behind the future observation.
    let again = h.pose_despite(&point, &|_: &Harness| {});
    assert!(again.sequence > pose.sequence);
    let reasons = ["future", "foreign", "invalid", "too_large", "undecodable"];
    let health = h.health_until(&attacks, |h| {
        reasons
            .iter()
            .all(|r| h.detail.contains_key(&format!("rejected.{r}")))
    });
    assert_eq!(
        health.detail.get("late").map(String::as_str),
        Some("0"),
        "{health:?}"
    );
    let size = health.to_json().len();
    assert!(size < 4096, "a health report of {size} bytes: {health:?}");
    assert!(h.stop() >= 2);
}
