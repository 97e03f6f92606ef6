//! A recorded session folder (`docs/recording.md`):
//!
//! - `session.json` — `{"schema": 1, "rig": NAME, "started_ns": …, "rig_file": TEXT}`, written
//!   whole before anything else;
//! - `poses.jsonl`, `observations.jsonl` — one message per line, exactly as on Zenoh
//!   (`docs/protocol.md`);
//! - `poses.csv` — one row per object per pose frame, for spreadsheets;
//! - `frames-<camera>.y4m` — raw frames of the cameras asked for.
//!
//! Reading checks every line and names file and line; an incomplete last line (a recorder that
//! was killed mid-write) is reported and skipped, everything before it is kept.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use stereoscope_proto::messages::{Message, Observation, PoseFrame};

pub const SESSION_SCHEMA: u32 = 1;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionInfo {
    pub schema: u32,
    pub rig: String,
    pub started_ns: u64,
    /// The rig file's text, so a session can be replayed without it.
    pub rig_file: String,
}

pub const POSES_CSV_HEADER: &str = "timestamp_ns,sequence,object_id,x_m,y_m,z_m,heading_deg,heading_directed,method,cameras,residual_px,body,body_marker\n";

/// Header of the rigid bodies' CSV (`stereoscope export --format bodies-csv`).
pub const BODIES_CSV_HEADER: &str =
    "timestamp_ns,sequence,body,x_m,y_m,z_m,qx,qy,qz,qw,residual_mm,markers_seen,markers,held\n";

/// Header of the kinematic models' CSV (`stereoscope export --format models-csv`): one row per
/// joint per model per pose frame; `v0`…`v3` the joint's values as the protocol gives them
/// (an angle in radians, an offset in metres, two angles, or a rotation x, y, z, w), unused
/// ones empty.
pub const MODELS_CSV_HEADER: &str =
    "timestamp_ns,sequence,model,valid,rms_mm,joint,v0,v1,v2,v3,determined,at_limit,residual_mm\n";

/// CSV rows of one pose frame's models.
pub fn model_csv_rows(f: &PoseFrame) -> String {
    let mut out = String::new();
    for m in &f.models {
        for j in &m.joints {
            let v: Vec<String> = (0..4)
                .map(|k| {
                    j.values
                        .get(k)
                        .map(|v| format!("{v:.9}"))
                        .unwrap_or_default()
                })
                .collect();
            out.push_str(&format!(
                "{},{},{},{},{:.3},{},{},{},{},{}\n",
                f.timestamp_ns,
                f.sequence,
                m.name,
                m.valid,
                m.rms_mm,
                j.name,
                v.join(","),
                j.determined,
                j.at_limit,
                j.residual_mm.map(|r| format!("{r:.3}")).unwrap_or_default()
            ));
        }
    }
    out
}

/// CSV rows of one pose frame's bodies.
pub fn body_csv_rows(f: &PoseFrame) -> String {
    let mut out = String::new();
    for b in &f.bodies {
        let [x, y, z] = b.position_m;
        let [qx, qy, qz, qw] = b.orientation_xyzw;
        out.push_str(&format!(
            "{},{},{},{x:.6},{y:.6},{z:.6},{qx:.6},{qy:.6},{qz:.6},{qw:.6},{:.3},{},{},{}\n",
            f.timestamp_ns, f.sequence, b.name, b.residual_mm, b.markers_seen, b.markers, b.held
        ));
    }
    out
}

/// CSV rows of one pose frame.
pub fn csv_rows(f: &PoseFrame) -> String {
    let mut out = String::new();
    for p in &f.poses {
        out.push_str(&format!(
            "{},{},{},{:.6},{:.6},{:.6},{},{},{},{},{:.4},{},{}\n",
            f.timestamp_ns,
            f.sequence,
            p.object_id,
            p.position_m[0],
            p.position_m[1],
            p.position_m[2],
            p.heading_deg.map(|h| format!("{h:.3}")).unwrap_or_default(),
            p.heading_directed,
            match p.method {
                stereoscope_proto::messages::PoseMethod::Triangulated => "triangulated",
                stereoscope_proto::messages::PoseMethod::DepthFromArea => "depth_from_area",
            },
            p.cameras.join(" "),
            p.residual_px,
            p.body.as_ref().map(|b| b.name.as_str()).unwrap_or(""),
            p.body
                .as_ref()
                .map(|b| b.marker.to_string())
                .unwrap_or_default(),
        ));
    }
    out
}

/// A new session folder's path inside `folder`: `<rig>-<UTC date and time>-<ms>`, unique per
/// start (a recorder restarted within the same millisecond gets `-2`, `-3`, …).
pub fn new_session_folder(folder: &Path, rig: &str) -> PathBuf {
    let now_ns = stereoscope_proto::messages::now_ns();
    let secs = (now_ns / 1_000_000_000) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    let base = format!(
        "{rig}-{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z-{:03}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60,
        (now_ns / 1_000_000) % 1000
    );
    let mut path = folder.join(&base);
    let mut n = 2;
    while path.exists() {
        path = folder.join(format!("{base}-{n}"));
        n += 1;
    }
    path
}

/// A problem in a session folder, naming the file and line.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {problem}", file.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct SessionError {
    pub file: PathBuf,
    pub line: Option<usize>,
    /// Said in the message (not as a separate cause, so that a chain prints it once).
    pub problem: SessionProblem,
}

/// What is wrong at [`SessionError`]'s place.
#[derive(Debug, thiserror::Error)]
pub enum SessionProblem {
    #[error("{0}")]
    Read(std::io::Error),
    #[error("{0}")]
    Info(serde_json::Error),
    #[error("session schema {found} is not {SESSION_SCHEMA}")]
    Schema { found: u32 },
    /// A record that does not decode or fails its checks, before the last line.
    #[error("{0}")]
    Record(stereoscope_proto::messages::DecodeError),
}

/// A session read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    pub info: SessionInfo,
    pub poses: Vec<PoseFrame>,
    pub observations: Vec<Observation>,
    /// Warnings (an incomplete last line), with file and line.
    pub warnings: Vec<String>,
}

fn read_lines<M: Message>(path: &Path, warnings: &mut Vec<String>) -> Result<Vec<M>, SessionError> {
    let text = std::fs::read(path).map_err(|e| SessionError {
        file: path.to_path_buf(),
        line: None,
        problem: SessionProblem::Read(e),
    })?;
    let complete = text.last().is_none_or(|&b| b == b'\n');
    let lines: Vec<&[u8]> = text
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .collect();
    let mut out = Vec::with_capacity(lines.len());
    for (i, line) in lines.iter().enumerate() {
        let last = i + 1 == lines.len();
        match M::from_json(line) {
            Ok(m) => out.push(m),
            Err(_) if last && !complete => warnings.push(format!(
                "{}:{}: incomplete last line (the recorder stopped mid-write); skipped",
                path.display(),
                i + 1
            )),
            Err(e) => {
                return Err(SessionError {
                    file: path.to_path_buf(),
                    line: Some(i + 1),
                    problem: SessionProblem::Record(e),
                });
            }
        }
    }
    Ok(out)
}

/// A recorder's JSON-lines file read back (`observations.jsonl` for a calibration, `poses.jsonl`
/// for the floor), with its warnings (an incomplete last line).
pub fn read_messages<M: Message>(path: &Path) -> Result<(Vec<M>, Vec<String>), SessionError> {
    let mut warnings = Vec::new();
    let msgs = read_lines(path, &mut warnings)?;
    Ok((msgs, warnings))
}

impl Session {
    pub fn read(dir: &Path) -> Result<Session, SessionError> {
        let info_path = dir.join("session.json");
        let info_text = std::fs::read(&info_path).map_err(|e| SessionError {
            file: info_path.clone(),
            line: None,
            problem: SessionProblem::Read(e),
        })?;
        let info: SessionInfo = serde_json::from_slice(&info_text).map_err(|e| SessionError {
            file: info_path.clone(),
            line: Some(e.line()),
            problem: SessionProblem::Info(e),
        })?;
        if info.schema != SESSION_SCHEMA {
            return Err(SessionError {
                file: info_path,
                line: None,
                problem: SessionProblem::Schema { found: info.schema },
            });
        }
        let mut warnings = Vec::new();
        // A session of frames alone (recorded without fusion, or written by another
        // program) has neither file: read as empty, and said.
        let optional = |name: &str, warnings: &mut Vec<String>| {
            let path = dir.join(name);
            if path.exists() {
                Ok(Some(path))
            } else {
                warnings.push(format!(
                    "{}: none (a session of frames only?)",
                    path.display()
                ));
                Ok::<_, SessionError>(None)
            }
        };
        let poses = match optional("poses.jsonl", &mut warnings)? {
            Some(p) => read_lines(&p, &mut warnings)?,
            None => Vec::new(),
        };
        let observations = match optional("observations.jsonl", &mut warnings)? {
            Some(p) => read_lines(&p, &mut warnings)?,
            None => Vec::new(),
        };
        Ok(Session {
            info,
            poses,
            observations,
            warnings,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, PoseMethod, SCHEMA_VERSION};

    /// A model's joints, a row each: an angle in v0, a ball joint's rotation in v0–v3, an
    /// unseen link's residual empty.
    #[test]
    fn a_models_joints_are_rows_of_the_models_csv() {
        use stereoscope_proto::messages::{JointState, ModelPose};
        let mut f = frame(3);
        f.models = vec![ModelPose {
            name: "leg".into(),
            valid: true,
            rms_mm: 0.25,
            markers_seen: 12,
            markers: 16,
            joints: vec![
                JointState {
                    name: "hip".into(),
                    values: vec![0.0, 0.1, 0.0, 0.995],
                    determined: true,
                    at_limit: false,
                    residual_mm: Some(0.2),
                },
                JointState {
                    name: "knee".into(),
                    values: vec![0.5],
                    determined: false,
                    at_limit: true,
                    residual_mm: None,
                },
            ],
            links: Vec::new(),
        }];
        let rows = model_csv_rows(&f);
        assert_eq!(
            rows,
            "1003,3,leg,true,0.250,hip,0.000000000,0.100000000,0.000000000,0.995000000,true,false,0.200\n\
             1003,3,leg,true,0.250,knee,0.500000000,,,,false,true,\n"
        );
        assert_eq!(
            MODELS_CSV_HEADER.split(',').count(),
            rows.lines().next().unwrap().split(',').count()
        );
    }

    fn frame(seq: u64) -> PoseFrame {
        PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            sequence: seq,
            timestamp_ns: 1000 + seq,
            frame_published_ns: 0,
            published_ns: 0,
            cameras: vec!["a".into(), "b".into()],
            poses: vec![Pose {
                object_id: 7,
                position_m: [0.5, -0.25, 1.0],
                velocity_m_per_s: [0.0; 3],
                heading_deg: None,
                heading_directed: false,
                method: PoseMethod::DepthFromArea,
                cameras: vec!["a".into()],
                residual_px: 0.0,
                out_of_range: true,
                body: None,
                model: None,
            }],
            bodies: Vec::new(),
            models: Vec::new(),
        }
    }

    #[test]
    fn csv_rows_follow_the_header() {
        let r = csv_rows(&frame(3));
        assert_eq!(
            r,
            "1003,3,7,0.500000,-0.250000,1.000000,,false,depth_from_area,a,0.0000,,\n"
        );
        assert_eq!(POSES_CSV_HEADER.split(',').count(), r.split(',').count());
    }

    #[test]
    fn reading_names_file_and_line() {
        let dir = std::env::temp_dir().join(format!("session-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let info = SessionInfo {
            schema: SESSION_SCHEMA,
            rig: "r".into(),
            started_ns: 1,
            rig_file: String::new(),
        };
        std::fs::write(dir.join("session.json"), serde_json::to_vec(&info).unwrap()).unwrap();
        let lines: Vec<String> = (0..3)
            .map(|i| String::from_utf8(frame(i).to_json()).unwrap())
            .collect();
        std::fs::write(dir.join("poses.jsonl"), lines.join("\n") + "\n").unwrap();
        std::fs::write(dir.join("observations.jsonl"), "").unwrap();
        let s = Session::read(&dir).unwrap();
        assert_eq!(s.poses.len(), 3);
        assert_eq!(s.poses[2], frame(2));
        // An incomplete last line: kept what came before, warned.
        std::fs::write(
            dir.join("poses.jsonl"),
            lines.join("\n") + "\n{\"schema\":1,",
        )
        .unwrap();
        let s = Session::read(&dir).unwrap();
        assert_eq!(s.poses.len(), 3);
        assert!(s.warnings[0].contains("poses.jsonl:4"), "{:?}", s.warnings);
        // A bad line in the middle is an error with file and line.
        let bad = format!("{}\nnot json\n{}\n", lines[0], lines[1]);
        std::fs::write(dir.join("poses.jsonl"), bad).unwrap();
        let err = Session::read(&dir).unwrap_err();
        assert!(
            matches!(
                err,
                SessionError {
                    line: Some(2),
                    problem: SessionProblem::Record(_),
                    ..
                }
            ),
            "{err:?}"
        );
        let e = err.to_string();
        assert!(e.contains("poses.jsonl:2"), "{e}");
        let other = SessionInfo {
            schema: SESSION_SCHEMA + 1,
            ..info.clone()
        };
        std::fs::write(
            dir.join("session.json"),
            serde_json::to_vec(&other).unwrap(),
        )
        .unwrap();
        let err = Session::read(&dir).unwrap_err();
        assert!(
            matches!(err.problem, SessionProblem::Schema { found } if found == SESSION_SCHEMA + 1),
            "{err:?}"
        );
        std::fs::remove_file(dir.join("session.json")).unwrap();
        let err = Session::read(&dir).unwrap_err();
        assert!(matches!(err.problem, SessionProblem::Read(_)), "{err:?}");
        let e = err.to_string();
        assert!(e.contains("session.json"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
