//! `stereoscope replay` and `stereoscope export`.
//!
//! Replay re-runs fusion (`stereoscope_fusion::fuser`, the same code the service runs) on the
//! recorded observations, grouped into exactly the sets the live fusion used (each recorded
//! pose frame names its cameras and time), and compares every pose with the recorded one; and
//! it can publish the recorded observations back on Zenoh, at recorded speed or as fast as
//! possible, for a running fusion and any other subscriber.

use crate::session::{POSES_CSV_HEADER, Session, csv_rows};
use std::collections::HashMap;
use stereoscope_fusion::fuser::Fuser;
use stereoscope_proto::messages::{Observation, PoseFrame};
use stereoscope_transport::context::parse_rig;

/// What re-fusing a session gave.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Refused {
    pub frames: usize,
    /// Pose frames whose every pose came out identical (ids, positions, headings, methods).
    pub identical: usize,
    /// The first difference, described.
    pub first_difference: Option<String>,
    /// Pose frames whose observations the session lacks (recorded after the frame).
    pub incomplete: usize,
}

/// Re-fuses `session` and compares with its recorded poses; `progress(done, total)` is called
/// as it goes.
pub fn refuse(
    session: &Session,
    mut progress: impl FnMut(usize, usize),
) -> Result<Refused, String> {
    let (file, rig) =
        parse_rig(&session.info.rig_file).map_err(|e| format!("session.json rig_file: {e}"))?;
    let (_, fuser_cfg, _) = stereoscope_fusion::settings(&file)?;
    let mut fuser = Fuser::new(&rig, fuser_cfg);
    let mut by_key: HashMap<(String, u64), &Observation> = HashMap::new();
    for o in &session.observations {
        by_key.insert((o.camera.clone(), o.timestamp_ns), o);
    }
    let mut by_camera: HashMap<&str, Vec<&Observation>> = HashMap::new();
    for o in &session.observations {
        by_camera.entry(o.camera.as_str()).or_default().push(o);
    }
    let mut out = Refused::default();
    let total = session.poses.len();
    for (i, pf) in session.poses.iter().enumerate() {
        progress(i, total);
        let mut set = Vec::new();
        for cam in &pf.cameras {
            let Some(ci) = rig.camera_index(cam) else {
                return Err(format!(
                    "pose frame {}: camera {cam:?} is not in the rig",
                    pf.sequence
                ));
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
            continue;
        }
        set.sort_by_key(|(c, _)| *c);
        let poses = fuser.fuse(&set, pf.timestamp_ns);
        out.frames += 1;
        if poses == pf.poses {
            out.identical += 1;
        } else if out.first_difference.is_none() {
            out.first_difference = Some(format!(
                "pose frame {}: recorded {:?}, replayed {:?}",
                pf.sequence, pf.poses, poses
            ));
        }
    }
    progress(total, total);
    Ok(out)
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
