//! The checks of a rig file that its types cannot express: names that become network keys,
//! hosts that exist, sources whose files are there, and bounds on every number that sizes
//! memory or time (image sizes, frames held in memory, rates, waits, grey levels, counts).
//! Everything a service would refuse later is refused here, at load, so a mistake in the file
//! stops `stereoscope run` at once instead of failing a service on every restart.

use crate::error::{RigError, err};
use crate::schema::{BodySpec, MotionSpec, RigFile, SourceSpec, SyntheticSpec, TargetShape};
use std::collections::HashSet;
use std::path::Path;
use stereoscope_proto::names::valid_segment;

/// Longest side of a camera image, pixels (the moment engine's limit).
pub const MAX_SIDE_PX: u32 = stereoscope_vision::image::MAX_SIDE_PX;
/// Most pixels of one camera image (32 MP: 64 MB a 16-bit frame in shared memory).
pub const MAX_PIXELS: u64 = 32 * 1024 * 1024;
/// Most bytes a synthetic camera's `loop_frames` may hold in memory.
pub const MAX_LOOP_BYTES: u64 = 1 << 30;
/// Frame rates a source may ask for, frames per second.
pub const FPS_RANGE: (f64, f64) = (0.01, 10_000.0);
/// Longest wait or timeout in `[fusion]`, milliseconds (one minute).
pub const MAX_WAIT_MS: f64 = 60_000.0;
/// Longest time fusion keeps an unseen object, seconds (one hour).
pub const MAX_DROP_AFTER_S: f64 = 3_600.0;
/// Largest pixel tolerance in `[fusion]`.
pub const MAX_TOLERANCE_PX: f64 = 10_000.0;
/// Fastest serial line, baud.
pub const MAX_BAUD: u32 = 4_000_000;
/// Fastest replay, times the recorded pace.
pub const MAX_REPLAY_SPEED: f64 = 1_000.0;

fn in_range(key: &str, v: f64, lo: f64, hi: f64, what: &str) -> Result<(), RigError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(err(
            key,
            format!("{v:?} {what} must be between {lo} and {hi}"),
        ))
    }
}

fn fps_in_range(key: &str, fps: f64) -> Result<(), RigError> {
    in_range(key, fps, FPS_RANGE.0, FPS_RANGE.1, "frames per second")
}

fn positive_at_most(key: &str, v: f64, hi: f64, what: &str) -> Result<(), RigError> {
    if v.is_finite() && v > 0.0 && v <= hi {
        Ok(())
    } else {
        Err(err(
            key,
            format!("{v:?} {what} must be above 0 and at most {hi}"),
        ))
    }
}

fn finite(key: &str, v: &[f64]) -> Result<(), RigError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(err(key, format!("{v:?} must be finite numbers")))
    }
}

fn segment(key: &str, v: &str, what: &str) -> Result<(), RigError> {
    if valid_segment(v) {
        Ok(())
    } else {
        Err(err(
            key,
            format!("{v:?} must be 1–32 characters of letters, digits, '_' or '-' ({what})"),
        ))
    }
}

/// A source file relative to the rig file's folder (`base`), or as given when absolute.
pub fn resolve(base: Option<&Path>, p: &str) -> std::path::PathBuf {
    let path = Path::new(p);
    match base {
        Some(b) if !path.is_absolute() && p != "-" => b.join(path),
        _ => path.to_path_buf(),
    }
}

fn readable_source(key: &str, path: &Path, folder_ok: bool) -> Result<(), RigError> {
    let meta = std::fs::metadata(path).map_err(|e| err(key, format!("{}: {e}", path.display())))?;
    if meta.is_dir() {
        if !folder_ok {
            return Err(err(
                key,
                format!("{} is a folder, not a file", path.display()),
            ));
        }
        let images = std::fs::read_dir(path)
            .map_err(|e| err(key, format!("{}: {e}", path.display())))?
            .filter_map(|e| e.ok())
            .any(|e| {
                let p = e.path();
                let ext = p
                    .extension()
                    .and_then(|x| x.to_str())
                    .map(str::to_ascii_lowercase);
                matches!(ext.as_deref(), Some("pgm" | "png"))
            });
        if !images {
            return Err(err(
                key,
                format!("{} holds no .pgm or .png file", path.display()),
            ));
        }
    } else if meta.is_file() {
        // A FIFO (ffmpeg's pipe) is not opened here: that would block until its writer starts.
        std::fs::File::open(path).map_err(|e| err(key, format!("{}: {e}", path.display())))?;
    }
    Ok(())
}

/// The brightest grey level a camera's source delivers: 255 for sources known to be 8-bit,
/// 65535 for the others (PGM, PNG and Y4M files may hold either).
pub(crate) fn max_level(source: Option<&SourceSpec>) -> u32 {
    match bits_of(source) {
        Some(8) => 255,
        _ => 65535,
    }
}

fn bits_of(source: Option<&SourceSpec>) -> Option<u32> {
    match source {
        Some(SourceSpec::Synthetic { bit_depth, .. }) => Some(bit_depth.unwrap_or(8)),
        Some(SourceSpec::V4l {
            format: Some(f), ..
        }) => Some(f.bits()),
        Some(SourceSpec::Genicam { format, .. }) => Some(match format {
            None | Some(crate::schema::GenicamFormat::Mono8) => 8,
            Some(_) => 16,
        }),
        _ => None,
    }
}

/// The most controls one camera's source sets.
pub const MAX_CONTROLS: usize = 64;

/// Checks everything of `file` but its cameras' optics (`cameras.rs`); `base` is the rig
/// file's folder, where relative source paths start.
/// The rig's bodies in metres, as the bodies library takes them.
pub fn body_defs(file: &RigFile) -> Vec<stereoscope_bodies::BodyDef> {
    let m = file.units.metres();
    file.bodies
        .iter()
        .map(|b| stereoscope_bodies::BodyDef {
            name: b.name.clone(),
            markers_m: b
                .markers
                .iter()
                .map(|p| nalgebra::Point3::new(p[0] * m, p[1] * m, p[2] * m))
                .collect(),
            tolerance_m: b.tolerance.map_or(0.003, |t| t * m),
        })
        .collect()
}

/// Every body usable and none ambiguous (`stereoscope_bodies::check_bodies`), the error naming
/// the body's key.
fn check_bodies(file: &RigFile) -> Result<(), RigError> {
    for (i, b) in file.bodies.iter().enumerate() {
        segment(
            &format!("body[{i}].name"),
            &b.name,
            "it is part of network keys",
        )?;
    }
    let defs = body_defs(file);
    stereoscope_bodies::check_bodies(&defs).map_err(|e| {
        use stereoscope_bodies::BodyError as E;
        let name = match &e {
            E::MarkerCount { body, .. }
            | E::NotFinite { body, .. }
            | E::Tolerance { body, .. }
            | E::TooClose { body, .. }
            | E::Collinear { body, .. } => body.clone(),
            E::DuplicateName(n) => n.clone(),
            E::Ambiguous(a) => a.body.clone(),
        };
        let i = file.bodies.iter().position(|b| b.name == name).unwrap_or(0);
        err(format!("body[{i}]"), e.to_string())
    })
}

/// Most consecutive sets a new object may be required to be seen in before it is published.
pub const MAX_CONFIRM_SETS: u32 = 120;

pub(crate) fn check(file: &RigFile, base: Option<&Path>, sources: bool) -> Result<(), RigError> {
    segment("name", &file.name, "it is part of network keys")?;
    let mut seen = HashSet::new();
    for (i, h) in file.hosts.iter().enumerate() {
        segment(
            &format!("host[{i}].name"),
            &h.name,
            "it is part of network keys",
        )?;
        if !seen.insert(h.name.as_str()) {
            return Err(err(
                format!("host[{i}].name"),
                format!("{:?} appears twice", h.name),
            ));
        }
        if let Some(p) = &h.iceoryx2_prefix
            && (p.is_empty()
                || p.len() > 32
                || !p
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-'))
        {
            return Err(err(
                format!("host[{i}].iceoryx2_prefix"),
                format!("{p:?} must be 1–32 characters of letters, digits, '_' or '-'"),
            ));
        }
    }
    crate::security::check_hosts(file)?;
    check_bodies(file)?;
    crate::vr::settings(file)?;
    let known_host = |key: String, h: &Option<String>| -> Result<(), RigError> {
        match h {
            Some(h) if !file.hosts.iter().any(|x| &x.name == h) => Err(err(
                key,
                format!(
                    "{h:?} is not a [[host]] of this rig (hosts: {:?})",
                    file.hosts.iter().map(|h| &h.name).collect::<Vec<_>>()
                ),
            )),
            None if file.hosts.len() > 1 => Err(err(
                key,
                "missing; with several [[host]] sections every camera, [fusion], [[serial]] and [recorder] must name its host",
            )),
            _ => Ok(()),
        }
    };
    let mut ids = HashSet::new();
    let mut devices = HashSet::new();
    for (i, c) in file.cameras.iter().enumerate() {
        let key = format!("camera[{i}]");
        segment(&format!("{key}.id"), &c.id, "it is part of network keys")?;
        if !ids.insert(c.id.as_str()) {
            return Err(err(
                format!("{key}.id"),
                format!("{:?} appears twice", c.id),
            ));
        }
        known_host(format!("{key}.host"), &c.host)?;
        let [w, h] = c.image_size;
        if w == 0
            || h == 0
            || w > MAX_SIDE_PX
            || h > MAX_SIDE_PX
            || w as u64 * h as u64 > MAX_PIXELS
        {
            return Err(err(
                format!("{key}.image_size"),
                format!(
                    "[{w}, {h}]: each side must be 1 to {MAX_SIDE_PX} pixels and the image at most {MAX_PIXELS} pixels"
                ),
            ));
        }
        let fps_key = format!("{key}.source.fps");
        match &c.source {
            Some(SourceSpec::Synthetic {
                fps,
                loop_frames,
                bit_depth,
            }) => {
                fps_in_range(&fps_key, *fps)?;
                if file.synthetic.is_none() {
                    return Err(err(
                        format!("{key}.source"),
                        "a synthetic camera needs a [synthetic] scene",
                    ));
                }
                if let Some(b) = bit_depth
                    && *b != 8
                    && *b != 16
                {
                    return Err(err(
                        format!("{key}.source.bit_depth"),
                        format!("{b} is not 8 or 16"),
                    ));
                }
                if let Some(n) = loop_frames {
                    let bytes =
                        *n as u64 * w as u64 * h as u64 * (bit_depth.unwrap_or(8) / 8) as u64;
                    if *n == 0 || bytes > MAX_LOOP_BYTES {
                        return Err(err(
                            format!("{key}.source.loop_frames"),
                            format!(
                                "{n} must be at least 1, and hold at most {} MiB of frames ({} MiB asked)",
                                MAX_LOOP_BYTES >> 20,
                                bytes >> 20
                            ),
                        ));
                    }
                }
            }
            Some(SourceSpec::Images { fps, path, .. }) => {
                fps_in_range(&fps_key, *fps)?;
                if sources {
                    readable_source(&format!("{key}.source.path"), &resolve(base, path), true)?;
                }
            }
            Some(SourceSpec::Y4m {
                path, replay_clock, ..
            }) => {
                if sources && path != "-" {
                    readable_source(&format!("{key}.source.path"), &resolve(base, path), false)?;
                }
                if let Some(c) = replay_clock {
                    positive_at_most(
                        &format!("{key}.source.replay_clock.speed"),
                        c.speed,
                        MAX_REPLAY_SPEED,
                        "times the recorded pace",
                    )?;
                }
            }
            Some(SourceSpec::V4l {
                fps,
                device,
                controls,
                readout_us,
                ..
            }) => {
                if let Some(r) = readout_us
                    && !(r.is_finite() && (0.0..=1_000_000.0).contains(r))
                {
                    return Err(err(
                        format!("{key}.source.readout_us"),
                        format!("{r} must be from 0 to 1 s (1000000 µs)"),
                    ));
                }
                if let Some(f) = fps {
                    fps_in_range(&fps_key, *f)?;
                }
                if controls.len() > MAX_CONTROLS {
                    return Err(err(
                        format!("{key}.source.controls"),
                        format!("{} controls; at most {MAX_CONTROLS}", controls.len()),
                    ));
                }
                for name in controls.keys() {
                    let ok = !name.is_empty()
                        && name.len() <= 32
                        && name
                            .bytes()
                            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
                    if !ok {
                        return Err(err(
                            format!("{key}.source.controls.{name}"),
                            "a control's name as `v4l2-ctl --list-ctrls` shows it: lower case, \
                             digits and _, at most 32 characters"
                                .to_string(),
                        ));
                    }
                }
                if !devices.insert((c.host.as_deref(), device.as_str())) {
                    return Err(err(
                        format!("{key}.source.device"),
                        format!("{device:?} is already another camera's on this host"),
                    ));
                }
            }
            Some(SourceSpec::Genicam {
                camera,
                fps,
                exposure_us,
                gain,
                trigger,
                ..
            }) => {
                if let Some(t) = trigger {
                    if t.is_empty() || t.contains('\0') || t.len() > 64 {
                        return Err(err(
                            format!("{key}.source.trigger"),
                            format!(
                                "{t:?}: \"free\", or a trigger source the camera lists (\"Line1\", \"Software\")"
                            ),
                        ));
                    }
                    if t == "Software" && fps.is_none() {
                        return Err(err(
                            format!("{key}.source.trigger"),
                            "\"Software\" needs the source's fps: how often the capture fires the trigger".to_string(),
                        ));
                    }
                }
                if let Some(f) = fps {
                    fps_in_range(&fps_key, *f)?;
                }
                if let Some(x) = exposure_us
                    && !(x.is_finite() && *x > 0.0 && *x <= 10_000_000.0)
                {
                    return Err(err(
                        format!("{key}.source.exposure_us"),
                        format!("{x} must be above 0 and at most 10 s (10000000 µs)"),
                    ));
                }
                if let Some(g) = gain
                    && !g.is_finite()
                {
                    return Err(err(
                        format!("{key}.source.gain"),
                        format!("{g} is not a number"),
                    ));
                }
                if camera.is_empty() || camera.contains('\0') {
                    return Err(err(
                        format!("{key}.source.camera"),
                        format!("{camera:?}: an Aravis device id or the camera's address"),
                    ));
                }
                if !devices.insert((c.host.as_deref(), camera.as_str())) {
                    return Err(err(
                        format!("{key}.source.camera"),
                        format!("{camera:?} is already another camera's on this host"),
                    ));
                }
            }
            None => {}
        }
    }
    if let Some(f) = &file.fusion {
        known_host("fusion.host".into(), &f.host)?;
        if let (true, Some(p)) = (sources, &f.replay_sets) {
            readable_source("fusion.replay_sets", &resolve(base, p), false)?;
        }
        for (k, v, hi, what) in [
            ("max_skew_ms", f.max_skew_ms, MAX_WAIT_MS, "ms"),
            ("max_wait_ms", f.max_wait_ms, MAX_WAIT_MS, "ms"),
            ("camera_timeout_ms", f.camera_timeout_ms, MAX_WAIT_MS, "ms"),
            ("clock_window_ms", f.clock_window_ms, MAX_WAIT_MS, "ms"),
            ("body_hold_ms", f.body_hold_ms, MAX_WAIT_MS, "ms"),
            (
                "max_epipolar_px",
                f.max_epipolar_px,
                MAX_TOLERANCE_PX,
                "pixels",
            ),
            (
                "max_residual_px",
                f.max_residual_px,
                MAX_TOLERANCE_PX,
                "pixels",
            ),
            ("drop_after_s", f.drop_after_s, MAX_DROP_AFTER_S, "s"),
            // 1 km in metres, in the file's unit.
            (
                "association_gate",
                f.association_gate,
                1000.0 / file.units.metres(),
                file.units.symbol(),
            ),
        ] {
            if let Some(v) = v {
                positive_at_most(&format!("fusion.{k}"), v, hi, what)?;
            }
        }
        if let Some(v) = &f.volume {
            finite("fusion.volume.min", &v.min)?;
            finite("fusion.volume.max", &v.max)?;
            if (0..3).any(|i| v.min[i] >= v.max[i]) {
                return Err(err(
                    "fusion.volume",
                    format!(
                        "min {:?} must be below max {:?} on every axis",
                        v.min, v.max
                    ),
                ));
            }
        }
        if let Some(n) = f.confirm_sets
            && !(1..=MAX_CONFIRM_SETS).contains(&n)
        {
            return Err(err(
                "fusion.confirm_sets",
                format!("{n} is not between 1 and {MAX_CONFIRM_SETS}"),
            ));
        }
        if let Some(n) = f.min_views_to_start {
            let cameras = file.cameras.len();
            if n < 2 {
                return Err(err(
                    "fusion.min_views_to_start",
                    format!("{n} is under 2: a point is triangulated from two cameras or more"),
                ));
            }
            if n as usize > cameras.max(2) {
                return Err(err(
                    "fusion.min_views_to_start",
                    format!(
                        "{n} is more than the rig's {cameras} cameras: no marker would ever start"
                    ),
                ));
            }
        }
    }
    let mut ports = HashSet::new();
    for (i, s) in file.serial.iter().enumerate() {
        known_host(format!("serial[{i}].host"), &s.host)?;
        if let Some(b) = s.baud
            && !(1..=MAX_BAUD).contains(&b)
        {
            return Err(err(
                format!("serial[{i}].baud"),
                format!("{b} is not between 1 and {MAX_BAUD}"),
            ));
        }
        if !ports.insert((s.host.as_deref(), s.port.as_str())) {
            return Err(err(
                format!("serial[{i}].port"),
                format!(
                    "{:?} is already another [[serial]] output's on this host",
                    s.port
                ),
            ));
        }
    }
    if let Some(v) = &file.vr {
        known_host("vr.host".into(), &v.host)?;
    }
    if let Some(r) = &file.realtime
        && !(1..=98).contains(&r.priority)
    {
        return Err(err(
            "realtime.priority",
            format!("{} is not between 1 and 98", r.priority),
        ));
    }
    if let Some(v) = &file.viewer {
        known_host("viewer.host".into(), &v.host)?;
        if let Some(l) = &v.listen
            && l.parse::<std::net::SocketAddr>().is_err()
        {
            return Err(err(
                "viewer.listen",
                format!("{l:?} is not an address and port such as \"127.0.0.1:8750\""),
            ));
        }
        if let Some(m) = v.max_clients
            && !(1..=256).contains(&m)
        {
            return Err(err(
                "viewer.max_clients",
                format!("{m} is not between 1 and 256"),
            ));
        }
    }
    if let Some(r) = &file.recorder {
        known_host("recorder.host".into(), &r.host)?;
        if r.folder.trim().is_empty() {
            return Err(err("recorder.folder", "is empty: say where sessions go"));
        }
        if let Some(f) = r.flush_ms
            && !(1..=60_000).contains(&f)
        {
            return Err(err(
                "recorder.flush_ms",
                format!("{f} is not between 1 and 60000"),
            ));
        }
        for (i, cam) in r.frames.iter().enumerate() {
            let on_host = file
                .cameras
                .iter()
                .find(|c| &c.id == cam)
                .map(|c| c.host.as_deref() == r.host.as_deref() || c.host.is_none());
            match on_host {
                None => {
                    return Err(err(
                        format!("recorder.frames[{i}]"),
                        format!("{cam:?} is not a camera of the rig"),
                    ));
                }
                Some(false) => {
                    return Err(err(
                        format!("recorder.frames[{i}]"),
                        format!(
                            "camera {cam:?} is on another host than the recorder: frames are read from this PC's shared memory"
                        ),
                    ));
                }
                Some(true) => {}
            }
        }
    }
    if let Some(s) = &file.synthetic {
        check_synthetic(s, &file.bodies, &file.models)?;
    }
    Ok(())
}

fn check_synthetic(
    s: &SyntheticSpec,
    bodies: &[BodySpec],
    models: &[crate::schema::ModelSpec],
) -> Result<(), RigError> {
    for (k, v, hi) in [
        ("noise_sigma", s.noise_sigma, 1000.0),
        ("blur_sigma_px", s.blur_sigma_px, 100.0),
        ("background", s.background, 65535.0),
    ] {
        if let Some(v) = v {
            in_range(&format!("synthetic.{k}"), v, 0.0, hi, "")?;
        }
    }
    if let Some(n) = s.samples
        && !(1..=16).contains(&n)
    {
        return Err(err(
            "synthetic.samples",
            format!("{n} is not between 1 and 16"),
        ));
    }
    for (i, t) in s.targets.iter().enumerate() {
        let key = format!("synthetic.target[{i}]");
        positive_at_most(&format!("{key}.radius"), t.radius, 1e6, "")?;
        if let Some(c) = t.contrast {
            in_range(
                &format!("{key}.contrast"),
                c,
                -65535.0,
                65535.0,
                "grey levels",
            )?;
        }
        let mkey = format!("{key}.motion");
        match &t.motion {
            MotionSpec::Static {
                position,
                heading_deg,
            } => {
                finite(&format!("{mkey}.position"), position)?;
                finite(&format!("{mkey}.heading_deg"), &[*heading_deg])?;
            }
            MotionSpec::Line { from, to, period_s } => {
                finite(&format!("{mkey}.from"), from)?;
                finite(&format!("{mkey}.to"), to)?;
                positive_at_most(&format!("{mkey}.period_s"), *period_s, 1e6, "s")?;
            }
            MotionSpec::Circle {
                centre,
                radius,
                period_s,
            } => {
                finite(&format!("{mkey}.centre"), centre)?;
                finite(&format!("{mkey}.radius"), &[*radius])?;
                positive_at_most(&format!("{mkey}.period_s"), *period_s, 1e6, "s")?;
            }
            MotionSpec::Spin {
                position,
                deg_per_s,
            } => {
                finite(&format!("{mkey}.position"), position)?;
                finite(&format!("{mkey}.deg_per_s"), &[*deg_per_s])?;
            }
            MotionSpec::Wander { centre, extent, .. } => {
                finite(&format!("{mkey}.centre"), centre)?;
                finite(&format!("{mkey}.extent"), extent)?;
            }
            MotionSpec::Joints {
                base,
                base_rpy_deg,
                swing,
                hide,
            } => {
                if let Some(h) = hide {
                    let hkey = format!("{mkey}.hide");
                    positive_at_most(&format!("{hkey}.every_s"), h.every_s, 1e6, "s")?;
                    positive_at_most(&format!("{hkey}.for_s"), h.for_s, h.every_s, "s")?;
                }
                finite(&format!("{mkey}.base"), base)?;
                finite(&format!("{mkey}.base_rpy_deg"), base_rpy_deg)?;
                for (k, w) in swing.iter().enumerate() {
                    finite(&format!("{mkey}.swing[{k}]"), w)?;
                    in_range(&format!("{mkey}.swing[{k}]"), w[2], 0.0, 1000.0, "Hz")?;
                }
                if t.shape != TargetShape::Model {
                    return Err(err(
                        format!("{mkey}.kind"),
                        "\"joints\" moves a target of shape \"model\" only",
                    ));
                }
            }
            MotionSpec::Head {
                centre,
                radius,
                period_s,
                turn_period_s,
                nod_deg,
            } => {
                finite(&format!("{mkey}.centre"), centre)?;
                finite(&format!("{mkey}.radius"), &[*radius])?;
                positive_at_most(&format!("{mkey}.period_s"), *period_s, 1e6, "s")?;
                positive_at_most(&format!("{mkey}.turn_period_s"), *turn_period_s, 1e6, "s")?;
                in_range(&format!("{mkey}.nod_deg"), *nod_deg, 0.0, 80.0, "degrees")?;
            }
        }
        match (t.shape, &t.grid) {
            (TargetShape::DotGrid, None) => {
                return Err(err(
                    format!("{key}.grid"),
                    "missing: a target of shape \"dot_grid\" gives { cols, rows, spacing }",
                ));
            }
            (TargetShape::DotGrid, Some(g)) => {
                if !(2..=40).contains(&g.cols) || !(2..=40).contains(&g.rows) {
                    return Err(err(
                        format!("{key}.grid"),
                        format!("{} x {} dots: 2 to 40 each way", g.cols, g.rows),
                    ));
                }
                positive_at_most(&format!("{key}.grid.spacing"), g.spacing, 1e6, "units")?;
                if !(t.radius > 0.0 && t.radius < g.spacing / 3.0) {
                    return Err(err(
                        format!("{key}.radius"),
                        format!(
                            "{}: a dot's radius is above 0 and under a third of the spacing ({})",
                            t.radius, g.spacing
                        ),
                    ));
                }
            }
            (_, Some(_)) => {
                return Err(err(
                    format!("{key}.grid"),
                    "only a target of shape \"dot_grid\" has a grid",
                ));
            }
            (_, None) => {}
        }
        match (t.shape, &t.model) {
            (TargetShape::Model, Some(name)) if !models.iter().any(|m| &m.name == name) => {
                return Err(err(
                    format!("{key}.model"),
                    format!(
                        "{name:?} is not a [[model]] of this rig (models: {:?})",
                        models.iter().map(|m| &m.name).collect::<Vec<_>>()
                    ),
                ));
            }
            (TargetShape::Model, None) => {
                return Err(err(
                    format!("{key}.model"),
                    "missing: a target of shape \"model\" names the [[model]] whose markers it carries",
                ));
            }
            (TargetShape::Model, Some(_)) => {
                if !matches!(t.motion, MotionSpec::Joints { .. }) {
                    return Err(err(
                        format!("{key}.motion"),
                        "a target of shape \"model\" moves by { kind = \"joints\", base, swing }",
                    ));
                }
            }
            (_, Some(_)) => {
                return Err(err(
                    format!("{key}.model"),
                    "only a target of shape \"model\" carries a model's markers",
                ));
            }
            (_, None) => {}
        }
        match (t.shape, &t.body) {
            (TargetShape::Body, Some(name)) if !bodies.iter().any(|b| &b.name == name) => {
                return Err(err(
                    format!("{key}.body"),
                    format!(
                        "{name:?} is not a [[body]] of this rig (bodies: {:?})",
                        bodies.iter().map(|b| &b.name).collect::<Vec<_>>()
                    ),
                ));
            }
            (TargetShape::Body, None) => {
                return Err(err(
                    format!("{key}.body"),
                    "missing: a target of shape \"body\" names the [[body]] whose markers it carries",
                ));
            }
            (TargetShape::Body, Some(_)) => {}
            (_, Some(_)) => {
                return Err(err(
                    format!("{key}.body"),
                    "only a target of shape \"body\" carries a body's markers",
                ));
            }
            (_, None) => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    fn rig(source: &str) -> String {
        format!(
            "name = \"t\"\nunits = \"mm\"\n[[camera]]\nid = \"c\"\nimage_size = [640, 480]\n\
             focal_length_mm = 4.0\npixel_pitch_um = [3.0, 3.0]\n\
             pose = {{ position = [0.0, 0.0, 2000.0], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }}\n\
             source = {source}\n"
        )
    }

    #[test]
    fn v4l2_controls_are_named_as_v4l2_ctl_names_them() {
        let ok = crate::Rig::from_toml(&rig(
            "{ kind = \"v4l\", device = \"/dev/video0\", controls = { white_balance_automatic = false, \
             power_line_frequency = \"Disabled\", brightness = 12 } }",
        ))
        .unwrap();
        let Some(crate::schema::SourceSpec::V4l { controls, .. }) = &ok.spec.cameras[0].source
        else {
            panic!("not a V4L2 source")
        };
        assert_eq!(
            controls.get("brightness"),
            Some(&crate::schema::ControlValue::Integer(12))
        );
        assert_eq!(
            controls.get("white_balance_automatic"),
            Some(&crate::schema::ControlValue::Bool(false))
        );
        let e = crate::Rig::from_toml(&rig(
            "{ kind = \"v4l\", device = \"/dev/video0\", controls = { \"White Balance\" = 1 } }",
        ))
        .unwrap_err();
        assert_eq!(e.key, "camera[0].source.controls.White Balance", "{e}");
    }
}

#[cfg(test)]
mod dot_grid_tests {
    fn rig(target: &str) -> String {
        format!(
            "name = \"t\"\nunits = \"cm\"\n[[camera]]\nid = \"c\"\nimage_size = [640, 480]\n\
             focal_length_mm = 4.0\npixel_pitch_um = [3.0, 3.0]\n\
             pose = {{ position = [0.0, 0.0, 200.0], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }}\n\
             source = {{ kind = \"synthetic\", fps = 30.0 }}\n[synthetic]\n[[synthetic.target]]\n{target}\n\
             motion = {{ kind = \"static\", position = [0.0, 0.0, 100.0] }}\n"
        )
    }

    #[test]
    fn a_dot_grid_target_needs_its_grid_and_dots_that_fit_it() {
        crate::Rig::from_toml(&rig(
            "shape = \"dot_grid\"\nradius = 0.5\ngrid = { cols = 7, rows = 5, spacing = 2.7 }",
        ))
        .unwrap();
        let key = |t: &str| crate::Rig::from_toml(&rig(t)).unwrap_err().key;
        assert_eq!(
            key("shape = \"dot_grid\"\nradius = 0.5"),
            "synthetic.target[0].grid"
        );
        assert_eq!(
            key("shape = \"dot_grid\"\nradius = 1.0\ngrid = { cols = 7, rows = 5, spacing = 2.7 }"),
            "synthetic.target[0].radius"
        );
        assert_eq!(
            key("shape = \"dot_grid\"\nradius = 0.5\ngrid = { cols = 1, rows = 5, spacing = 2.7 }"),
            "synthetic.target[0].grid"
        );
        assert_eq!(
            key("shape = \"sphere\"\nradius = 0.5\ngrid = { cols = 7, rows = 5, spacing = 2.7 }"),
            "synthetic.target[0].grid"
        );
    }
}
