//! `stereoscope body define NAME --rig RIG`: a rigid body from what the cameras see now
//! (`docs/bodies.md`, "Defining a body"). Listens to the running rig's pose frames for a
//! while, takes the loose markers tracked through nearly all of it, averages each, and writes
//! the `[[body]]` table: origin at the markers' centroid, axes the world's at that moment,
//! positions in the rig file's unit. The new body is checked with the rig's bodies (count,
//! collinear, symmetric, confusable) before anything is written.

use nalgebra::{Point3, Vector3};
use std::collections::BTreeMap;
use stereoscope_bodies::{BodyDef, MAX_MARKERS, check_bodies};
use stereoscope_proto::messages::{PoseFrame, PoseMethod};
use stereoscope_rig::schema::{BodySpec, Units};

/// The most a recording's markers may wander about their mean shape (RMS) to make a body.
pub const MAX_SHAPE_SPREAD_M: f64 = 0.0015;

/// Share of the frames a marker must be in to be taken.
pub const MIN_SHARE: f64 = 0.9;

/// Which markers make the body and how its frame is set (`docs/bodies.md`, "Defining a body
/// from the cameras"). Coordinates in the rig file's unit, world frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DefineChoice {
    /// Only these objects (the ids the live table and `status` show).
    pub objects: Option<Vec<u32>>,
    /// Only markers inside this box (min x, y, z, max x, y, z).
    pub inside: Option<[f64; 6]>,
    pub origin: Origin,
    pub axes: Axes,
    /// Tolerance of a measured inter-marker distance, rig file unit (default 3 mm).
    pub tolerance: Option<f64>,
}

/// Where the body's origin is.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum Origin {
    /// The markers' centroid.
    #[default]
    Centroid,
    /// The k-th marker taken (in object-id order).
    Marker(usize),
    /// A point in the world, rig file unit (a tip, a pivot measured by other means).
    Point([f64; 3]),
    /// The point the body turns about (a pointer's tip in a divot), found by listening this
    /// many seconds more while the user turns the body about it (`stereoscope_bodies::pivot`).
    Pivot(f64),
}

/// How long `--origin pivot` listens to the body turning, seconds, unless told.
pub const PIVOT_SECONDS: f64 = 10.0;

/// How the body's axes lie.
#[derive(Debug, Clone, Default, PartialEq)]
pub enum Axes {
    /// The world's, at the moment of definition.
    #[default]
    World,
    /// x from marker a towards marker b, y towards marker c within the plane of the three, z
    /// their cross product (markers numbered as taken, in object-id order).
    Markers([usize; 3]),
}

/// An `--origin` or `--axes` that does not parse, with the text given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ChoiceError {
    #[error(
        "--origin {0:?}: \"centroid\", \"marker:K\", \"point:X,Y,Z\" (rig file unit) or \"pivot\" / \"pivot:SECONDS\" (1–120 s)"
    )]
    Origin(String),
    #[error("--axes {0:?}: \"world\" or \"markers:A,B,C\" (three different markers)")]
    Axes(String),
}

impl std::str::FromStr for Origin {
    type Err = ChoiceError;
    fn from_str(s: &str) -> Result<Origin, ChoiceError> {
        let bad = || ChoiceError::Origin(s.to_string());
        if s == "centroid" {
            return Ok(Origin::Centroid);
        }
        if s == "pivot" {
            return Ok(Origin::Pivot(PIVOT_SECONDS));
        }
        if let Some(t) = s.strip_prefix("pivot:") {
            return match t.parse::<f64>() {
                Ok(t) if (1.0..=120.0).contains(&t) => Ok(Origin::Pivot(t)),
                _ => Err(bad()),
            };
        }
        if let Some(k) = s.strip_prefix("marker:") {
            return k.parse().map(Origin::Marker).map_err(|_| bad());
        }
        if let Some(p) = s.strip_prefix("point:") {
            let v: Vec<f64> = p
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|_| bad())?;
            if v.len() == 3 && v.iter().all(|x| x.is_finite()) {
                return Ok(Origin::Point([v[0], v[1], v[2]]));
            }
        }
        Err(bad())
    }
}

impl std::str::FromStr for Axes {
    type Err = ChoiceError;
    fn from_str(s: &str) -> Result<Axes, ChoiceError> {
        let bad = || ChoiceError::Axes(s.to_string());
        if s == "world" {
            return Ok(Axes::World);
        }
        let k: Vec<usize> = s
            .strip_prefix("markers:")
            .ok_or_else(bad)?
            .split(',')
            .map(|x| x.trim().parse::<usize>())
            .collect::<Result<_, _>>()
            .map_err(|_| bad())?;
        match k[..] {
            [a, b, c] if a != b && b != c && a != c => Ok(Axes::Markers([a, b, c])),
            _ => Err(bad()),
        }
    }
}

/// Why no body could be defined.
#[derive(Debug, thiserror::Error)]
pub enum DefineError {
    #[error("no pose frames arrived in {seconds} s: is the rig running (stereoscope run)?")]
    NoFrames { seconds: f64 },
    #[error(
        "{found} loose markers were tracked through {share:.0} % of the {frames} frames ({ids:?}); a body needs 3 to {MAX_MARKERS}: show its markers to the cameras and hide others"
    )]
    Count {
        found: usize,
        frames: usize,
        share: f64,
        ids: Vec<u32>,
    },
    #[error(
        "marker {marker} (object {object}) moved {spread_mm:.1} mm while it was averaged: hold the body still"
    )]
    Moved {
        marker: usize,
        object: u32,
        spread_mm: f64,
    },
    #[error(
        "{what} names marker {index}; the markers taken are numbered from 0, in the order of their objects {ids:?}"
    )]
    NoSuchMarker {
        what: &'static str,
        index: usize,
        ids: Vec<u32>,
    },
    #[error("--axes markers {a}, {b}, {c} lie on one line: they give no plane")]
    Collinear { a: usize, b: usize, c: usize },
    #[error("{0}")]
    Body(#[from] stereoscope_bodies::BodyError),
    #[error(
        "the body was found whole in {found} of the {frames} frames while it turned; keep all its markers in view"
    )]
    PivotUnseen { found: usize, frames: usize },
    #[error("pivot: {0}")]
    Pivot(#[from] stereoscope_bodies::pivot::PivotError),
}

/// The body the frames show: `name`, markers (file unit) about their centroid, the given
/// tolerance (file unit; default 3 mm), checked against `existing`. Also returns each marker's
/// RMS wobble about its mean, metres (the triangulation noise).
pub fn define(
    name: &str,
    frames: &[PoseFrame],
    units: Units,
    existing: &[BodyDef],
    choice: &DefineChoice,
) -> Result<(BodySpec, f64, Vec<u32>), DefineError> {
    let scale = units.metres();
    let tolerance = choice.tolerance;
    if frames.is_empty() {
        return Err(DefineError::NoFrames { seconds: 0.0 });
    }
    let mut seen: BTreeMap<u32, Vec<Point3<f64>>> = BTreeMap::new();
    for f in frames {
        for p in &f.poses {
            let inside = choice.inside.is_none_or(|b| {
                (0..3).all(|k| {
                    let v = p.position_m[k] / scale;
                    v >= b[k].min(b[k + 3]) && v <= b[k].max(b[k + 3])
                })
            });
            let chosen = choice
                .objects
                .as_ref()
                .is_none_or(|ids| ids.contains(&p.object_id));
            if p.body.is_none() && p.method == PoseMethod::Triangulated && inside && chosen {
                seen.entry(p.object_id)
                    .or_default()
                    .push(Point3::from(p.position_m));
            }
        }
    }
    let need = (frames.len() as f64 * MIN_SHARE).ceil() as usize;
    let kept: Vec<(u32, Vec<Point3<f64>>)> =
        seen.into_iter().filter(|(_, v)| v.len() >= need).collect();
    if !(3..=MAX_MARKERS).contains(&kept.len()) {
        return Err(DefineError::Count {
            found: kept.len(),
            frames: frames.len(),
            share: MIN_SHARE * 100.0,
            ids: kept.iter().map(|(id, _)| *id).collect(),
        });
    }
    let means: Vec<Point3<f64>> = kept
        .iter()
        .map(|(_, v)| {
            Point3::from(v.iter().map(|p| p.coords).sum::<Vector3<f64>>() / v.len() as f64)
        })
        .collect();
    let mut wobble_sq = 0.0;
    let mut n = 0usize;
    for (k, ((id, v), m)) in kept.iter().zip(&means).enumerate() {
        let rms = (v.iter().map(|p| (p - m).norm_squared()).sum::<f64>() / v.len() as f64).sqrt();
        if rms > 0.005 {
            return Err(DefineError::Moved {
                marker: k,
                object: *id,
                spread_mm: rms * 1e3,
            });
        }
        wobble_sq += rms * rms * v.len() as f64;
        n += v.len();
    }
    let marker = |what: &'static str, index: usize| {
        means
            .get(index)
            .copied()
            .ok_or_else(|| DefineError::NoSuchMarker {
                what,
                index,
                ids: kept.iter().map(|(id, _)| *id).collect(),
            })
    };
    let origin = match &choice.origin {
        // A pivot is found by `pivot_point` and given here as a point.
        Origin::Centroid | Origin::Pivot(_) => {
            Point3::from(means.iter().map(|p| p.coords).sum::<Vector3<f64>>() / means.len() as f64)
        }
        Origin::Marker(k) => marker("--origin", *k)?,
        Origin::Point(p) => Point3::new(p[0] * scale, p[1] * scale, p[2] * scale),
    };
    // The body's axes in the world: columns x, y, z.
    let world_from_body = match &choice.axes {
        Axes::World => nalgebra::Matrix3::identity(),
        Axes::Markers([a, b, c]) => {
            let (pa, pb, pc) = (
                marker("--axes", *a)?,
                marker("--axes", *b)?,
                marker("--axes", *c)?,
            );
            let collinear = DefineError::Collinear {
                a: *a,
                b: *b,
                c: *c,
            };
            let x = (pb - pa)
                .try_normalize(1e-9)
                .ok_or(DefineError::Collinear {
                    a: *a,
                    b: *b,
                    c: *c,
                })?;
            let z = x.cross(&(pc - pa)).try_normalize(1e-6).ok_or(collinear)?;
            nalgebra::Matrix3::from_columns(&[x, z.cross(&x), z])
        }
    };
    let tolerance_m = tolerance.map_or(0.003, |t| t * scale);
    let def = BodyDef {
        name: name.to_string(),
        markers_m: means
            .iter()
            .map(|p| Point3::from(world_from_body.transpose() * (p - origin)))
            .collect(),
        tolerance_m,
    };
    let mut all = existing.to_vec();
    all.push(def.clone());
    check_bodies(&all)?;
    // Rounded to a micrometre in the file's unit: the file stays readable.
    let decimals = match units {
        Units::Metres => 6,
        Units::Centimetres => 4,
        Units::Millimetres => 3,
    };
    let round = |v: f64| {
        format!("{:.*}", decimals, v / scale)
            .parse::<f64>()
            .unwrap_or(v / scale)
    };
    let spec = BodySpec {
        name: name.to_string(),
        markers: def
            .markers_m
            .iter()
            .map(|p| [round(p.x), round(p.y), round(p.z)])
            .collect(),
        tolerance: tolerance.or(Some(round(0.003))),
        smoothing: None,
        predict_ms: None,
    };
    let ids = kept.iter().map(|(id, _)| *id).collect();
    Ok((spec, (wobble_sq / n.max(1) as f64).sqrt(), ids))
}

/// Where `def` (markers about its centroid, the world's axes, as [`define`] with the
/// centroid makes them) turned about while `moving` was recorded, as a world point at the
/// pose `still` shows it in: the body found whole in each frame among the loose markers
/// (`stereoscope_bodies::identify`), and the point fixed in it through those poses
/// (`stereoscope_bodies::pivot`).
pub fn pivot_point(
    def: &BodyDef,
    still: &[PoseFrame],
    moving: &[PoseFrame],
) -> Result<(Point3<f64>, stereoscope_bodies::pivot::Pivot), DefineError> {
    let whole = |f: &PoseFrame| {
        let points: Vec<Point3<f64>> = f
            .poses
            .iter()
            .filter(|p| p.body.is_none() && p.method == PoseMethod::Triangulated)
            .map(|p| Point3::from(p.position_m))
            .collect();
        stereoscope_bodies::identify(std::slice::from_ref(def), &points)
            .into_iter()
            .find(|m| m.seen() == def.markers_m.len())
            .map(|m| m.world_from_body)
    };
    let Some(at_still) = still.iter().rev().find_map(whole) else {
        return Err(DefineError::PivotUnseen {
            found: 0,
            frames: still.len(),
        });
    };
    let poses: Vec<nalgebra::Isometry3<f64>> = moving.iter().filter_map(whole).collect();
    if poses.len() < stereoscope_bodies::pivot::MIN_POSES {
        return Err(DefineError::PivotUnseen {
            found: poses.len(),
            frames: moving.len(),
        });
    }
    let p = stereoscope_bodies::pivot::pivot(&poses)?;
    Ok((at_still * p.in_body_m, p))
}

/// The `[[body]]` table as TOML.
pub fn to_toml(b: &BodySpec) -> String {
    let markers: Vec<String> = b
        .markers
        .iter()
        .map(|m| format!("[{}, {}, {}]", m[0], m[1], m[2]))
        .collect();
    let mut t = format!(
        "[[body]]\nname = {:?}\nmarkers = [{}]\n",
        b.name,
        markers.join(", ")
    );
    if let Some(tol) = b.tolerance {
        t.push_str(&format!("tolerance = {tol}\n"));
    }
    t
}

/// `stereoscope body define`: listens `seconds` to the rig's pose frames through its first
/// host's router (or `connect`), defines the body and prints its table, or appends it to the
/// rig file with `write` (read back and checked as a whole before it is kept).
pub fn define_live(
    name: &str,
    rig_path: &std::path::Path,
    connect: Option<String>,
    seconds: f64,
    write: bool,
    tls: stereoscope_service::context::TlsArgs,
    choice: &DefineChoice,
) -> anyhow::Result<String> {
    let rig = rig_for_new_body(rig_path, name)?;
    let (session, endpoint) = crate::mask::client_session(&rig, connect, &tls)?;
    let inlet = stereoscope_transport::Inlet::<PoseFrame>::zenoh(
        &session,
        &[stereoscope_proto::names::zenoh::poses(&rig.name)],
        &rig.name,
        "pose frame",
        100_000,
    )?;
    eprintln!("hold the body still: listening {seconds} s to {endpoint} …");
    std::thread::sleep(std::time::Duration::from_secs_f64(seconds.clamp(0.1, 60.0)));
    let mut refused = stereoscope_transport::Counters::default();
    let frames: Vec<PoseFrame> = std::iter::from_fn(|| inlet.try_next(&mut refused)).collect();
    if let Some(r) = refused.refusals() {
        eprintln!("pose frames {r}");
    }
    if frames.is_empty() {
        return Err(DefineError::NoFrames { seconds }.into());
    }
    let existing: Vec<BodyDef> = stereoscope_rig::body_defs(&rig.spec)
        .into_iter()
        .filter(|b| b.name != name)
        .collect();
    let (spec, wobble, ids) = match choice.origin {
        Origin::Pivot(turn_s) => {
            // The shape first (about its centroid, the world's axes), then the point it
            // turns about, then the body again with its origin there.
            let plain = DefineChoice {
                origin: Origin::Centroid,
                axes: Axes::World,
                ..choice.clone()
            };
            let (shape, _, _) = define(name, &frames, rig.spec.units, &existing, &plain)?;
            let scale = rig.spec.units.metres();
            let def = BodyDef {
                name: name.to_string(),
                markers_m: shape
                    .markers
                    .iter()
                    .map(|m| Point3::new(m[0] * scale, m[1] * scale, m[2] * scale))
                    .collect(),
                tolerance_m: shape.tolerance.map_or(0.003, |t| t * scale),
            };
            eprintln!(
                "now turn the body about the point to be its origin (a tip in a divot), tilting it \
                 both ways: listening {turn_s} s …"
            );
            let _ = std::iter::from_fn(|| inlet.try_next(&mut refused)).count();
            std::thread::sleep(std::time::Duration::from_secs_f64(turn_s));
            let moving: Vec<PoseFrame> =
                std::iter::from_fn(|| inlet.try_next(&mut refused)).collect();
            let (at, p) = pivot_point(&def, &frames, &moving)?;
            eprintln!(
                "pivot: {} poses, turned up to {:.0}°, the point held within {:.2} mm RMS",
                p.frames,
                p.turn_deg,
                p.rms_m * 1e3
            );
            let pivoted = DefineChoice {
                origin: Origin::Point([at.x / scale, at.y / scale, at.z / scale]),
                ..choice.clone()
            };
            define(name, &frames, rig.spec.units, &existing, &pivoted)?
        }
        _ => define(name, &frames, rig.spec.units, &existing, choice)?,
    };
    eprintln!(
        "{} markers from {} frames; each wobbled {:.2} mm RMS about its mean",
        spec.markers.len(),
        frames.len(),
        wobble * 1e3
    );
    finish(&spec, &ids, rig_path, write)
}

/// Lists the markers taken, and the table: appended to the rig file with `write`.
fn finish(
    spec: &BodySpec,
    ids: &[u32],
    rig_path: &std::path::Path,
    write: bool,
) -> anyhow::Result<String> {
    for (k, (id, m)) in ids.iter().zip(&spec.markers).enumerate() {
        eprintln!("  marker {k}: object {id}, at {m:?} in the body");
    }
    let text = to_toml(spec);
    if write {
        append_body(rig_path, &text)?;
    }
    Ok(text)
}

/// The rig at `rig_path`, loaded, once `name` can be a new body of it (a valid name no body
/// has).
fn rig_for_new_body(
    rig_path: &std::path::Path,
    name: &str,
) -> anyhow::Result<stereoscope_rig::Rig> {
    let rig = stereoscope_rig::Rig::load(rig_path)?;
    if !stereoscope_proto::names::valid_segment(name) {
        anyhow::bail!(
            "body name {name:?}: 1–32 letters, digits, '_' or '-' (it is part of network keys)"
        );
    }
    if rig.spec.bodies.iter().any(|b| b.name == name) {
        anyhow::bail!(
            "{}: a body named {name:?} is defined already",
            rig_path.display()
        );
    }
    Ok(rig)
}

/// Appends a `[[body]]` table to the rig file, once the whole file with it loads (written
/// beside and renamed: a failure leaves the file as it was).
fn append_body(rig_path: &std::path::Path, text: &str) -> anyhow::Result<()> {
    use anyhow::Context as _;
    let old = std::fs::read_to_string(rig_path)
        .with_context(|| format!("reading {}", rig_path.display()))?;
    // A blank line between the file's last table and the new one.
    let new = format!("{}\n\n{text}", old.trim_end());
    stereoscope_rig::Rig::from_toml(&new)
        .with_context(|| format!("{} with the new body", rig_path.display()))?;
    let tmp = rig_path.with_extension("toml.new");
    std::fs::write(&tmp, &new).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, rig_path).with_context(|| format!("replacing {}", rig_path.display()))?;
    eprintln!("added to {}", rig_path.display());
    Ok(())
}

/// The shape of markers `ids` through `frames`: in the frames that show them all, each
/// frame's markers brought onto a reference shape by their rigid motion (Kabsch) and averaged,
/// twice — first onto the first such frame, then onto that mean, leaving out the frames more
/// than [`SHAPE_FRAME_OUTLIER_M`] RMS off it (blobs of two markers merged in a view) — as a
/// pose frame of the mean shape where the markers first were together, for [`define`]; with
/// the RMS spread of the frames kept about it, metres, the frames kept and the frames showing
/// them all.
pub fn mean_shape(frames: &[PoseFrame], ids: &[u32]) -> Option<(PoseFrame, f64, usize, usize)> {
    let together: Vec<(&PoseFrame, Vec<Point3<f64>>)> = frames
        .iter()
        .filter_map(|f| {
            let ps: Option<Vec<Point3<f64>>> = ids
                .iter()
                .map(|id| {
                    f.poses
                        .iter()
                        .find(|p| p.object_id == *id && p.body.is_none())
                        .map(|p| Point3::from(p.position_m))
                })
                .collect();
            Some((f, ps?))
        })
        .collect();
    let (first_frame, first) = together.first()?.clone();
    let ones = vec![1.0; ids.len()];
    // Each frame brought onto `reference`, with its RMS residual there.
    let onto = |reference: &[Point3<f64>]| -> Vec<(Vec<Point3<f64>>, f64)> {
        together
            .iter()
            .filter_map(|(_, ps)| {
                let (m, r) = stereoscope_bodies::kabsch(ps, reference, &ones)?;
                Some((ps.iter().map(|p| m * p).collect(), r))
            })
            .collect()
    };
    let mean = |placed: &[&Vec<Point3<f64>>]| -> Vec<Point3<f64>> {
        let n = placed.len().max(1) as f64;
        (0..ids.len())
            .map(|k| Point3::from(placed.iter().map(|ps| ps[k].coords).sum::<Vector3<f64>>() / n))
            .collect()
    };
    let pass1 = onto(&first);
    let mean1 = mean(&pass1.iter().map(|(ps, _)| ps).collect::<Vec<_>>());
    let pass2 = onto(&mean1);
    let mut kept: Vec<&Vec<Point3<f64>>> = pass2
        .iter()
        .filter(|(_, r)| *r <= SHAPE_FRAME_OUTLIER_M)
        .map(|(ps, _)| ps)
        .collect();
    let used = kept.len();
    // No frame near the mean: the shape (to be refused, `used` 0) from every frame.
    if kept.is_empty() {
        kept = pass2.iter().map(|(ps, _)| ps).collect();
    }
    let shape = mean(&kept);
    let sq: f64 = kept
        .iter()
        .flat_map(|ps| ps.iter().zip(&shape).map(|(p, m)| (p - m).norm_squared()))
        .sum();
    let spread = (sq / (kept.len().max(1) * ids.len()) as f64).sqrt();
    // The mean shape placed where the markers first were together.
    let (back, _) = stereoscope_bodies::kabsch(&shape, &first, &ones)?;
    let mut frame = first_frame.clone();
    frame.poses = ids
        .iter()
        .zip(&shape)
        .filter_map(|(id, m)| {
            let mut p = first_frame
                .poses
                .iter()
                .find(|p| p.object_id == *id)?
                .clone();
            let w = back * m;
            p.position_m = [w.x, w.y, w.z];
            Some(p)
        })
        .collect();
    Some((frame, spread, used, together.len()))
}

/// A frame whose markers lie further than this (RMS) from the mean shape is left out of it.
pub const SHAPE_FRAME_OUTLIER_M: f64 = 0.002;

/// `stereoscope body define NAME --rig RIG --session DIR`: the markers that moved together in
/// a recording (`stereoscope_kinematics::moved_together`; or `--objects`), their mean shape
/// (`mean_shape`), defined as from the cameras with the origin and axes asked (the world's
/// axes and points as they were where the markers were first seen together).
pub fn define_from_session(
    name: &str,
    rig_path: &std::path::Path,
    session_dir: &std::path::Path,
    write: bool,
    choice: &DefineChoice,
) -> anyhow::Result<String> {
    let rig = rig_for_new_body(rig_path, name)?;
    if matches!(choice.origin, Origin::Pivot(_)) {
        anyhow::bail!("--origin pivot listens to the body turning live: not with --session");
    }
    let session = stereoscope_recorder::session::Session::read(session_dir)?;
    let frames = &session.poses;
    let ids: Vec<u32> = match &choice.objects {
        Some(ids) => ids.clone(),
        None => {
            let tracks = crate::model::tracks(frames);
            let groups = stereoscope_kinematics::moved_together(
                &tracks,
                &stereoscope_kinematics::DefineOptions::default(),
            );
            match groups.as_slice() {
                [] => anyhow::bail!(
                    "{}: no 3 or more markers moved together (kept their distances within 1.5 mm while moving {} cm or more) in its {} frames",
                    session_dir.display(),
                    stereoscope_kinematics::define::MIN_TRAVEL_M * 100.0,
                    frames.len()
                ),
                [g] => {
                    eprintln!(
                        "markers that moved together: objects {:?}, seen together in {} frames, travelled {:.2} m",
                        g.ids, g.frames_together, g.travel_m
                    );
                    g.ids.clone()
                }
                many => {
                    let list: Vec<String> = many
                        .iter()
                        .map(|g| format!("{:?} ({} frames)", g.ids, g.frames_together))
                        .collect();
                    anyhow::bail!(
                        "{}: several groups of markers moved together: {}; choose one with --objects",
                        session_dir.display(),
                        list.join(", ")
                    )
                }
            }
        }
    };
    let Some((frame, spread, used, together)) = mean_shape(frames, &ids) else {
        anyhow::bail!(
            "{}: objects {ids:?} are never all seen in one frame",
            session_dir.display()
        );
    };
    eprintln!(
        "their shape from {used} of the {together} frames showing them all (the rest over {} mm \
         RMS off it): each marker within {:.2} mm RMS of the mean",
        SHAPE_FRAME_OUTLIER_M * 1e3,
        spread * 1e3
    );
    // An id passed from one marker to another spoils many frames, not a few.
    if spread > MAX_SHAPE_SPREAD_M || used * 5 < together * 4 {
        anyhow::bail!(
            "{}: objects {ids:?} did not keep one shape ({used} of {together} frames within {} mm RMS of their mean, which they keep within {:.1} mm; a body needs 80 % and {} mm): an id may have passed from one marker to another; choose others with --objects",
            session_dir.display(),
            SHAPE_FRAME_OUTLIER_M * 1e3,
            spread * 1e3,
            MAX_SHAPE_SPREAD_M * 1e3
        );
    }
    let existing: Vec<BodyDef> = stereoscope_rig::body_defs(&rig.spec);
    let chosen = DefineChoice {
        objects: Some(ids),
        inside: None,
        ..choice.clone()
    };
    let (spec, _, ids) = define(name, &[frame], rig.spec.units, &existing, &chosen)?;
    finish(&spec, &ids, rig_path, write)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Pose, SCHEMA_VERSION};

    fn frame(points: &[(u32, [f64; 3])]) -> PoseFrame {
        PoseFrame {
            schema: SCHEMA_VERSION,
            rig: "r".into(),
            sequence: 0,
            timestamp_ns: 0,
            frame_published_ns: 0,
            published_ns: 0,
            cameras: vec![],
            poses: points
                .iter()
                .map(|(id, p)| Pose {
                    object_id: *id,
                    position_m: *p,
                    velocity_m_per_s: [0.0; 3],
                    heading_deg: None,
                    heading_directed: false,
                    method: PoseMethod::Triangulated,
                    cameras: vec![],
                    residual_px: 0.0,
                    out_of_range: false,
                    body: None,
                    model: None,
                })
                .collect(),
            bodies: vec![],
            models: Vec::new(),
        }
    }

    #[test]
    fn a_still_body_is_averaged_about_its_centroid_and_checked() {
        let layout = [
            [0.0, 0.0, 0.0],
            [0.18, 0.0, 0.0],
            [0.0, 0.11, 0.0],
            [0.06, 0.06, 0.08],
        ];
        let at = [0.5, -0.2, 1.0];
        let mut frames = Vec::new();
        for k in 0..40 {
            let wobble = if k % 2 == 0 { 0.0004 } else { -0.0004 };
            let mut pts: Vec<(u32, [f64; 3])> = layout
                .iter()
                .enumerate()
                .map(|(i, m)| {
                    (
                        i as u32 + 1,
                        [at[0] + m[0] + wobble, at[1] + m[1], at[2] + m[2]],
                    )
                })
                .collect();
            // A stray seen once in a while is not a marker of the body.
            if k % 5 == 0 {
                pts.push((9, [2.0, 2.0, 2.0]));
            }
            frames.push(frame(&pts));
        }
        let any = DefineChoice::default();
        let (spec, wobble, ids) = define("tool", &frames, Units::Millimetres, &[], &any).unwrap();
        assert_eq!(ids, vec![1, 2, 3, 4]);
        assert_eq!(spec.markers.len(), 4);
        assert!((wobble - 0.0004).abs() < 1e-9, "{wobble}");
        // Centroid (0.06, 0.0425, 0.02) m: marker 0 at (−60, −42.5, −20) mm.
        let m0 = spec.markers[0];
        assert!(
            (m0[0] + 60.0).abs() < 1e-6 && (m0[1] + 42.5).abs() < 1e-6,
            "{m0:?}"
        );
        assert_eq!(spec.tolerance, Some(3.0));
        let text = to_toml(&spec);
        assert!(
            text.starts_with("[[body]]\nname = \"tool\"\nmarkers = [[-60, -42.5, -20]"),
            "{text}"
        );
        // The same layout again is confusable with the first.
        let first = stereoscope_bodies::BodyDef {
            name: "first".into(),
            markers_m: layout
                .iter()
                .map(|m| Point3::new(m[0], m[1], m[2]))
                .collect(),
            tolerance_m: 0.003,
        };
        let e = define("tool", &frames, Units::Millimetres, &[first], &any).unwrap_err();
        assert!(e.to_string().contains("matches body"), "{e}");
        // Two markers only, or a marker that moves.
        let two: Vec<PoseFrame> = (0..10).map(|_| frame(&[(1, at), (2, [0.0; 3])])).collect();
        assert!(matches!(
            define("x", &two, Units::Metres, &[], &any),
            Err(DefineError::Count { found: 2, .. })
        ));
        let moving: Vec<PoseFrame> = (0..10)
            .map(|k| {
                frame(&[
                    (1, [0.01 * k as f64, 0.0, 0.0]),
                    (2, [0.3, 0.0, 0.0]),
                    (3, [0.0, 0.2, 0.0]),
                ])
            })
            .collect();
        assert!(matches!(
            define("x", &moving, Units::Metres, &[], &any),
            Err(DefineError::Moved { object: 1, .. })
        ));
    }

    #[test]
    fn markers_chosen_by_id_or_box_with_the_origin_and_axes_asked() {
        // Two bodies in view, the second moving: choosing the first's markers by id or by a
        // box defines it alone.
        let frames: Vec<PoseFrame> = (0..20)
            .map(|k| {
                let drift = 0.01 * k as f64;
                frame(&[
                    (3, [1.0, 0.0, 0.5]),
                    (5, [1.2, 0.0, 0.5]),
                    (8, [1.0, 0.1, 0.5]),
                    (11, [1.0, 0.0, 0.65]),
                    (20, [-1.0 + drift, 0.0, 0.5]),
                    (21, [-1.2 + drift, 0.0, 0.5]),
                    (22, [-1.0 + drift, 0.2, 0.5]),
                ])
            })
            .collect();
        let all = define("a", &frames, Units::Metres, &[], &DefineChoice::default());
        assert!(
            matches!(all, Err(DefineError::Moved { object: 20, .. })),
            "{all:?}"
        );
        let by_id = DefineChoice {
            objects: Some(vec![3, 5, 8, 11]),
            ..DefineChoice::default()
        };
        let (a, _, ids) = define("a", &frames, Units::Metres, &[], &by_id).unwrap();
        assert_eq!(ids, vec![3, 5, 8, 11]);
        let by_box = DefineChoice {
            inside: Some([0.5, -0.5, 0.0, 1.5, 0.5, 1.0]),
            ..DefineChoice::default()
        };
        let (b, _, _) = define("a", &frames, Units::Metres, &[], &by_box).unwrap();
        assert_eq!(a, b);
        // Origin at marker 0, x towards marker 1, y towards marker 2: the markers in the body
        // frame are (0,0,0), (0.2,0,0), (0,0.1,0), (0,0,0.15).
        let framed = DefineChoice {
            origin: "marker:0".parse().unwrap(),
            axes: "markers:0,1,2".parse().unwrap(),
            ..by_id.clone()
        };
        let (f, _, _) = define("a", &frames, Units::Metres, &[], &framed).unwrap();
        let want = [
            [0.0, 0.0, 0.0],
            [0.2, 0.0, 0.0],
            [0.0, 0.1, 0.0],
            [0.0, 0.0, 0.15],
        ];
        for (m, w) in f.markers.iter().zip(want) {
            for k in 0..3 {
                assert!((m[k] - w[k]).abs() < 1e-9, "{:?}", f.markers);
            }
        }
        // A point as origin, in the file's unit.
        let at_point = DefineChoice {
            origin: "point:1000,0,500".parse().unwrap(),
            ..by_id.clone()
        };
        let (p, _, _) = define("a", &frames, Units::Millimetres, &[], &at_point).unwrap();
        assert!((p.markers[1][0] - 200.0).abs() < 1e-6, "{:?}", p.markers);
        // Bad choices name what is wrong.
        let e = define(
            "a",
            &frames,
            Units::Metres,
            &[],
            &DefineChoice {
                origin: Origin::Marker(7),
                ..by_id.clone()
            },
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("marker 7") && e.to_string().contains("[3, 5, 8, 11]"),
            "{e}"
        );
        assert!("markers:0,0,1".parse::<Axes>().is_err());
        assert!(
            "point:1,2"
                .parse::<Origin>()
                .unwrap_err()
                .to_string()
                .contains("point:X,Y,Z")
        );
    }

    /// A pointer held still, then turned about its tip in a divot: the tip found within
    /// 0.5 mm, and the body defined with its origin there (its markers measured from the tip).
    #[test]
    fn a_pivot_origin_is_found_from_the_body_turned_about_it() {
        use nalgebra::UnitQuaternion;
        let layout = [
            Vector3::new(0.05, 0.0, 0.0),
            Vector3::new(0.20, 0.0, 0.0),
            Vector3::new(0.12, 0.06, 0.0),
            Vector3::new(0.09, -0.03, 0.05),
        ];
        // The tip at the body's own origin; the divot in the world.
        let divot = Vector3::new(0.4, 0.1, 0.9);
        let at = |rot: UnitQuaternion<f64>, noise: f64, k: usize| -> PoseFrame {
            let pts: Vec<(u32, [f64; 3])> = layout
                .iter()
                .enumerate()
                .map(|(i, m)| {
                    let w = divot + rot * m;
                    let e = noise * (((k * 7 + i * 3) % 11) as f64 / 5.0 - 1.0);
                    (i as u32 + 1, [w.x + e, w.y - e, w.z + e])
                })
                .collect();
            frame(&pts)
        };
        let still: Vec<PoseFrame> = (0..20)
            .map(|k| at(UnitQuaternion::identity(), 0.0002, k))
            .collect();
        let moving: Vec<PoseFrame> = (0..120)
            .map(|k| {
                let s = k as f64 / 120.0 * std::f64::consts::TAU;
                let rot = UnitQuaternion::from_euler_angles(
                    0.5 * s.sin(),
                    0.4 * (2.0 * s).cos() - 0.4,
                    0.2 * s,
                );
                at(rot, 0.0002, k)
            })
            .collect();
        let plain = DefineChoice::default();
        let (shape, _, _) = define("pointer", &still, Units::Metres, &[], &plain).unwrap();
        let def = BodyDef {
            name: "pointer".into(),
            markers_m: shape
                .markers
                .iter()
                .map(|m| Point3::new(m[0], m[1], m[2]))
                .collect(),
            tolerance_m: 0.003,
        };
        let (tip, p) = pivot_point(&def, &still, &moving).unwrap();
        assert!((tip.coords - divot).norm() < 0.0005, "{tip} {p:?}");
        let choice = DefineChoice {
            origin: Origin::Point([tip.x, tip.y, tip.z]),
            ..DefineChoice::default()
        };
        let (spec, _, _) = define("pointer", &still, Units::Metres, &[], &choice).unwrap();
        for (got, want) in spec.markers.iter().zip(&layout) {
            let d = Vector3::new(got[0], got[1], got[2]) - want;
            assert!(d.norm() < 0.001, "{got:?} {want}");
        }
        // Held still throughout: no turn, refused saying so.
        let e = pivot_point(&def, &still, &still).unwrap_err().to_string();
        assert!(e.contains("turned") && e.contains("15"), "{e}");
        assert_eq!("pivot:20".parse::<Origin>(), Ok(Origin::Pivot(20.0)));
        assert!("pivot:0".parse::<Origin>().is_err());
    }
}
