//! Where a camera's frames come from, as a rig file describes it (`docs/services.md`,
//! "capture"): a V4L2 camera ([`v4l2`], Linux), a Y4M file or pipe ([`y4m`]), a PGM/PNG sequence
//! ([`images`]), or the synthetic scene ([`synthetic`], rendered with its ground truth). Each
//! is a [`FrameSource`]: the capture service publishes what it reads into shared memory, and
//! the benches, examples and offline processing read the same sources in process.

pub mod genicam;
pub mod images;
pub mod source;
pub mod synthetic;
#[cfg(target_os = "linux")]
pub mod v4l2;
pub mod y4m;

pub use source::{BadFrame, FrameSource, Read, SourceError};
use stereoscope_rig::schema::{ReplayClock, SourceSpec};
use stereoscope_rig::{Rig, RigError, RigErrorKind};

/// Why a camera's source could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error("camera {camera}: not a camera of the rig")]
    UnknownCamera { camera: String },
    #[error("camera {camera}: camera[{index}].source is missing: say where its frames come from")]
    NoSource { camera: String, index: usize },
    #[error(
        "camera {camera}: the source gives {}×{} frames but camera[{index}].image_size is {}×{}",
        .got_px.0, .got_px.1, .rig_px.0, .rig_px.1
    )]
    SizeMismatch {
        camera: String,
        index: usize,
        got_px: (u32, u32),
        rig_px: (u32, u32),
    },
    #[error("camera {camera}")]
    Source {
        camera: String,
        #[source]
        source: SourceError,
    },
    /// The rig asks for what this build cannot do.
    #[error("camera {camera}")]
    Unsupported {
        camera: String,
        #[source]
        source: RigError,
    },
}

/// Refuses a rig whose cameras among `cameras` need what this build lacks (V4L2 anywhere but
/// Linux): a configuration error, found before any service starts.
pub fn check_supported(rig: &Rig, cameras: &[String]) -> Result<(), OpenError> {
    for (i, c) in rig.spec.cameras.iter().enumerate() {
        if cfg!(not(target_os = "linux"))
            && cameras.contains(&c.id)
            && let Some(SourceSpec::V4l { device, .. }) = &c.source
        {
            return Err(no_v4l(rig, i, device));
        }
    }
    Ok(())
}

/// Camera `index` of `rig` wants V4L2 device `device`, which this build cannot open.
#[cfg_attr(target_os = "linux", allow(dead_code))]
fn no_v4l(rig: &Rig, index: usize, device: &str) -> OpenError {
    OpenError::Unsupported {
        camera: rig
            .cameras
            .get(index)
            .map(|c| c.id.clone())
            .unwrap_or_default(),
        source: RigError {
            kind: RigErrorKind::Value,
            file: rig.path.clone(),
            key: format!("camera[{index}].source"),
            message: format!(
                "{device}: V4L2 cameras are Linux's; this build is for {}",
                std::env::consts::OS
            ),
        },
    }
}

/// Opens camera `camera`'s source as the rig file describes it, and checks its frame size
/// against the rig's `image_size`.
pub fn open(rig: &Rig, camera: &str) -> Result<Box<dyn FrameSource>, OpenError> {
    open_in_run(rig, camera, None)
}

/// How long after a run's start its files' first frames are due: the launcher starts every
/// service within it.
pub const RUN_CLOCK_LEAD_NS: u64 = 2_000_000_000;

/// The replay clock a rig's Y4M files share in a run that started at `run_start_ns` (the
/// launcher's session): the earliest recorded time (`Xts`) of the first frames of the rig's
/// files this PC can read — every capture computes the same — played from `RUN_CLOCK_LEAD_NS`
/// after the start, each frame restamped (by its `Xts`, or by its index and the file's rate).
pub fn run_clock(rig: &Rig, run_start_ns: u64) -> ReplayClock {
    let recorded_ns = rig
        .spec
        .cameras
        .iter()
        .filter_map(|c| match &c.source {
            Some(SourceSpec::Y4m {
                path,
                replay_clock: None,
                ..
            }) => y4m::first_frame_timestamp(&rig.source_path(path)),
            _ => None,
        })
        .min()
        .unwrap_or(0);
    ReplayClock {
        recorded_ns,
        wall_ns: run_start_ns + RUN_CLOCK_LEAD_NS,
        speed: 1.0,
        restamp: true,
    }
}

/// [`open`], in a run that started at `run_start_ns` (`None`: not under a launcher). In a run,
/// a Y4M file paced in real time (`realtime`, the default, and not `repeat`) without a replay
/// clock of its own plays on [`run_clock`]: files recorded together stay in step by their
/// recorded times, and files without times by frame index, whatever the machine's load
/// (each frame waits for its moment worker); otherwise each capture would start its file at
/// its own moment and fusion pair frames a frame apart.
pub fn open_in_run(
    rig: &Rig,
    camera: &str,
    run_start_ns: Option<u64>,
) -> Result<Box<dyn FrameSource>, OpenError> {
    let index = rig
        .camera_index(camera)
        .ok_or_else(|| OpenError::UnknownCamera {
            camera: camera.to_string(),
        })?;
    let spec = &rig.spec.cameras[index];
    let src = spec.source.as_ref().ok_or_else(|| OpenError::NoSource {
        camera: camera.to_string(),
        index,
    })?;
    let wrap = |source: SourceError| OpenError::Source {
        camera: camera.to_string(),
        source,
    };
    let rel = |p: &str| rig.source_path(p).display().to_string();
    let source: Box<dyn FrameSource> = match src {
        SourceSpec::Synthetic {
            fps,
            loop_frames,
            bit_depth,
        } => Box::new(
            synthetic::SyntheticSource::new(
                &rig.spec,
                &rig.models,
                rig.cameras[index].camera,
                index,
                *fps,
                *loop_frames,
                *bit_depth,
            )
            .map_err(wrap)?,
        ),
        SourceSpec::Y4m {
            path,
            realtime,
            repeat,
            replay_clock,
        } => {
            let clock = match (replay_clock, run_start_ns) {
                (Some(c), _) => Some(*c),
                (None, Some(start)) if *realtime && !*repeat => Some(run_clock(rig, start)),
                (None, _) => None,
            };
            Box::new(
                y4m::Y4mSource::open(&rel(path), *realtime, *repeat)
                    .map_err(wrap)?
                    .with_replay_clock(clock),
            )
        }
        SourceSpec::Images {
            path,
            fps,
            realtime,
            repeat,
        } => {
            Box::new(images::ImageSource::open(&rel(path), *fps, *realtime, *repeat).map_err(wrap)?)
        }
        #[cfg(target_os = "linux")]
        SourceSpec::V4l {
            device,
            format,
            fps,
            exposure,
            gain,
            controls,
            readout_us,
        } => Box::new(
            v4l2::V4lSource::open(
                device,
                &v4l2::V4lRequest {
                    format: format.map(|f| f.fourcc()),
                    size_px: Some((spec.image_size[0], spec.image_size[1])),
                    fps: *fps,
                    exposure: *exposure,
                    gain: *gain,
                    controls: controls.iter().map(|(k, v)| (k.as_str(), v)).collect(),
                    readout_ns: readout_us.map(|us| (us * 1e3) as u64),
                },
            )
            .map_err(wrap)?,
        ),
        SourceSpec::Genicam {
            camera,
            format,
            fps,
            exposure_us,
            gain,
            timestamps,
            trigger,
            library,
        } => Box::new(
            genicam::GenicamSource::open(&genicam::GenicamRequest {
                camera: camera.clone(),
                size_px: (spec.image_size[0], spec.image_size[1]),
                format: match format {
                    None | Some(stereoscope_rig::schema::GenicamFormat::Mono8) => {
                        genicam::Mono::Eight
                    }
                    Some(stereoscope_rig::schema::GenicamFormat::Mono10) => genicam::Mono::Ten,
                    Some(stereoscope_rig::schema::GenicamFormat::Mono12) => genicam::Mono::Twelve,
                    Some(stereoscope_rig::schema::GenicamFormat::Mono16) => genicam::Mono::Sixteen,
                },
                fps: *fps,
                exposure_us: *exposure_us,
                gain_db: *gain,
                clock: match timestamps {
                    Some(stereoscope_rig::schema::GenicamClock::Ptp) => genicam::Clock::Ptp,
                    _ => genicam::Clock::Mapped,
                },
                trigger: trigger.as_deref().map(|t| match t {
                    "free" => genicam::Trigger::Free,
                    source => genicam::Trigger::Source(source.to_string()),
                }),
                library: library.clone(),
            })
            .map_err(wrap)?,
        ),
        #[cfg(not(target_os = "linux"))]
        SourceSpec::V4l { device, .. } => {
            return Err(no_v4l(rig, index, device));
        }
    };
    let (w, h) = source.size();
    let [rw, rh] = spec.image_size;
    if (w, h) != (rw, rh) {
        return Err(OpenError::SizeMismatch {
            camera: camera.to_string(),
            index,
            got_px: (w, h),
            rig_px: (rw, rh),
        });
    }
    Ok(source)
}
