//! A recorded session out to other tools' files (not in the thesis): poses and bodies as CSV,
//! and as C3D with gaps filled on request — `stereoscope export` (docs/recording.md).

use crate::replay::ReplayError;
use crate::session::{
    BODIES_CSV_HEADER, MODELS_CSV_HEADER, POSES_CSV_HEADER, Session, body_csv_rows, csv_rows,
    model_csv_rows,
};
use stereoscope_rig::Rig;

/// The session's rigid bodies as CSV, one row per body per pose frame.
pub fn export_bodies_csv(session: &Session) -> String {
    let mut s = String::from(BODIES_CSV_HEADER);
    for f in &session.poses {
        s.push_str(&body_csv_rows(f));
    }
    s
}

/// The session's kinematic models as CSV, one row per joint per model per pose frame.
pub fn export_models_csv(session: &Session) -> String {
    let mut s = String::from(MODELS_CSV_HEADER);
    for f in &session.poses {
        s.push_str(&model_csv_rows(f));
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

/// The session's markers as a table on one clock, a row per frame of the C3D export's frame
/// rate: `frame,time_s`, then per marker (the C3D labels: `obj<id>`, `<body>:m<k>`, …)
/// `<label>_x_mm,<label>_y_mm,<label>_z_mm,<label>_filled`; a missing sample is three empty
/// cells and an empty flag, a measured one flag 0, one filled in a gap (`fill_gaps_frames`,
/// as [`export_c3d`] fills them) flag 1 — never filled silently. `time_s` is from the first
/// frame.
pub fn export_markers_csv(
    session: &Session,
    fill_gaps_frames: Option<usize>,
) -> Result<String, ReplayError> {
    let e = export_c3d(session, fill_gaps_frames)?;
    let filled: std::collections::HashSet<(usize, usize)> =
        e.filled.iter().map(|&(c, f, _)| (c, f)).collect();
    let mut s = String::from("frame,time_s");
    for l in &e.trial.labels {
        // Labels are object ids and the rig's body, model, link and marker names (checked
        // there: no commas).
        s.push_str(&format!(",{l}_x_mm,{l}_y_mm,{l}_z_mm,{l}_filled"));
    }
    s.push('\n');
    let rate = f64::from(e.trial.frame_rate_hz);
    for (f, row) in e.trial.frames.iter().enumerate() {
        s.push_str(&format!("{f},{:.6}", f as f64 / rate));
        for (c, point) in row.iter().enumerate() {
            match point {
                Some(p) => s.push_str(&format!(
                    ",{:.3},{:.3},{:.3},{}",
                    p.xyz_mm[0],
                    p.xyz_mm[1],
                    p.xyz_mm[2],
                    u8::from(filled.contains(&(c, f)))
                )),
                None => s.push_str(",,,,"),
            }
        }
        s.push('\n');
    }
    Ok(s)
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
                None if p.model.is_some() => {}
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
    let models = ModelColumns::new(&rig, session, &mut labels, &mut descriptions);
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
        for m in pf.models.iter().filter(|m| m.valid) {
            for l in &m.links {
                if let Some(&c) = models.link_column.get(&(m.name.clone(), l.name.clone()))
                    && row[c].is_none()
                {
                    row[c] = Some(C3dPoint {
                        xyz_mm: l.position_m.map(|v| (v * 1000.0) as f32),
                        cameras: 0,
                        residual_mm: 0,
                    });
                }
            }
        }
        for p in &pf.poses {
            let (pos, head) = match (&p.body, &p.model) {
                (Some(b), _) => match body_column.get(&b.name) {
                    Some(&c) if b.marker < stereoscope_proto::messages::MAX_BODY_MARKERS => {
                        (c + 1 + b.marker as usize, None)
                    }
                    _ => continue,
                },
                (None, Some(m)) => match models
                    .marker_column
                    .get(&(m.name.clone(), m.marker.clone()))
                {
                    Some(&c) => (c, None),
                    None => continue,
                },
                (None, None) => match column.get(&p.object_id) {
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
        Some(max) => {
            // Loose markers on splines; each body's markers, and each link's, as a rigid set.
            let loose: Vec<usize> = column.values().map(|&(pos, _)| pos).collect();
            let mut sets: Vec<Vec<usize>> = body_column
                .iter()
                .map(|(name, &origin)| {
                    let n = bodies.get(name).copied().unwrap_or(0);
                    (0..n.min(stereoscope_proto::messages::MAX_BODY_MARKERS) as usize)
                        .map(|k| origin + 1 + k)
                        .collect()
                })
                .collect();
            sets.extend(models.link_sets.iter().cloned());
            fill_c3d_gaps(&mut frames, &loose, &sets, max)
        }
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

/// The kinematic models' columns of a C3D export: per model of the rig seen in the session,
/// each link's origin (`<model>:<link>`, from the model's valid fits) and then that link's
/// markers (`<model>:<marker>`, the points fitted as them), in the rig's order; a label in
/// the recording its rig does not name comes after, under its own link.
struct ModelColumns {
    link_column: std::collections::BTreeMap<(String, String), usize>,
    marker_column: std::collections::BTreeMap<(String, String), usize>,
    /// Each link's marker columns: one rigid set for gap filling.
    link_sets: Vec<Vec<usize>>,
}

impl ModelColumns {
    fn new(
        rig: &Rig,
        session: &Session,
        labels: &mut Vec<String>,
        descriptions: &mut Vec<String>,
    ) -> ModelColumns {
        use std::collections::{BTreeMap, BTreeSet};
        // (model, link) → its markers, in order.
        let mut links: Vec<((String, String), Vec<String>)> = Vec::new();
        let mut seen_models: BTreeSet<&str> = BTreeSet::new();
        let mut extra: BTreeSet<(String, String, String)> = BTreeSet::new();
        for pf in &session.poses {
            seen_models.extend(pf.models.iter().map(|m| m.name.as_str()));
            for m in pf.poses.iter().filter_map(|p| p.model.as_ref()) {
                seen_models.insert(&m.name);
                extra.insert((m.name.clone(), m.link.clone(), m.marker.clone()));
            }
        }
        for rm in rig
            .models
            .iter()
            .filter(|m| seen_models.contains(m.model.name.as_str()))
        {
            let m = &rm.model;
            for (l, link) in m.links.iter().enumerate() {
                let on: Vec<String> = m
                    .markers
                    .iter()
                    .filter(|k| k.link == l)
                    .map(|k| k.name.clone())
                    .collect();
                for k in &on {
                    extra.remove(&(m.name.clone(), link.name.clone(), k.clone()));
                }
                links.push(((m.name.clone(), link.name.clone()), on));
            }
        }
        for (model, link, marker) in extra {
            let key = (model, link);
            match links.iter_mut().find(|(k, _)| *k == key) {
                Some((_, on)) => on.push(marker),
                None => links.push((key, vec![marker])),
            }
        }
        let mut out = ModelColumns {
            link_column: BTreeMap::new(),
            marker_column: BTreeMap::new(),
            link_sets: Vec::new(),
        };
        let label = |s: String| s.chars().take(32).collect::<String>();
        for ((model, link), markers) in links {
            out.link_column
                .insert((model.clone(), link.clone()), labels.len());
            labels.push(label(format!("{model}:{link}")));
            descriptions.push(format!("model {model}, link {link}, origin"));
            let mut set = Vec::new();
            for k in markers {
                set.push(labels.len());
                out.marker_column
                    .insert((model.clone(), k.clone()), labels.len());
                labels.push(label(format!("{model}:{k}")));
                descriptions.push(format!("model {model}, link {link}, marker {k}"));
            }
            out.link_sets.push(set);
        }
        out
    }
}

/// Fills the markers' gaps of at most `max` frames in a C3D table (see [`export_c3d`]): the
/// `loose` columns on splines, each of `sets` as one rigid set.
fn fill_c3d_gaps(
    frames: &mut [Vec<Option<crate::c3d::C3dPoint>>],
    loose: &[usize],
    rigid: &[Vec<usize>],
    max: usize,
) -> Vec<(usize, usize, stereoscope_bodies::gaps::FillMethod)> {
    use stereoscope_bodies::gaps::{Track, fill_gaps};
    let mut cols: Vec<usize> = loose.to_vec();
    let mut sets: Vec<Vec<usize>> = Vec::new();
    for set in rigid {
        let first = cols.len();
        cols.extend(set);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::replay::tests::{frame, session_of};
    use stereoscope_proto::messages::PoseFrame;

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
        // The same as a table on one clock: the filled samples flagged 1, the measured 0,
        // the gap left open empty; unfilled without the option.
        let csv = export_markers_csv(&session, Some(10)).unwrap();
        let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(
            rows[0][..6],
            [
                "frame",
                "time_s",
                "obj1_x_mm",
                "obj1_y_mm",
                "obj1_z_mm",
                "obj1_filled"
            ]
        );
        assert_eq!(rows.len(), 1 + e.trial.frames.len());
        assert!(rows.iter().all(|r| r.len() == rows[0].len()));
        assert_eq!(rows[1 + 5][5], "0");
        assert_eq!(rows[1 + 12][5], "1");
        let x: f64 = rows[1 + 12][2].parse().unwrap();
        assert!((x - 12.0 / 120.0 * 1000.0).abs() < 0.01, "{x}");
        assert_eq!(rows[1 + 25][2..6], ["", "", "", ""]);
        let m0_flag = 2 + 4 * m0 + 3;
        assert_eq!(rows[1 + 17][m0_flag], "1");
        let plain = export_markers_csv(&session, None).unwrap();
        let plain_rows: Vec<Vec<&str>> = plain.lines().map(|l| l.split(',').collect()).collect();
        assert_eq!(plain_rows[1 + 12][2..6], ["", "", "", ""]);
        assert!(
            plain_rows
                .iter()
                .skip(1)
                .all(|r| r.iter().skip(5).step_by(4).all(|c| *c != "1"))
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

    /// A model's points are labelled by model and marker, each link's origin by model and
    /// link, in C3D and the markers' CSV; a gap in a link's marker is filled from the link's
    /// other markers (rigid), flagged; an invalid fit adds no link origin.
    #[test]
    fn model_markers_and_links_are_labelled_and_filled_as_rigid_sets() {
        use stereoscope_proto::messages::{LinkPose, ModelLabel, ModelPose};
        let ms = 1_000_000;
        let label = |marker: &str| {
            Some(ModelLabel {
                name: "arm".into(),
                link: "forearm".into(),
                marker: marker.into(),
            })
        };
        let poses: Vec<PoseFrame> = (0..12u64)
            .map(|i| {
                // Four markers of the forearm moving together along x, and a loose one.
                let x = 0.01 * i as f64;
                let mut f = frame(i * 33 * ms, &[x, x + 0.1, x + 0.2, x + 0.3, 0.9]);
                for (k, p) in f.poses.iter_mut().take(4).enumerate() {
                    p.model = label(&format!("forearm_{k}"));
                    // Not in a line, so the set's motion is determined.
                    p.position_m[1] = 0.5 + 0.02 * (k * k) as f64;
                    p.position_m[2] = 0.05 * k as f64;
                }
                // forearm_1 hidden in frames 5 and 6.
                if i == 5 || i == 6 {
                    f.poses.remove(1);
                }
                f.models = vec![ModelPose {
                    name: "arm".into(),
                    valid: i != 9,
                    rms_mm: 0.3,
                    markers_seen: 4,
                    markers: 4,
                    joints: Vec::new(),
                    links: vec![LinkPose {
                        name: "forearm".into(),
                        position_m: [x, 0.0, 0.0],
                        orientation_xyzw: [0.0, 0.0, 0.0, 1.0],
                    }],
                }];
                f
            })
            .collect();
        let session = session_of(poses);
        let e = export_c3d(&session, Some(4)).unwrap();
        assert_eq!(
            e.trial.labels,
            [
                "obj5",
                "arm:forearm",
                "arm:forearm_0",
                "arm:forearm_1",
                "arm:forearm_2",
                "arm:forearm_3"
            ]
        );
        assert_eq!(
            e.trial.descriptions[3],
            "model arm, link forearm, marker forearm_1"
        );
        assert_eq!(e.trial.frames[2][1].unwrap().xyz_mm, [20.0, 0.0, 0.0]);
        assert!(e.trial.frames[9][1].is_none(), "an invalid fit's link");
        let measured = e.trial.frames[4][3].unwrap();
        assert!(measured.cameras != 0);
        // Filled from forearm_0 and forearm_2 as a rigid set, flagged as filled.
        for f in [5, 6] {
            let p = e.trial.frames[f][3].unwrap();
            let want = [f as f32 * 10.0 + 100.0, 520.0, 50.0];
            for (a, b) in p.xyz_mm.iter().zip(want) {
                assert!((a - b).abs() < 0.01, "frame {f}: {:?}", p.xyz_mm);
            }
            assert_eq!(p.cameras, 0);
            assert!(
                e.filled
                    .contains(&(3, f, stereoscope_bodies::gaps::FillMethod::Rigid))
            );
        }
        let csv = export_markers_csv(&session, Some(4)).unwrap();
        let header = csv.lines().next().unwrap();
        assert!(
            header.contains(
                ",arm:forearm_1_x_mm,arm:forearm_1_y_mm,arm:forearm_1_z_mm,arm:forearm_1_filled"
            ),
            "{header}"
        );
        let flag = header
            .split(',')
            .position(|c| c == "arm:forearm_1_filled")
            .unwrap();
        let cell = |line: usize| csv.lines().nth(line).unwrap().split(',').nth(flag).unwrap();
        // Frame 5 (line 6) filled, frame 4 measured.
        assert_eq!((cell(6), cell(5)), ("1", "0"), "{csv}");
    }
}
