//! `stereoscope replay` and `stereoscope export`.
//!
//! Replay re-runs fusion (`stereoscope_pipeline::Fusion`, the same code the service runs) on the
//! recorded observations, grouped into exactly the sets the live fusion used (each recorded
//! pose frame names its cameras and time), and compares every pose with the recorded one; and
//! it can publish the recorded observations back on Zenoh, at recorded speed or as fast as
//! possible, for a running fusion and any other subscriber.

use crate::session::{BODIES_CSV_HEADER, POSES_CSV_HEADER, Session, body_csv_rows, csv_rows};
use std::collections::HashMap;
use stereoscope_pipeline::Fusion;
use stereoscope_proto::messages::{Observation, PoseFrame};
use stereoscope_rig::Rig;

/// Why a session cannot be replayed or exported.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("session.json rig_file")]
    Rig(#[from] stereoscope_rig::RigError),
    #[error("pose frame {sequence}: camera {camera:?} is not in the rig")]
    UnknownCamera { sequence: u64, camera: String },
    #[error(
        "poses.jsonl: {0} pose frame time(s); a C3D file needs at least two to have a frame rate"
    )]
    TooFewTimes(usize),
    #[error(
        "poses.jsonl: {frames} frames of {period_ns} ns: the session's times are too far apart for one C3D file"
    )]
    TooLong { frames: f64, period_ns: u64 },
    #[error(
        "poses.jsonl: {frames} frames × {points} points would make a C3D file of {} MB, over the {} MB this export writes (a session with this many objects over this long is not one trial)",
        .frames * .points * 16 / 1_000_000,
        MAX_C3D_CELLS * 16 / 1_000_000
    )]
    TooLarge { frames: usize, points: usize },
    #[error(
        "no recorded frames: {} (record with --frames and every camera; without --frames, replay re-fuses the recorded observations)",
        .0.join(", ")
    )]
    NoFrames(Vec<String>),
    #[error("the replay rig")]
    Encode(#[from] toml::ser::Error),
}

/// What re-fusing a session gave.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Refused {
    pub frames: usize,
    /// Pose frames whose every pose came out identical (positions, velocities, headings,
    /// methods, cameras, residuals, body labels) and every rigid body too, objects paired by position and their ids by one
    /// consistent renumbering.
    pub identical: usize,
    /// The last re-fused frames that are all identical: where a replay of a recording that
    /// began mid-run (fusion's state starts afresh) has converged to the live system.
    pub identical_last_frames: usize,
    /// Recorded object id → re-fused id, where they differ (a recording that began mid-run:
    /// fusion numbers its objects afresh).
    pub renumbered: Vec<(u32, u32)>,
    /// The first difference, in words.
    pub first_difference: Option<String>,
    /// Pose frames whose observations the session lacks (recorded after the frame).
    pub incomplete: usize,
    /// Pose frames fusion published and the recording lacks (gaps in the sequence numbers: the
    /// recorder did not receive them), whose sets were formed again from the recorded
    /// observations between their neighbours and fused in their place, so fusion's state
    /// stays the live one's.
    pub reformed: Vec<u64>,
    /// Gaps in the sequence numbers that could not be formed again (first, last missing): the
    /// observations between the neighbours do not make as many sets as are missing (a fusion
    /// that restarted, or observations lost with the poses). Frames after one may differ.
    pub gaps: Vec<(u64, u64)>,
    /// Objects whose undirected heading (an axis, [`Pose::heading_directed`] false) points the
    /// other way along the same axis: the sense is chosen when fusion first sees an object, so
    /// a replay of a recording that began after fusion started may choose the other one. Such
    /// poses count as reproduced.
    ///
    /// [`Pose::heading_directed`]: stereoscope_proto::messages::Pose::heading_directed
    pub heading_reversed: Vec<u32>,
}

/// Compares a re-fused pose frame with the recorded one: objects paired by position, ids
/// through `ids` (recorded → re-fused, extended on first sight). `None` when identical, else
/// what differs, in words.
fn differs(
    recorded: &PoseFrame,
    replayed: &[stereoscope_proto::messages::Pose],
    ids: &mut HashMap<u32, u32>,
    reversed: &mut std::collections::BTreeSet<u32>,
) -> Option<String> {
    let at = |p: &[f64; 3]| format!("[{:.4}, {:.4}, {:.4}] m", p[0], p[1], p[2]);
    let frame = format!(
        "pose frame {} (t = {} ns)",
        recorded.sequence, recorded.timestamp_ns
    );
    if recorded.poses.len() != replayed.len() {
        return Some(format!(
            "{frame}: {} objects recorded, {} re-fused",
            recorded.poses.len(),
            replayed.len()
        ));
    }
    let dist = |a: &[f64; 3], b: &[f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    let mut used = vec![false; replayed.len()];
    for r in &recorded.poses {
        let Some((j, p)) = replayed
            .iter()
            .enumerate()
            .filter(|(j, _)| !used[*j])
            .min_by(|a, b| {
                dist(&a.1.position_m, &r.position_m)
                    .total_cmp(&dist(&b.1.position_m, &r.position_m))
            })
        else {
            return Some(format!(
                "{frame}: object {} has no re-fused counterpart",
                r.object_id
            ));
        };
        used[j] = true;
        let mapped = *ids.entry(r.object_id).or_insert(p.object_id);
        let who = format!(
            "{frame}: object {} (re-fused as {})",
            r.object_id, p.object_id
        );
        if mapped != p.object_id {
            return Some(format!(
                "{who}: earlier frames re-fused it as object {mapped}"
            ));
        }
        if p.position_m != r.position_m {
            return Some(format!(
                "{who}: at {} recorded, {} re-fused ({:.3} mm apart)",
                at(&r.position_m),
                at(&p.position_m),
                dist(&r.position_m, &p.position_m) * 1e3
            ));
        }
        let mut heading_deg = p.heading_deg;
        if heading_deg != r.heading_deg
            && !r.heading_directed
            && !p.heading_directed
            && let (Some(a), Some(b)) = (r.heading_deg, p.heading_deg)
            && same_axis_reversed(a, b)
        {
            reversed.insert(r.object_id);
            heading_deg = r.heading_deg;
        }
        if heading_deg != r.heading_deg || p.heading_directed != r.heading_directed {
            return Some(format!(
                "{who}: heading {:?}° recorded, {:?}° re-fused",
                r.heading_deg, p.heading_deg
            ));
        }
        let same_id = stereoscope_proto::messages::Pose {
            object_id: r.object_id,
            heading_deg,
            ..p.clone()
        };
        if &same_id != r {
            return Some(format!(
                "{who}: same position and heading, but velocity, method, cameras or residual differ"
            ));
        }
    }
    None
}

/// One set as fusion takes it: (rig camera index, observation), in camera order.
type Set = Vec<(usize, Observation)>;

/// Whether headings `a` and `b` (degrees) are one axis's two senses: 180° apart, to the last
/// bits a sum of 180 can round away.
fn same_axis_reversed(a: f64, b: f64) -> bool {
    let d = (a - b).rem_euclid(360.0);
    (d - 180.0).abs() <= 1e-9 * a.abs().max(b.abs()).max(180.0)
}

/// The sets fusion formed between two recorded pose frames whose sequence numbers leave `missing`
/// out, formed again from the recorded observations after `after` (the earlier frame's set,
/// excluded) and before `before_ns` (the later frame's time): observations in time order,
/// each set opened by the earliest left and taking every other camera's first observation
/// within `max_skew_ns` of it, as live fusion pairs them. `None` unless exactly `missing` sets
/// come out (a fusion restarted, or observations lost with the pose frames).
fn reform_sets(
    by_camera: &HashMap<&str, Vec<&Observation>>,
    rig: &Rig,
    after: &[(usize, Observation)],
    after_ns: u64,
    before_ns: u64,
    missing: u64,
    max_skew_ns: u64,
) -> Option<Vec<Set>> {
    let mut left: Vec<(usize, &Observation)> = Vec::new();
    for (cam, list) in by_camera {
        let ci = rig.camera_index(cam)?;
        let used = after
            .iter()
            .find(|(c, _)| *c == ci)
            .map(|(_, o)| o.timestamp_ns);
        left.extend(
            list.iter()
                .filter(|o| o.timestamp_ns > after_ns && o.timestamp_ns < before_ns)
                .filter(|o| used.is_none_or(|t| o.timestamp_ns > t))
                .map(|o| (ci, *o)),
        );
    }
    left.sort_by_key(|(c, o)| (o.timestamp_ns, *c));
    let mut sets: Vec<Set> = Vec::new();
    let mut taken = vec![false; left.len()];
    for i in 0..left.len() {
        if taken[i] {
            continue;
        }
        let t0 = left[i].1.timestamp_ns;
        let mut set: Set = Vec::new();
        for j in i..left.len() {
            let (c, o) = left[j];
            if o.timestamp_ns > t0 + max_skew_ns {
                break;
            }
            if !taken[j] && !set.iter().any(|(k, _)| *k == c) {
                taken[j] = true;
                set.push((c, o.clone()));
            }
        }
        set.sort_by_key(|(c, _)| *c);
        sets.push(set);
        if sets.len() as u64 > missing {
            return None;
        }
    }
    (sets.len() as u64 == missing).then_some(sets)
}

/// Re-fuses `session` and compares with its recorded poses; `progress(done, total)` is called
/// as it goes.
pub fn refuse(
    session: &Session,
    progress: impl FnMut(usize, usize),
) -> Result<Refused, ReplayError> {
    let rig = Rig::from_recording(&session.info.rig_file)?;
    refuse_with(session, &rig, progress, |_| {})
}

/// [`refuse`] with `rig` instead of the session's own (its cameras by the same ids: a new
/// calibration of the same cameras, `stereoscope replay --rig`), handing each re-fused pose
/// frame to `frame` (the recorded frame's sequence, times and cameras, the new poses and
/// bodies) as it goes.
pub fn refuse_with(
    session: &Session,
    rig: &Rig,
    mut progress: impl FnMut(usize, usize),
    mut frame: impl FnMut(PoseFrame),
) -> Result<Refused, ReplayError> {
    let rig = rig.clone();
    let mut fusion = Fusion::of_rig(&rig);
    let mut by_key: HashMap<(String, u64), &Observation> = HashMap::new();
    for o in &session.observations {
        by_key.insert((o.camera.clone(), o.timestamp_ns), o);
    }
    let mut by_camera: HashMap<&str, Vec<&Observation>> = HashMap::new();
    for o in &session.observations {
        by_camera.entry(o.camera.as_str()).or_default().push(o);
    }
    let mut out = Refused::default();
    let mut ids: HashMap<u32, u32> = HashMap::new();
    let mut reversed = std::collections::BTreeSet::new();
    let max_skew_ns = stereoscope_pipeline::FusionSettings::of_rig(&rig.spec)
        .pairing
        .max_skew_ns;
    // The last fused recorded frame: its sequence, time and set.
    let mut last: Option<(u64, u64, Set)> = None;
    let total = session.poses.len();
    for (i, pf) in session.poses.iter().enumerate() {
        progress(i, total);
        if let Some((seq, t_ns, prev_set)) = &last
            && pf.sequence > seq + 1
        {
            let missing = pf.sequence - seq - 1;
            match reform_sets(
                &by_camera,
                &rig,
                prev_set,
                *t_ns,
                pf.timestamp_ns,
                missing,
                max_skew_ns,
            ) {
                Some(sets) => {
                    for (k, set) in sets.iter().enumerate() {
                        let timestamp_ns = set.iter().map(|(_, o)| o.timestamp_ns).min();
                        let timestamp_ns = timestamp_ns.unwrap_or(*t_ns);
                        let (poses, bodies) = fusion.fuse(set, timestamp_ns);
                        let sequence = seq + 1 + k as u64;
                        out.reformed.push(sequence);
                        frame(PoseFrame {
                            sequence,
                            timestamp_ns,
                            frame_published_ns: set
                                .iter()
                                .map(|(_, o)| o.frame_published_ns)
                                .max()
                                .unwrap_or(0),
                            published_ns: set
                                .iter()
                                .map(|(_, o)| o.published_ns)
                                .max()
                                .unwrap_or(0),
                            cameras: set
                                .iter()
                                .map(|(c, _)| rig.cameras[*c].id.clone())
                                .collect(),
                            poses,
                            bodies,
                            ..pf.clone()
                        });
                    }
                }
                None => out.gaps.push((seq + 1, pf.sequence - 1)),
            }
        }
        let mut set = Vec::new();
        for cam in &pf.cameras {
            let Some(ci) = rig.camera_index(cam) else {
                return Err(ReplayError::UnknownCamera {
                    sequence: pf.sequence,
                    camera: cam.clone(),
                });
            };
            // The set's time is its earliest frame; the others are the closest after it.
            let o = by_key
                .get(&(cam.clone(), pf.timestamp_ns))
                .copied()
                .or_else(|| {
                    by_camera.get(cam.as_str()).and_then(|v| {
                        v.iter()
                            .filter(|o| o.timestamp_ns >= pf.timestamp_ns)
                            .min_by_key(|o| o.timestamp_ns - pf.timestamp_ns)
                            .copied()
                    })
                });
            match o {
                Some(o) => set.push((ci, o.clone())),
                None => break,
            }
        }
        if set.len() != pf.cameras.len() {
            out.incomplete += 1;
            last = Some((pf.sequence, pf.timestamp_ns, set));
            continue;
        }
        set.sort_by_key(|(c, _)| *c);
        let (poses, found) = fusion.fuse(&set, pf.timestamp_ns);
        last = Some((pf.sequence, pf.timestamp_ns, set));
        out.frames += 1;
        frame(PoseFrame {
            poses: poses.clone(),
            bodies: found.clone(),
            ..pf.clone()
        });
        let body_difference = (found != pf.bodies).then(|| {
            format!(
                "pose frame {} (t = {} ns): bodies {:?} recorded, {:?} re-fused",
                pf.sequence,
                pf.timestamp_ns,
                pf.bodies
                    .iter()
                    .map(|b| (&b.name, b.position_m))
                    .collect::<Vec<_>>(),
                found
                    .iter()
                    .map(|b| (&b.name, b.position_m))
                    .collect::<Vec<_>>()
            )
        });
        match differs(pf, &poses, &mut ids, &mut reversed).or(body_difference) {
            None => {
                out.identical += 1;
                out.identical_last_frames += 1;
            }
            Some(d) => {
                out.identical_last_frames = 0;
                out.first_difference.get_or_insert(d);
            }
        }
    }
    progress(total, total);
    out.heading_reversed = reversed.into_iter().collect();
    out.renumbered = ids.into_iter().filter(|(r, p)| r != p).collect();
    out.renumbered.sort_unstable();
    Ok(out)
}

/// The session's rigid bodies as CSV, one row per body per pose frame.
pub fn export_bodies_csv(session: &Session) -> String {
    let mut s = String::from(BODIES_CSV_HEADER);
    for f in &session.poses {
        s.push_str(&body_csv_rows(f));
    }
    s
}

/// The session's poses as CSV (what `poses.csv` holds, rebuilt from `poses.jsonl`).
pub fn export_csv(session: &Session) -> String {
    let mut s = String::from(POSES_CSV_HEADER);
    for f in &session.poses {
        s.push_str(&csv_rows(f));
    }
    s
}

/// The recorded observations in publication order with their delay from the first, ns.
pub fn schedule(session: &Session) -> Vec<(u64, &Observation)> {
    let t0 = session
        .observations
        .first()
        .map(|o| o.published_ns)
        .unwrap_or(0);
    session
        .observations
        .iter()
        .map(|o| (o.published_ns.saturating_sub(t0), o))
        .collect()
}

/// Recorded pose frames, for callers that print or compare them.
pub fn poses(session: &Session) -> &[PoseFrame] {
    &session.poses
}

/// How far the heading marker of an object sits from it, along its heading (mm).
pub const HEADING_MARKER_MM: f64 = 100.0;

/// A session as a C3D trial, and what went into it.
#[derive(Debug, Clone, PartialEq)]
pub struct C3dExport {
    pub trial: crate::c3d::C3dTrial,
    /// Object poses that fell into a C3D frame where the same object already was (pose frames
    /// closer than half a period); the first one is kept.
    pub merged: usize,
    /// The samples filled in gaps: (point, frame, how).
    pub filled: Vec<(usize, usize, stereoscope_bodies::gaps::FillMethod)>,
    pub pose_frames: usize,
}

/// Most C3D frames one export makes.
pub const MAX_C3D_FRAMES: usize = 50_000_000;
/// Most frame × point cells one export makes (16 bytes each in the file: 1.6 GB).
pub const MAX_C3D_CELLS: usize = 100_000_000;

/// The session's poses as C3D points (docs/recording.md): per object a marker `obj<id>` at its
/// position and, for objects with a heading, `obj<id>_heading` [`HEADING_MARKER_MM`] along it
/// in the horizontal plane; millimetres, world frame. The frame rate is the pose frames' median
/// spacing; each pose frame goes to the C3D frame nearest its timestamp, frames without one
/// have every marker missing.
///
/// With `fill_gaps_frames`, gaps of at most that many frames between two sightings of a marker
/// are filled (`stereoscope_bodies::gaps`): a body's marker from the body's other markers, a
/// loose one on a spline; a filled point has no camera bits and a zero residual (C3D's mark of
/// a point not measured), and is listed in [`C3dExport::filled`]. Origins and heading markers
/// are computed from the markers and are not filled.
pub fn export_c3d(
    session: &Session,
    fill_gaps_frames: Option<usize>,
) -> Result<C3dExport, ReplayError> {
    use crate::c3d::{C3dPoint, C3dTrial};
    use std::collections::BTreeMap;
    let rig = Rig::from_recording(&session.info.rig_file)?;
    let mut times: Vec<u64> = session.poses.iter().map(|p| p.timestamp_ns).collect();
    times.sort_unstable();
    times.dedup();
    let mut gaps: Vec<u64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_unstable();
    let Some(&period_ns) = gaps.get(gaps.len() / 2) else {
        return Err(ReplayError::TooFewTimes(times.len()));
    };
    let (t0, t_last) = (times[0], times[times.len() - 1]);
    // In floating point until bounded: a timestamp near u64::MAX must not overflow a count.
    let frames_f = ((t_last - t0) as f64 / period_ns as f64).round() + 1.0;
    if !(frames_f <= MAX_C3D_FRAMES as f64) {
        return Err(ReplayError::TooLong {
            frames: frames_f,
            period_ns,
        });
    }
    let n_frames = frames_f as usize;
    let slot = |t: u64| {
        (((t.saturating_sub(t0)) as f64 / period_ns as f64).round() as usize).min(n_frames - 1)
    };
    // Markers: every loose object in the session, in id order; then every rigid body's
    // origin and markers, labelled `<body>:origin`, `<body>:m<index>`.
    let mut objects: BTreeMap<u32, bool> = BTreeMap::new();
    let mut bodies: BTreeMap<String, u32> = BTreeMap::new();
    for pf in &session.poses {
        for p in &pf.poses {
            match &p.body {
                None => *objects.entry(p.object_id).or_default() |= p.heading_deg.is_some(),
                Some(b) => {
                    let n = bodies.entry(b.name.clone()).or_default();
                    *n = (*n).max(b.marker + 1);
                }
            }
        }
        for b in &pf.bodies {
            let n = bodies.entry(b.name.clone()).or_default();
            *n = (*n).max(b.markers);
        }
    }
    let mut labels = Vec::new();
    let mut descriptions = Vec::new();
    let mut column: BTreeMap<u32, (usize, Option<usize>)> = BTreeMap::new();
    for (&id, &has_heading) in &objects {
        let pos = labels.len();
        labels.push(format!("obj{id}"));
        descriptions.push(format!("object {id}"));
        let head = has_heading.then(|| {
            labels.push(format!("obj{id}_heading"));
            descriptions.push(format!(
                "object {id}, {HEADING_MARKER_MM} mm along its heading"
            ));
            pos + 1
        });
        column.insert(id, (pos, head));
    }
    // Per body: its origin's column, then its markers' (C3D labels hold at most 32 characters,
    // body names at most 32: the label is cut, the description keeps the whole name).
    let mut body_column: BTreeMap<String, usize> = BTreeMap::new();
    for (name, &n) in &bodies {
        body_column.insert(name.clone(), labels.len());
        labels.push(format!("{name}:origin").chars().take(32).collect());
        descriptions.push(format!("rigid body {name}, origin"));
        for k in 0..n.min(stereoscope_proto::messages::MAX_BODY_MARKERS) {
            labels.push(format!("{name}:m{k}").chars().take(32).collect());
            descriptions.push(format!("rigid body {name}, marker {k}"));
        }
    }
    // Checked before the table is allocated: frames × points cells.
    if n_frames.saturating_mul(labels.len().max(1)) > MAX_C3D_CELLS {
        return Err(ReplayError::TooLarge {
            frames: n_frames,
            points: labels.len(),
        });
    }
    let mut frames = vec![vec![None; labels.len()]; n_frames];
    let mut merged = 0;
    for pf in &session.poses {
        let row = &mut frames[slot(pf.timestamp_ns)];
        for b in pf.bodies.iter().filter(|b| !b.held) {
            if let Some(&c) = body_column.get(&b.name)
                && row[c].is_none()
            {
                row[c] = Some(C3dPoint {
                    xyz_mm: b.position_m.map(|v| (v * 1000.0) as f32),
                    cameras: 0,
                    residual_mm: 0,
                });
            }
        }
        for p in &pf.poses {
            let (pos, head) = match &p.body {
                Some(b) => match body_column.get(&b.name) {
                    Some(&c) if b.marker < stereoscope_proto::messages::MAX_BODY_MARKERS => {
                        (c + 1 + b.marker as usize, None)
                    }
                    _ => continue,
                },
                None => match column.get(&p.object_id) {
                    Some(&ph) => ph,
                    None => continue,
                },
            };
            if row[pos].is_some() {
                merged += 1;
                continue;
            }
            let cameras = p
                .cameras
                .iter()
                .filter_map(|c| rig.camera_index(c))
                .filter(|&i| i < 7)
                .fold(0u8, |m, i| m | (1 << i));
            let mm = p.position_m.map(|v| v * 1000.0);
            row[pos] = Some(C3dPoint {
                xyz_mm: mm.map(|v| v as f32),
                cameras,
                residual_mm: residual_mm(&rig, p),
            });
            if let (Some(h), Some(deg)) = (head, p.heading_deg) {
                let (s, c) = deg.to_radians().sin_cos();
                row[h] = Some(C3dPoint {
                    xyz_mm: [
                        (mm[0] + HEADING_MARKER_MM * c) as f32,
                        (mm[1] + HEADING_MARKER_MM * s) as f32,
                        mm[2] as f32,
                    ],
                    cameras: 0,
                    residual_mm: 0,
                });
            }
        }
    }
    let filled = match fill_gaps_frames {
        Some(max) => fill_c3d_gaps(&mut frames, &column, &body_column, &bodies, max),
        None => Vec::new(),
    };
    Ok(C3dExport {
        trial: C3dTrial {
            frame_rate_hz: (1e9 / period_ns as f64) as f32,
            labels,
            descriptions,
            frames,
        },
        merged,
        filled,
        pose_frames: session.poses.len(),
    })
}

/// A measured point's residual for C3D, millimetres (1–255): its reprojection residual in
/// pixels taken to its distance by each camera that saw it (pixels × depth / focal length),
/// averaged; 1 where that cannot be worked out (a measured point is never 0).
fn residual_mm(rig: &Rig, p: &stereoscope_proto::messages::Pose) -> u8 {
    let at = nalgebra::Point3::from(p.position_m);
    let per_camera: Vec<f64> = p
        .cameras
        .iter()
        .filter_map(|c| rig.camera_index(c))
        .filter_map(|i| {
            let cam = &rig.cameras.get(i)?.camera;
            let depth = (cam.cam_from_world * at).z;
            let f = 0.5 * (cam.intrinsics.fx + cam.intrinsics.fy);
            (depth > 0.0).then(|| p.residual_px * depth / f * 1000.0)
        })
        .collect();
    let mm = per_camera.iter().sum::<f64>() / per_camera.len().max(1) as f64;
    if mm.is_finite() {
        mm.round().clamp(1.0, 255.0) as u8
    } else {
        1
    }
}

/// Fills the markers' gaps of at most `max` frames in a C3D table (see [`export_c3d`]):
/// loose objects' columns on splines, each body's marker columns as one rigid set.
fn fill_c3d_gaps(
    frames: &mut [Vec<Option<crate::c3d::C3dPoint>>],
    column: &std::collections::BTreeMap<u32, (usize, Option<usize>)>,
    body_column: &std::collections::BTreeMap<String, usize>,
    bodies: &std::collections::BTreeMap<String, u32>,
    max: usize,
) -> Vec<(usize, usize, stereoscope_bodies::gaps::FillMethod)> {
    use stereoscope_bodies::gaps::{Track, fill_gaps};
    let mut cols: Vec<usize> = column.values().map(|&(pos, _)| pos).collect();
    let mut sets: Vec<Vec<usize>> = Vec::new();
    for (name, &origin) in body_column {
        let n = bodies.get(name).copied().unwrap_or(0) as usize;
        let first = cols.len();
        cols.extend(
            (0..n.min(stereoscope_proto::messages::MAX_BODY_MARKERS as usize))
                .map(|k| origin + 1 + k),
        );
        sets.push((first..cols.len()).collect());
    }
    let mut tracks: Vec<Track> = cols
        .iter()
        .map(|&c| {
            frames
                .iter()
                .map(|row| {
                    row[c].map(|p| {
                        nalgebra::Point3::new(
                            p.xyz_mm[0] as f64,
                            p.xyz_mm[1] as f64,
                            p.xyz_mm[2] as f64,
                        )
                    })
                })
                .collect()
        })
        .collect();
    let filled = fill_gaps(&mut tracks, &sets, max);
    filled
        .into_iter()
        .filter_map(|f| {
            let c = *cols.get(f.marker)?;
            let p = tracks.get(f.marker)?.get(f.frame).copied().flatten()?;
            frames.get_mut(f.frame)?[c] = Some(crate::c3d::C3dPoint {
                xyz_mm: [p.x as f32, p.y as f32, p.z as f32],
                cameras: 0,
                residual_mm: 0,
            });
            Some((c, f.frame, f.method))
        })
        .collect()
}

/// The recorded frames of `camera` in a session folder.
pub fn frames_file(session_dir: &std::path::Path, camera: &str) -> std::path::PathBuf {
    session_dir.join(format!("frames-{camera}.y4m"))
}

/// A one-PC rig that feeds a session's recorded frames through the services: the session's
/// rig with every camera reading its `frames-<camera>.y4m` at `speed` × the recorded pace, the session's
/// start at wall-clock `start_wall_ns`, every camera on that one clock (each frame keeps its
/// recorded exposure time, so fusion forms the recorded sets; a session without pose frames
/// has its frames stamped with their replay time, paired as live), one host `replay` whose router listens on
/// `listen` with iceoryx2 prefix `iox_prefix`, and no serial outputs. Every camera needs its
/// frames: an error names the files missing.
pub fn frames_rig(
    session: &Session,
    session_dir: &std::path::Path,
    start_wall_ns: u64,
    speed: f64,
    listen: &str,
    iox_prefix: &str,
) -> Result<String, ReplayError> {
    use stereoscope_rig::schema::{HostSpec, ReplayClock, SourceSpec};
    let mut file = Rig::from_recording(&session.info.rig_file)?.spec;
    let missing: Vec<String> = file
        .cameras
        .iter()
        .map(|c| frames_file(session_dir, &c.id))
        .filter(|p| !p.is_file())
        .map(|p| p.display().to_string())
        .collect();
    if !missing.is_empty() {
        return Err(ReplayError::NoFrames(missing));
    }
    // A session with frames and no pose frames (recorded without fusion, or written by
    // another program) has no sets to follow: its frames are stamped with their replay time
    // and paired as live ones.
    let frames_only = session.poses.is_empty();
    for c in &mut file.cameras {
        let path = frames_file(session_dir, &c.id);
        let path = std::path::absolute(&path).unwrap_or(path);
        c.host = None;
        c.source = Some(SourceSpec::Y4m {
            path: path.display().to_string(),
            realtime: false,
            repeat: false,
            replay_clock: Some(ReplayClock {
                recorded_ns: session.info.started_ns,
                wall_ns: start_wall_ns,
                speed,
                restamp: frames_only,
            }),
        });
    }
    if let (Some(f), true) = (&mut file.fusion, frames_only) {
        f.host = None;
        // The files run out; a camera is not gone meanwhile.
        f.camera_timeout_ms = Some(10_000.0);
    } else if let Some(f) = &mut file.fusion {
        f.host = None;
        // Sets as they were recorded, not as frames happen to arrive on a loaded machine:
        // fusion forms each recorded set with the cameras it had, waiting for each (up to
        // 2 s: a frame lost in the replay), and never counts a camera as gone while the files
        // run.
        let poses = session_dir.join("poses.jsonl");
        f.replay_sets = Some(
            std::path::absolute(&poses)
                .unwrap_or(poses)
                .display()
                .to_string(),
        );
        f.max_wait_ms = Some(2_000.0);
        f.camera_timeout_ms = Some(10_000.0);
        // A recording starts with its objects already confirmed: holding them back for the
        // replay's first sets would lose poses the recording has.
        f.confirm_sets = Some(1);
    }
    file.serial.clear();
    file.hosts = vec![HostSpec {
        name: "replay".into(),
        zenoh_listen: vec![listen.to_string()],
        zenoh_connect: Vec::new(),
        iceoryx2_prefix: Some(iox_prefix.to_string()),
        tls: None,
        local_listen: None,
    }];
    Ok(file.to_toml()?)
}

/// Replayed poses against the recorded ones.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct FramesCompared {
    pub recorded_frames: usize,
    pub replayed_frames: usize,
    /// Replayed pose frames with a recorded one of the same `timestamp_ns` (the same frames).
    pub matched_frames: usize,
    /// Objects of matched frames paired with a recorded object (nearest, within 5 cm).
    pub objects_compared: usize,
    /// Objects of matched frames without a recorded one near, and the other way round.
    pub objects_unmatched: usize,
    /// Compared objects at exactly the recorded position.
    pub objects_identical: usize,
    /// The last matched frames (in replay order) whose every object is identical to the
    /// recorded one, none unmatched: where the replay has converged to the live system.
    pub identical_last_frames: usize,
    pub position_rms_mm: f64,
    pub position_max_mm: f64,
    /// Recorded frames the replay did not make (by position in the recording, 0 = first, and
    /// sequence number), the first ten: where to look when frames are missing.
    pub missing: Vec<MissingFrame>,
}

/// A recorded pose frame without a replayed one at its time.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MissingFrame {
    pub index: usize,
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub cameras: Vec<String>,
}

/// Compares poses fusion made from replayed frames with the recorded poses: frames by
/// timestamp (replayed frames keep their recorded exposure times), objects by position (the
/// replay's fusion numbers objects afresh).
pub fn compare_frames(recorded: &[PoseFrame], replayed: &[PoseFrame]) -> FramesCompared {
    let by_time: HashMap<u64, &PoseFrame> = recorded.iter().map(|f| (f.timestamp_ns, f)).collect();
    let mut out = FramesCompared {
        recorded_frames: recorded.len(),
        replayed_frames: replayed.len(),
        ..Default::default()
    };
    let mut sum_sq = 0.0;
    for f in replayed {
        let Some(r) = by_time.get(&f.timestamp_ns) else {
            continue;
        };
        out.matched_frames += 1;
        let mut identical = true;
        let mut taken = vec![false; r.poses.len()];
        for p in &f.poses {
            let nearest = r
                .poses
                .iter()
                .enumerate()
                .filter(|(i, _)| !taken[*i])
                .map(|(i, q)| {
                    let d: f64 = (0..3)
                        .map(|k| (p.position_m[k] - q.position_m[k]).powi(2))
                        .sum::<f64>()
                        .sqrt();
                    (i, d)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match nearest {
                Some((i, d)) if d < 0.05 => {
                    taken[i] = true;
                    out.objects_compared += 1;
                    let mm = d * 1000.0;
                    sum_sq += mm * mm;
                    out.position_max_mm = out.position_max_mm.max(mm);
                    if d == 0.0 {
                        out.objects_identical += 1;
                    } else {
                        identical = false;
                    }
                }
                _ => {
                    out.objects_unmatched += 1;
                    identical = false;
                }
            }
        }
        let left = taken.iter().filter(|t| !**t).count();
        out.objects_unmatched += left;
        out.identical_last_frames = if identical && left == 0 {
            out.identical_last_frames + 1
        } else {
            0
        };
    }
    if out.objects_compared > 0 {
        out.position_rms_mm = (sum_sq / out.objects_compared as f64).sqrt();
    }
    let replayed_times: std::collections::HashSet<u64> =
        replayed.iter().map(|f| f.timestamp_ns).collect();
    out.missing = recorded
        .iter()
        .enumerate()
        .filter(|(_, r)| !replayed_times.contains(&r.timestamp_ns))
        .take(10)
        .map(|(index, r)| MissingFrame {
            index,
            sequence: r.sequence,
            timestamp_ns: r.timestamp_ns,
            cameras: r.cameras.clone(),
        })
        .collect();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, PoseMethod};

    fn frame(t: u64, xs: &[f64]) -> PoseFrame {
        PoseFrame {
            schema: 1,
            rig: "r".into(),
            sequence: t,
            timestamp_ns: t,
            frame_published_ns: t,
            published_ns: t,
            cameras: vec!["cam0".into(), "cam1".into()],
            poses: xs
                .iter()
                .enumerate()
                .map(|(i, &x)| Pose {
                    object_id: i as u32 + 1,
                    position_m: [x, 0.5, 1.0],
                    velocity_m_per_s: [0.0; 3],
                    heading_deg: None,
                    heading_directed: false,
                    method: PoseMethod::Triangulated,
                    cameras: vec!["cam0".into(), "cam1".into()],
                    residual_px: 0.0,
                    out_of_range: false,
                    body: None,
                })
                .collect(),
            bodies: Vec::new(),
        }
    }

    /// Objects pair by position whatever their ids; a frame counts towards the identical tail
    /// only with every object identical and none left over; frames at other times are not
    /// compared.
    #[test]
    fn replayed_poses_compare_by_time_and_position() {
        let recorded = vec![
            frame(1, &[0.1, 0.5]),
            frame(2, &[0.1, 0.5]),
            frame(3, &[0.1, 0.5]),
            frame(4, &[0.1, 0.5]),
            frame(5, &[0.1, 0.5]),
        ];
        let replayed = vec![
            frame(1, &[0.5, 0.102]),    // 2 mm off
            frame(2, &[0.5]),           // one missing
            frame(3, &[0.5, 0.1]),      // identical, in another order
            frame(4, &[0.1, 0.5, 0.9]), // one extra
            frame(5, &[0.1, 0.5]),
            frame(6, &[0.1, 0.5]), // no recorded frame at this time
        ];
        let c = compare_frames(&recorded, &replayed);
        assert_eq!((c.recorded_frames, c.replayed_frames), (5, 6));
        assert_eq!(c.matched_frames, 5);
        assert_eq!(c.objects_compared, 9);
        assert_eq!(c.objects_unmatched, 2);
        assert_eq!(c.objects_identical, 8);
        assert_eq!(c.identical_last_frames, 1);
        assert!((c.position_max_mm - 2.0).abs() < 1e-9, "{c:?}");
        let same = compare_frames(&recorded, &recorded);
        assert_eq!((same.identical_last_frames, same.position_rms_mm), (5, 0.0));
    }

    fn session_of(poses: Vec<PoseFrame>) -> Session {
        Session {
            info: crate::session::SessionInfo {
                schema: crate::session::SESSION_SCHEMA,
                rig: "demo".into(),
                started_ns: 0,
                rig_file: include_str!("../../../deploy/rigs/demo.toml").into(),
            },
            poses,
            observations: vec![],
            warnings: vec![],
        }
    }

    /// Times and counts from a session file are checked before they size anything: a last
    /// timestamp of u64::MAX (it panicked) and 200 objects over 40 M frames (it ran out of
    /// memory) are refused with the figures.
    #[test]
    fn a_c3d_export_of_hostile_times_or_counts_is_refused_not_crashed() {
        let ms = 1_000_000;
        let mut poses: Vec<PoseFrame> = (0..5).map(|i| frame(i * 33 * ms, &[0.1])).collect();
        poses.push(frame(u64::MAX, &[0.1]));
        let err = export_c3d(&session_of(poses), None).unwrap_err();
        assert!(matches!(err, ReplayError::TooLong { .. }), "{err:?}");

        let many: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let mut poses: Vec<PoseFrame> = (0..5).map(|i| frame(i * 33 * ms, &many)).collect();
        poses.push(frame(40_000_000 * 33 * ms, &many));
        let err = export_c3d(&session_of(poses), None).unwrap_err();
        assert!(
            matches!(
                err,
                ReplayError::TooLarge {
                    frames: 40_000_001,
                    points: 200
                }
            ),
            "{err:?}"
        );
        assert!(
            err.to_string().contains("40000001 frames × 200 points"),
            "{err}"
        );

        // An ordinary session still exports.
        let poses: Vec<PoseFrame> = (0..5).map(|i| frame(i * 33 * ms, &[0.1, 0.2])).collect();
        let e = export_c3d(&session_of(poses), None).unwrap();
        assert_eq!(e.trial.frames.len(), 5);
    }

    /// Gaps of a loose marker and of a body's marker are filled when asked, flagged by a zero
    /// residual and no camera bits; measured points keep a residual of at least 1 mm; a gap
    /// longer than asked is left.
    #[test]
    fn c3d_gaps_are_filled_and_flagged_only_when_asked() {
        use stereoscope_bodies::gaps::FillMethod;
        use stereoscope_proto::messages::BodyLabel;
        // A marker moving 1 m/s along x, object 1; a body "wand" of four markers translating
        // with it (objects 2–5), each 8.33 mm a frame.
        let layout = [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [0.0, 0.12, 0.0],
            [0.02, 0.03, 0.15],
        ];
        let poses: Vec<PoseFrame> = (0..40u64)
            .map(|i| {
                let x = i as f64 / 120.0;
                let mut f = frame(i * 8_333_333, &[x]);
                f.poses[0].residual_px = 0.4;
                for (k, l) in layout.iter().enumerate() {
                    let mut p = f.poses[0].clone();
                    p.object_id = 2 + k as u32;
                    p.position_m = [0.5 + x + l[0], l[1], 1.0 + l[2]];
                    p.body = Some(BodyLabel {
                        name: "wand".into(),
                        marker: k as u32,
                    });
                    f.poses.push(p);
                }
                // Object 1 missing in frames 10–14 and 20–31, body marker 0 in 15–19.
                f.poses.retain(|p| {
                    !(p.object_id == 1 && ((10..15).contains(&i) || (20..32).contains(&i)))
                        && !(p.object_id == 2 && (15..20).contains(&i))
                });
                f
            })
            .collect();
        let session = session_of(poses);
        let plain = export_c3d(&session, None).unwrap();
        assert!(plain.filled.is_empty());
        assert!(plain.trial.frames[12][0].is_none());
        let e = export_c3d(&session, Some(10)).unwrap();
        let at = |f: usize, c: usize| e.trial.frames[f][c];
        // Object 1 (column 0): frames 10–14 filled on a spline, 20–31 (12 frames) left.
        let loose: Vec<usize> = e.filled.iter().filter(|f| f.0 == 0).map(|f| f.1).collect();
        assert_eq!(loose, (10..15).collect::<Vec<_>>());
        assert!(at(25, 0).is_none());
        assert!(
            e.filled
                .iter()
                .filter(|f| f.0 == 0)
                .all(|f| f.2 == FillMethod::Spline)
        );
        for f in 10..15 {
            let p = at(f, 0).unwrap();
            assert_eq!((p.cameras, p.residual_mm), (0, 0));
            let want_mm = f as f64 / 120.0 * 1000.0;
            assert!((p.xyz_mm[0] as f64 - want_mm).abs() < 0.01, "{f}: {p:?}");
        }
        // The body's marker 0 (column of "wand:m0") from the other three.
        let m0 = e.trial.labels.iter().position(|l| l == "wand:m0").unwrap();
        let rigid: Vec<_> = e.filled.iter().filter(|f| f.0 == m0).collect();
        assert_eq!(rigid.len(), 5);
        assert!(rigid.iter().all(|f| f.2 == FillMethod::Rigid));
        let p = at(17, m0).unwrap();
        let want = 500.0 + 17.0 / 120.0 * 1000.0;
        assert!((p.xyz_mm[0] as f64 - want).abs() < 0.01, "{p:?}");
        // Measured points: camera bits and a residual of at least 1 mm.
        let measured = at(5, 0).unwrap();
        assert!(
            measured.cameras != 0 && measured.residual_mm >= 1,
            "{measured:?}"
        );
    }

    /// A body's markers are labelled by body and index in C3D and CSV, its origin too; loose
    /// markers keep their object ids; a held body adds no point.
    #[test]
    fn bodies_are_labelled_in_c3d_and_csv() {
        use stereoscope_proto::messages::{BodyLabel, BodyPose};
        let ms = 1_000_000;
        let poses: Vec<PoseFrame> = (0..4u64)
            .map(|i| {
                let mut f = frame(i * 33 * ms, &[0.1, 0.2, 0.3]);
                f.poses[1].body = Some(BodyLabel {
                    name: "head".into(),
                    marker: 2,
                });
                f.bodies = vec![BodyPose {
                    name: "head".into(),
                    position_m: [0.5, 0.5, 1.0],
                    orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
                    velocity_m_per_s: [0.0; 3],
                    angular_velocity_rad_per_s: [0.0; 3],
                    residual_mm: 0.5,
                    markers_seen: 3,
                    markers: 4,
                    held: i == 3,
                    roll_unobservable: false,
                }];
                f
            })
            .collect();
        let session = session_of(poses);
        let e = export_c3d(&session, None).unwrap();
        assert_eq!(
            e.trial.labels,
            [
                "obj1",
                "obj3",
                "head:origin",
                "head:m0",
                "head:m1",
                "head:m2",
                "head:m3"
            ]
        );
        let head_m2 = e.trial.frames[0][5].unwrap();
        assert_eq!(head_m2.xyz_mm, [200.0, 500.0, 1000.0]);
        assert_eq!(e.trial.frames[0][2].unwrap().xyz_mm, [500.0, 500.0, 1000.0]);
        assert!(
            e.trial.frames[3][2].is_none(),
            "a held body is not a measurement"
        );
        assert!(e.trial.frames[0][3].is_none());
        let csv = export_csv(&session);
        assert!(csv.lines().nth(2).unwrap().ends_with(",head,2"), "{csv}");
        assert!(csv.lines().nth(1).unwrap().ends_with(",,"), "{csv}");
        let bodies = export_bodies_csv(&session);
        assert_eq!(bodies.lines().count(), 5);
        assert!(
            bodies.lines().nth(4).unwrap().ends_with(",3,4,true"),
            "{bodies}"
        );
    }

    fn observation(camera: &str, t_ns: u64) -> Observation {
        Observation {
            schema: 1,
            rig: "demo".into(),
            camera: camera.into(),
            sequence: t_ns,
            timestamp_ns: t_ns,
            frame_published_ns: t_ns,
            published_ns: t_ns,
            width_px: 320,
            height_px: 240,
            threshold: 100,
            dark: false,
            full_frame: true,
            dropped_blobs: 0,
            blobs: vec![],
        }
    }

    /// The sets between two recorded frames are formed again as live pairing forms them
    /// (each opened by the earliest observation left, one per camera within the skew), the
    /// earlier frame's own observations left out; a gap with more or fewer sets than missing
    /// sequence numbers (a fusion restarted, observations lost too) is not formed at all.
    #[test]
    fn lost_pose_frames_sets_are_formed_again_only_when_they_add_up() {
        let rig = Rig::from_recording(include_str!("../../../deploy/rigs/demo.toml")).unwrap();
        let ms = 1_000_000;
        // cam1 exposes 2 ms after cam0; the frame at 0 was recorded, 33 and 66 were lost.
        let obs: Vec<Observation> = [0, 33, 66, 100]
            .iter()
            .flat_map(|&t| {
                [
                    observation("cam0", t * ms),
                    observation("cam1", t * ms + 2 * ms),
                ]
            })
            .collect();
        let mut by_camera: HashMap<&str, Vec<&Observation>> = HashMap::new();
        for o in &obs {
            by_camera.entry(o.camera.as_str()).or_default().push(o);
        }
        let first = vec![(0, obs[0].clone()), (1, obs[1].clone())];
        let skew = 5 * ms;
        let sets = reform_sets(&by_camera, &rig, &first, 0, 100 * ms, 2, skew).unwrap();
        let times: Vec<Vec<(usize, u64)>> = sets
            .iter()
            .map(|s| s.iter().map(|(c, o)| (*c, o.timestamp_ns / ms)).collect())
            .collect();
        assert_eq!(times, [vec![(0, 33), (1, 35)], vec![(0, 66), (1, 68)]]);
        assert!(reform_sets(&by_camera, &rig, &first, 0, 100 * ms, 1, skew).is_none());
        assert!(reform_sets(&by_camera, &rig, &first, 0, 100 * ms, 3, skew).is_none());
        // With a skew under the cameras' 2 ms, each camera's frame is a set of its own.
        let apart = reform_sets(&by_camera, &rig, &first, 0, 100 * ms, 4, ms).unwrap();
        assert_eq!(apart.len(), 4);
    }

    /// An undirected heading pointing the other way along its axis, to rounding, is the
    /// same axis; any other difference is not.
    #[test]
    fn undirected_headings_compare_as_axes() {
        assert!(same_axis_reversed(173.2557730228029, 353.25577302280294));
        assert!(same_axis_reversed(350.0, 170.0));
        assert!(same_axis_reversed(0.0, 180.0));
        assert!(!same_axis_reversed(10.0, 10.0));
        assert!(!same_axis_reversed(10.0, 190.001));
    }
}
