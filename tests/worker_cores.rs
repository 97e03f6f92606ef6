//! The moment worker's cores (`docs/vision.md`, "Cores") against its windows read whole, on
//! the calibration test's wand (`tests/chain`): the worker's own frames, no processes. Its own
//! test binary: the calibration system tests beside it are sensitive to a loaded machine
//! (`docs/reliability.md`), and test binaries run one after another.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod chain;

use chain::ceiling;

/// The worker's cores (`docs/vision.md`, "Cores") change no observation: the four cameras'
/// frames of the wand's recording, with frames skipped as a loaded machine skips them, give
/// the same observations to a worker reading the cores first and to one reading the windows
/// whole, and most frames are settled by the cores.
#[test]
fn the_cores_change_no_observation_of_the_wand_with_frames_skipped() {
    use stereoscope_pipeline::worker::Worker;
    use stereoscope_proto::frame::{FrameHeader, PixelFormat};
    use stereoscope_sources::FrameSource;
    use stereoscope_sources::synthetic::SyntheticSource;
    let dir = std::env::temp_dir().join("stereoscope-cores-unused");
    let text = chain::scene_rig("chain", &ceiling(), 60.0, &dir, 7000, chain::WAND_SCENE);
    let rig = stereoscope_rig::Rig::from_toml(&text).unwrap();
    for cam in 0..rig.cameras.len() {
        let mut src = SyntheticSource::new(
            &rig.spec,
            &rig.models,
            rig.cameras[cam].camera,
            cam,
            60.0,
            None,
            None,
        )
        .unwrap();
        let settings = rig.worker_settings(cam).unwrap();
        assert!(settings.tracker.core_scan);
        let mut cored = Worker::new(settings.clone(), "chain", "cam").unwrap();
        let mut whole_settings = settings;
        whole_settings.tracker.core_scan = false;
        let mut whole = Worker::new(whole_settings, "chain", "cam").unwrap();
        let mut header = FrameHeader::new("cam", PixelFormat::Gray8, 320, 240).unwrap();
        let mut buf = vec![0u8; 320 * 240];
        let (mut seq, mut frames) = (0u64, 0u64);
        while seq < 1200 {
            src.read(seq, 1000.0 + seq as f64 / 60.0, &mut buf).unwrap();
            header.sequence = seq;
            let a = cored.process_frame(&header, &buf).unwrap();
            let b = whole.process_frame(&header, &buf).unwrap();
            assert_eq!(
                format!("{:?}", a.blobs),
                format!("{:?}", b.blobs),
                "cam{cam} frame {seq}"
            );
            frames += 1;
            // Two frames in five are followed by a skipped one, in a fixed pattern.
            seq += 1 + (seq * 7919 % 5) / 3;
        }
        let (settled, widened) = cored.core_scans();
        assert!(
            settled * 10 > frames * 8,
            "cam{cam}: {settled} of {frames} settled"
        );
        assert_eq!(whole.core_scans(), (0, 0));
        println!("cam{cam}: {frames} frames, cores settled {settled}, widened {widened}");
    }
}
