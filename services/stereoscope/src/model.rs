//! `stereoscope model define NAME --rig RIG --session DIR`: a kinematic model's markers, and
//! its measured link lengths, from a recorded range-of-motion take (`docs/models.md`,
//! "Defining a model"). The skeleton (links and joints) is a URDF (`--urdf`) or the rig's
//! `[[model]]` of that name; a second session (`--home`) shows the model standing still at its
//! zero pose.
//! The algorithm is `stereoscope_kinematics::define`; this is its file handling and report.

use anyhow::{Context as _, anyhow, bail};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stereoscope_kinematics::define::{DefineOptions, Defined, Track, define_model};
use stereoscope_kinematics::{Base, FitOptions, Model, fit_chain, model_from_urdf};
use stereoscope_proto::messages::{PoseFrame, PoseMethod};
use stereoscope_rig::Rig;

/// A definition whose markers' RMS residual, fitted back to its own take, has a median above
/// this (or that fits under 90 % of the frames) is not written.
pub const MAX_REFIT_MEDIAN_M: f64 = 0.0015;

/// What `model define` is asked.
#[derive(Debug, Clone)]
pub struct ModelDefineOptions {
    pub name: String,
    pub rig: PathBuf,
    pub session: PathBuf,
    pub urdf: Option<PathBuf>,
    /// The session of the model standing still at its zero pose.
    pub home: PathBuf,
    /// Markers are on one link when their distance varies less than this, rig file unit.
    pub rigid_tolerance: Option<f64>,
    pub write: bool,
}

/// What it found: the `[[model]]` table, the report, and the report's figures as JSON.
#[derive(Debug)]
pub struct ModelDefined {
    pub table: String,
    pub report: String,
    pub json: serde_json::Value,
}

/// Every triangulated marker of the take that is not a rigid body's, one track per object id.
pub fn tracks(frames: &[PoseFrame]) -> Vec<Track> {
    let mut index = std::collections::BTreeMap::new();
    let mut tracks: Vec<Track> = Vec::new();
    for (f, frame) in frames.iter().enumerate() {
        for p in &frame.poses {
            if p.body.is_some() || p.method != PoseMethod::Triangulated {
                continue;
            }
            let k = *index.entry(p.object_id).or_insert_with(|| {
                tracks.push(Track {
                    id: p.object_id,
                    points: vec![None; frames.len()],
                });
                tracks.len() - 1
            });
            tracks[k].points[f] = Some(nalgebra::Point3::from(p.position_m));
        }
    }
    tracks
}

/// The skeleton: the URDF given, or the rig's model of that name (its markers are replaced).
fn skeleton(opts: &ModelDefineOptions, rig: &Rig) -> anyhow::Result<Model> {
    let base = rig
        .models
        .iter()
        .find(|m| m.model.name == opts.name)
        .map_or(Base::Floating, |m| m.model.base.clone());
    if let Some(path) = &opts.urdf {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        let mut m = model_from_urdf(&path.display().to_string(), &text, &[], base)?;
        m.name.clone_from(&opts.name);
        return Ok(m);
    }
    rig.models
        .iter()
        .find(|m| m.model.name == opts.name)
        .map(|m| m.model.clone())
        .ok_or_else(|| {
            anyhow!(
                "{}: no [[model]] named {:?}; give its skeleton with --urdf",
                opts.rig.display(),
                opts.name
            )
        })
}

/// Runs the definition on the session's pose frames.
pub fn define(opts: &ModelDefineOptions) -> anyhow::Result<ModelDefined> {
    let rig = Rig::load(&opts.rig)?;
    if !stereoscope_proto::names::valid_segment(&opts.name) {
        bail!(
            "model name {:?}: 1–32 letters, digits, '_' or '-' (it is part of network keys)",
            opts.name
        );
    }
    let skeleton = skeleton(opts, &rig)?;
    let read = |dir: &Path| -> anyhow::Result<Vec<PoseFrame>> {
        let session = stereoscope_recorder::session::Session::read(dir)?;
        for w in &session.warnings {
            eprintln!("{w}");
        }
        if session.poses.is_empty() {
            bail!("{}: no pose frames in the session", dir.display());
        }
        Ok(session.poses)
    };
    let frames = &read(&opts.session)?;
    let home_frames = &read(&opts.home)?;
    let scale = rig.spec.units.metres();
    let define_opts = DefineOptions {
        rigid_tolerance_m: opts
            .rigid_tolerance
            .map_or(DefineOptions::default().rigid_tolerance_m, |t| t * scale),
        ..DefineOptions::default()
    };
    let tracks = tracks(frames);
    let home_tracks = self::tracks(home_frames);
    // The whole take first; where that does not fit, its first, last and middle two thirds,
    // then halves (a stretch in which fewer ids passed between neighbouring markers), until one
    // fits; else the definition that fits its stretch best.
    let n = frames.len();
    let mut tried: Vec<(usize, usize, Defined, Refit)> = Vec::new();
    let mut first_error = None;
    let stretches = [
        (0, n),
        (0, 2 * n / 3),
        (n / 3, n),
        (n / 6, 5 * n / 6),
        (0, n / 2),
        (n / 4, 3 * n / 4),
        (n / 2, n),
    ];
    for (from, to) in stretches {
        let stretch: Vec<Track> = tracks
            .iter()
            .map(|t| Track {
                id: t.id,
                points: t.points[from..to].to_vec(),
            })
            .collect();
        match define_model(&skeleton, &stretch, &home_tracks, &define_opts) {
            Ok(d) => {
                let check = refit(&d, to - from);
                let good = fits(&check, to - from);
                tried.push((from, to, d, check));
                if good {
                    break;
                }
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    let best = tried.into_iter().max_by(|a, b| {
        let score = |x: &(usize, usize, Defined, Refit)| {
            (
                fits(&x.3, x.1 - x.0),
                x.3.valid as f64 / (x.1 - x.0) as f64,
                -x.3.median_m,
            )
        };
        let (sa, sb) = (score(a), score(b));
        sa.0.cmp(&sb.0)
            .then(sa.1.total_cmp(&sb.1))
            .then(sa.2.total_cmp(&sb.2))
    });
    let Some((from, to, d, check)) = best else {
        let e = first_error.map_or_else(|| anyhow!("no definition"), anyhow::Error::from);
        return Err(e.context(format!(
            "{} ({} frames, {} marker tracks), zero pose {} ({} frames): model {:?}",
            opts.session.display(),
            frames.len(),
            tracks.len(),
            opts.home.display(),
            home_frames.len(),
            opts.name,
        )));
    };
    let frames = &frames[from..to];
    let mut report = report(&d, &check, frames.len(), home_frames.len(), scale);
    if (from, to) != (0, n) {
        report = format!(
            "the whole take did not define a model that fits it; frames {from}–{} did:\n{report}",
            to - 1
        );
    }
    let mut json = figures(&d, &check, frames.len());
    json["from_frame"] = serde_json::json!(from);
    // A definition that does not fit its own take is not written: the markers or the links
    // were found wrong (ids passed between neighbouring markers can join two links).
    if opts.write && !fits(&check, frames.len()) {
        bail!(
            "{report}the defined model fits its own take in {} of {} frames (RMS median {:.2} mm): not written to {}; record the take again, slower or with more cameras",
            check.valid,
            frames.len(),
            check.median_m * 1e3,
            opts.rig.display()
        );
    }
    let table = table(opts, &rig, &d, scale)?;
    Ok(ModelDefined {
        table,
        report,
        json,
    })
}

/// The defined model fitted back to the take, frame by frame: frames valid, median and 95th
/// percentile RMS (metres).
struct Refit {
    valid: usize,
    median_m: f64,
    p95_m: f64,
}

/// Fitted back in 90 % of its frames or more, with a median RMS within
/// [`MAX_REFIT_MEDIAN_M`].
fn fits(check: &Refit, frames: usize) -> bool {
    check.valid * 10 >= frames * 9 && check.median_m <= MAX_REFIT_MEDIAN_M
}

fn refit(d: &Defined, frames: usize) -> Refit {
    let mut prev = None;
    let mut rms = Vec::new();
    let opts = FitOptions::default();
    for f in 0..frames {
        let observed: Vec<Option<nalgebra::Point3<f64>>> =
            d.observations.iter().map(|o| o[f]).collect();
        match fit_chain(&d.model, &observed, prev.as_ref(), &opts) {
            Ok(fit) if fit.valid => {
                rms.push(fit.rms_m);
                prev = Some(fit.state);
            }
            _ => prev = None,
        }
    }
    rms.sort_by(f64::total_cmp);
    let at = |q: f64| {
        rms.get(((rms.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    Refit {
        valid: rms.len(),
        median_m: at(0.5),
        p95_m: at(0.95),
    }
}

fn report(d: &Defined, check: &Refit, frames: usize, home: usize, scale: f64) -> String {
    let unit = |m: f64| m / scale;
    let mut r = String::new();
    let _ = writeln!(
        r,
        "model {:?}: {frames} frames of motion, {home} at the zero pose",
        d.model.name
    );
    let _ = writeln!(
        r,
        "links (each marker's share of the frames it was found in, by its link's shape):"
    );
    for l in &d.links {
        let shares: Vec<String> = l
            .seen_share
            .iter()
            .map(|s| format!("{:.0} %", s * 100.0))
            .collect();
        let _ = writeln!(
            r,
            "  {:<12} {} markers ({}), {:.2} mm RMS off their mean shape",
            l.link,
            l.seen_share.len(),
            shares.join(", "),
            l.shape_rms_m * 1e3
        );
    }
    let _ = writeln!(
        r,
        "joints (SCoRE centre / SARA axis; residual per frame; the skeleton registered at the zero pose):"
    );
    for j in &d.joints {
        let axis = j
            .axis_residual_rad
            .map_or(String::new(), |a| format!(", axis {:.3}°", a.to_degrees()));
        let reg = j
            .registration_rad
            .map_or(String::new(), |a| format!(", {:.3}°", a.to_degrees()));
        let _ = writeln!(
            r,
            "  {:<14} {:<10} {:.2} mm{axis} over {} frames; skeleton off by {:.2} mm{reg}",
            j.name,
            j.kind,
            j.residual_m * 1e3,
            j.frames,
            j.registration_m * 1e3
        );
    }
    let _ = writeln!(
        r,
        "link lengths (axis to axis along their common normal, to a centre, centre to centre), rig file unit:"
    );
    for l in &d.lengths {
        let angle = match (l.measured_angle_rad, l.model_angle_rad) {
            (Some(a), Some(b)) => format!(
                ", axes at {:.2}° (skeleton {:.2}°)",
                a.to_degrees(),
                b.to_degrees()
            ),
            _ => String::new(),
        };
        let _ = writeln!(
            r,
            "  {:<12} {} → {}: {:.3} measured, {:.3} in the skeleton ({:+.3} mm){angle}",
            l.link,
            l.from_joint,
            l.to_joint,
            unit(l.measured_m),
            unit(l.model_m),
            (l.measured_m - l.model_m) * 1e3
        );
    }
    let _ = writeln!(
        r,
        "the model fitted back to the take: {} of {frames} frames valid, RMS median {:.2} mm, 95th percentile {:.2} mm",
        check.valid,
        check.median_m * 1e3,
        check.p95_m * 1e3
    );
    if !d.left_out.is_empty() {
        let _ = writeln!(
            r,
            "left out (seen too seldom or on no rigid cluster of 3): objects {:?}",
            d.left_out
        );
    }
    r
}

fn figures(d: &Defined, check: &Refit, frames: usize) -> serde_json::Value {
    serde_json::json!({
        "model": d.model.name,
        "frames": frames,
        "links": d.links.iter().map(|l| serde_json::json!({
            "link": l.link, "markers": l.seen_share.len(), "seen_share": l.seen_share,
            "shape_rms_m": l.shape_rms_m,
        })).collect::<Vec<_>>(),
        "joints": d.joints.iter().map(|j| serde_json::json!({
            "name": j.name, "kind": j.kind, "residual_m": j.residual_m,
            "axis_residual_deg": j.axis_residual_rad.map(f64::to_degrees),
            "registration_m": j.registration_m,
        })).collect::<Vec<_>>(),
        "lengths": d.lengths.iter().map(|l| serde_json::json!({
            "link": l.link, "from": l.from_joint, "to": l.to_joint,
            "measured_m": l.measured_m, "model_m": l.model_m,
            "measured_angle_deg": l.measured_angle_rad.map(f64::to_degrees),
            "model_angle_deg": l.model_angle_rad.map(f64::to_degrees),
        })).collect::<Vec<_>>(),
        "refit": { "valid": check.valid, "median_rms_m": check.median_m, "p95_rms_m": check.p95_m },
        "fits": fits(check, frames),
        "left_out": d.left_out,
    })
}

/// The markers as `[[model.marker]]` tables in the rig file's unit, rounded to a micrometre.
fn marker_tables(d: &Defined, scale: f64) -> toml_edit::ArrayOfTables {
    let mut out = toml_edit::ArrayOfTables::new();
    for m in &d.markers {
        let mut t = toml_edit::Table::new();
        t.insert("name", toml_edit::value(m.name.clone()));
        t.insert("link", toml_edit::value(m.link.clone()));
        let mut p = toml_edit::Array::new();
        // A micrometre in the file's unit: 6 decimals for metres, 3 for millimetres.
        let decimals = (-(1e-6 / scale).log10()).round().max(0.0) as usize;
        for v in m.in_link_m {
            let x = v / scale;
            p.push(format!("{x:.decimals$}").parse::<f64>().unwrap_or(x));
        }
        t.insert("position", toml_edit::value(p));
        out.push(t);
    }
    out
}

/// The `[[model]]` table, alone (printed) or in the rig file (`--write`: the model of that
/// name gets the new markers, and the URDF given; or the table is appended), the whole file
/// checked before it replaces the old one.
fn table(opts: &ModelDefineOptions, rig: &Rig, d: &Defined, scale: f64) -> anyhow::Result<String> {
    let urdf_key = opts.urdf.as_ref().map(|u| relative_to(u, &opts.rig));
    let existing = rig.spec.models.iter().position(|m| m.name == opts.name);
    let mut new_table = toml_edit::Table::new();
    new_table.insert("name", toml_edit::value(opts.name.clone()));
    match (&urdf_key, existing) {
        (Some(u), _) => {
            new_table.insert("urdf", toml_edit::value(u.clone()));
        }
        (None, Some(k)) => {
            // The rig's own skeleton, as it is written there.
            let spec = &rig.spec.models[k];
            let mut s = spec.clone();
            s.markers.clear();
            let text = toml::to_string(&s)?;
            let doc: toml_edit::DocumentMut = text.parse()?;
            for (key, item) in doc.iter() {
                if key != "name" && key != "marker" {
                    new_table.insert(key, item.clone());
                }
            }
        }
        (None, None) => bail!("no skeleton for {:?}", opts.name),
    }
    new_table.insert(
        "marker",
        toml_edit::Item::ArrayOfTables(marker_tables(d, scale)),
    );
    let mut alone = toml_edit::DocumentMut::new();
    let mut models = toml_edit::ArrayOfTables::new();
    models.push(new_table.clone());
    alone.insert("model", toml_edit::Item::ArrayOfTables(models));
    if !opts.write {
        return Ok(alone.to_string());
    }
    let old = std::fs::read_to_string(&opts.rig)
        .with_context(|| format!("reading {}", opts.rig.display()))?;
    let mut doc: toml_edit::DocumentMut = old
        .parse()
        .map_err(|e| anyhow!("{}: {e}", opts.rig.display()))?;
    let list = doc
        .entry("model")
        .or_insert(toml_edit::Item::ArrayOfTables(
            toml_edit::ArrayOfTables::new(),
        ))
        .as_array_of_tables_mut()
        .ok_or_else(|| anyhow!("{}: `model` is not an array of tables", opts.rig.display()))?;
    let at = list
        .iter()
        .position(|t| t.get("name").and_then(|n| n.as_str()) == Some(opts.name.as_str()));
    match at.and_then(|k| list.get_mut(k)) {
        Some(t) => {
            t.insert("marker", new_table["marker"].clone());
            if let Some(u) = &urdf_key {
                t.remove("joint");
                t.insert("urdf", toml_edit::value(u.clone()));
            }
        }
        None => list.push(new_table),
    }
    let new = doc.to_string();
    let tmp = opts.rig.with_extension("toml.new");
    std::fs::write(&tmp, &new).with_context(|| format!("writing {}", tmp.display()))?;
    if let Err(e) = Rig::load(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(anyhow!(e).context(format!(
            "{} with the defined model does not load; left unchanged",
            opts.rig.display()
        )));
    }
    std::fs::rename(&tmp, &opts.rig)
        .with_context(|| format!("replacing {}", opts.rig.display()))?;
    eprintln!("written to {}", opts.rig.display());
    Ok(alone.to_string())
}

/// `path` as the rig file refers to it: relative to the rig's folder where it is inside it or
/// beside it, else as given.
fn relative_to(path: &Path, rig: &Path) -> String {
    let dir = rig.parent().unwrap_or(Path::new("."));
    let abs = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf());
    let (p, d) = (abs(path), abs(dir));
    if let Ok(rel) = p.strip_prefix(&d) {
        return rel.display().to_string();
    }
    if let Some(parent) = d.parent()
        && let Ok(rel) = p.strip_prefix(parent)
    {
        return Path::new("..").join(rel).display().to_string();
    }
    p.display().to_string()
}
