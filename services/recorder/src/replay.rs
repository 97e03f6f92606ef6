//! `stereoscope replay` and `stereoscope export`.
//!
//! Replay re-runs fusion (`stereoscope_pipeline::Fusion`, the same code the service runs) on the
//! recorded observations, grouped into exactly the sets the live fusion used (each recorded
//! pose frame names its cameras and time), and compares every pose with the recorded one; and
//! it can publish the recorded observations back on Zenoh, at recorded speed or as fast as
//! possible, for a running fusion and any other subscriber.

use crate::session::Session;
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
        crate::export::MAX_C3D_CELLS * 16 / 1_000_000
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
                        let models = fusion.take_models();
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
                            models,
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
        let models = fusion.take_models();
        last = Some((pf.sequence, pf.timestamp_ns, set));
        out.frames += 1;
        frame(PoseFrame {
            poses: poses.clone(),
            bodies: found.clone(),
            models,
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
        local_auth: false,
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
pub(crate) mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, PoseMethod};

    pub(crate) fn frame(t: u64, xs: &[f64]) -> PoseFrame {
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
                    model: None,
                })
                .collect(),
            bodies: Vec::new(),
            models: Vec::new(),
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

    pub(crate) fn session_of(poses: Vec<PoseFrame>) -> Session {
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
