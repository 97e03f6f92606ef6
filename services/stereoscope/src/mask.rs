//! `stereoscope calibrate mask`: rectangles where what is bright is not a marker — a lamp, a
//! window, a reflection on a shiny floor — found by watching a running rig with no markers in
//! view, as motion-capture systems do before a wand wave (`docs/calibration.md`, "Masks").
//! Every blob the moment workers report while it listens becomes a rectangle (its bounding
//! box grown by a margin, overlapping ones joined: `stereoscope_calibration::mask`); written
//! into each camera's
//! `moments.mask`, they make the workers ignore blobs whose centroid falls inside
//! (`stereoscope_vision::Tracker::set_mask`). `--check` listens again and names what the
//! cameras still see.

use anyhow::{Context as _, anyhow};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use stereoscope_calibration::mask::{Rect, join, rectangles, share_pct};
use stereoscope_proto::messages::Observation;
use stereoscope_rig::Rig;
use stereoscope_rig::moments::MAX_MASK_RECTS;
use stereoscope_transport::net::{self, ZenohSpec};

#[derive(Debug, Clone)]
pub struct MaskOptions {
    pub rig: PathBuf,
    /// A Zenoh router to ask (default: the rig's first host's).
    pub connect: Option<String>,
    pub seconds: f64,
    /// Pixels added round each blob's box.
    pub grow_px: u32,
    /// Write the rig with the masks here.
    pub out: Option<PathBuf>,
    /// Only report what the cameras see now.
    pub check: bool,
    pub tls: stereoscope_service::context::TlsArgs,
}

/// How a tool reaches a rig's router: `connect` if given, else the rig's first host's
/// endpoint for its services (with the host's certificate when it says `local_auth`), else
/// `tcp/127.0.0.1:7447`; certificates given on the command line are used over the rig's.
pub fn tool_zenoh(
    rig: Option<&Rig>,
    connect: Option<String>,
    tls: &stereoscope_service::context::TlsArgs,
) -> anyhow::Result<ZenohSpec> {
    let host = rig.and_then(|r| r.spec.hosts.first().map(|h| (r, h)));
    let mut zenoh = match (connect, host) {
        (Some(endpoint), _) => ZenohSpec::client_of(&endpoint),
        (None, Some((r, h))) => stereoscope_service::context::default_zenoh(r, Some(h))?,
        (None, None) => ZenohSpec::client_of("tcp/127.0.0.1:7447"),
    };
    if let Some(t) = tls.files() {
        zenoh.tls = Some(t);
    }
    Ok(zenoh)
}

/// A client session to the rig's router (or `connect`, [`tool_zenoh`]), and the endpoint
/// asked.
pub fn client_session(
    rig: &Rig,
    connect: Option<String>,
    tls: &stereoscope_service::context::TlsArgs,
) -> anyhow::Result<(zenoh::Session, String)> {
    let zenoh = tool_zenoh(Some(rig), connect, tls)?;
    let endpoint = zenoh.connect.join(", ");
    let session =
        net::open_client(&zenoh).with_context(|| format!("asking the router at {endpoint}"))?;
    Ok((session, endpoint))
}

/// Listens to every camera's observations for `seconds`.
fn listen(rig: &Rig, opts: &MaskOptions) -> anyhow::Result<Vec<Observation>> {
    let (session, endpoint) = client_session(rig, opts.connect.clone(), &opts.tls)?;
    let inlet = crate::wand_live::observations_inlet(&session, rig)?;
    eprintln!(
        "listening {} s to {endpoint} for what the cameras see …",
        opts.seconds
    );
    std::thread::sleep(std::time::Duration::from_secs_f64(opts.seconds));
    let mut refused = stereoscope_transport::Counters::default();
    let got: Vec<Observation> = std::iter::from_fn(|| inlet.try_next(&mut refused)).collect();
    if let Some(r) = refused.refusals() {
        eprintln!("observations {r}");
    }
    Ok(got)
}

/// Runs the command; returns how many cameras still see something with `--check` (the exit
/// status is 1 when any does), else 0.
pub fn run(opts: &MaskOptions, out: &mut impl Write) -> anyhow::Result<usize> {
    if !(opts.seconds.is_finite() && (0.5..=600.0).contains(&opts.seconds)) {
        anyhow::bail!("--seconds {} is not between 0.5 and 600", opts.seconds);
    }
    if opts.grow_px > 1000 {
        anyhow::bail!("--grow {} is over 1000 pixels", opts.grow_px);
    }
    let rig = Rig::load(&opts.rig)?;
    let size_of = |id: &str| rig.camera_index(id).map(|i| rig.spec.cameras[i].image_size);
    let observations = listen(&rig, opts)?;
    let silent: Vec<&str> = rig
        .cameras
        .iter()
        .map(|c| c.id.as_str())
        .filter(|id| !observations.iter().any(|o| o.camera == *id))
        .collect();
    if silent.len() == rig.cameras.len() {
        anyhow::bail!(
            "no observation from any camera of rig {:?} in {} s: is it running (stereoscope run)?",
            rig.name,
            opts.seconds
        );
    }
    for id in &silent {
        writeln!(
            out,
            "warning: camera {id} sent nothing: is its worker running?"
        )?;
    }
    let found = rectangles(
        &observations,
        size_of,
        if opts.check { 0 } else { opts.grow_px },
    );
    if opts.check {
        let mut seeing = 0;
        for c in &rig.cameras {
            let rects = found.get(&c.id).map(Vec::as_slice).unwrap_or_default();
            if rects.is_empty() {
                writeln!(out, "{}: sees nothing", c.id)?;
            } else {
                seeing += 1;
                writeln!(out, "{}: sees {} places: {:?}", c.id, rects.len(), rects)?;
            }
        }
        return Ok(seeing);
    }
    let mut masks: BTreeMap<String, Vec<Rect>> = BTreeMap::new();
    for (i, c) in rig.cameras.iter().enumerate() {
        let spec = &rig.spec.cameras[i];
        let [w, h] = spec.image_size;
        // The masks the workers use already (they report nothing there) stay.
        let mut rects: Vec<Rect> = spec
            .moments
            .as_ref()
            .map(|m| m.mask.clone())
            .unwrap_or_default();
        let before = rects.len();
        rects.extend(found.get(&c.id).cloned().unwrap_or_default());
        let rects = join(rects);
        if rects.len() > MAX_MASK_RECTS {
            anyhow::bail!(
                "camera {}: {} rectangles, over the {MAX_MASK_RECTS} a camera may have: is a marker in view?",
                c.id,
                rects.len()
            );
        }
        writeln!(
            out,
            "{}: {} rectangles ({} new), {:.2} % of the image masked{}",
            c.id,
            rects.len(),
            rects.len().saturating_sub(before),
            share_pct(&rects, w, h),
            if share_pct(&rects, w, h) > 5.0 {
                " — much: was a marker in view?"
            } else {
                ""
            }
        )?;
        masks.insert(c.id.clone(), rects);
    }
    match &opts.out {
        Some(path) => {
            write_masks(&opts.rig, path, &masks)?;
            writeln!(
                out,
                "wrote {}: restart the rig's services on it, then `stereoscope calibrate mask --check` shows what the cameras still see",
                path.display()
            )?;
        }
        None => writeln!(out, "(give --out RIG.toml to write the masks)")?,
    }
    Ok(0)
}

/// The rig file with each camera's `moments.mask` set, comments and layout kept.
fn write_masks(
    rig_path: &Path,
    out: &Path,
    masks: &BTreeMap<String, Vec<Rect>>,
) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(rig_path)
        .with_context(|| format!("reading {}", rig_path.display()))?;
    let text = with_masks(&text, rig_path, masks)?;
    // What is written must load.
    Rig::from_toml(&text).with_context(|| format!("the rig with masks for {}", out.display()))?;
    std::fs::write(out, text).with_context(|| format!("writing {}", out.display()))
}

/// A rig file's text with each camera's `moments.mask` set (`path` names it in errors).
fn with_masks(
    text: &str,
    rig_path: &Path,
    masks: &BTreeMap<String, Vec<Rect>>,
) -> anyhow::Result<String> {
    let mut doc: toml_edit::DocumentMut = text
        .parse()
        .map_err(|e| anyhow!("{}: {e}", rig_path.display()))?;
    let cams = doc
        .get_mut("camera")
        .and_then(|c| c.as_array_of_tables_mut())
        .ok_or_else(|| anyhow!("{}: no [[camera]] tables", rig_path.display()))?;
    for cam in cams.iter_mut() {
        let Some(id) = cam.get("id").and_then(|v| v.as_str()).map(str::to_string) else {
            continue;
        };
        let Some(rects) = masks.get(&id) else {
            continue;
        };
        let mut list = toml_edit::Array::new();
        for r in rects {
            let mut a = toml_edit::Array::new();
            for v in r {
                a.push(*v as i64);
            }
            list.push(a);
        }
        match cam.get_mut("moments") {
            Some(toml_edit::Item::Value(toml_edit::Value::InlineTable(t))) => {
                t.insert("mask", toml_edit::Value::Array(list));
                // `{ max_objects = 10, mask = … }`: the spacing made anew, not the old last
                // value's space before the closing brace kept before the comma.
                t.fmt();
            }
            Some(toml_edit::Item::Table(t)) => {
                t.insert("mask", toml_edit::value(list));
            }
            _ => {
                let mut t = toml_edit::InlineTable::new();
                t.insert("mask", toml_edit::Value::Array(list));
                cam.insert("moments", toml_edit::value(t));
            }
        }
    }
    Ok(doc.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mask added to an inline `moments` table reads as a person would write it.
    #[test]
    fn a_mask_joins_an_inline_moments_table_tidily() {
        let text = "[[camera]]\nid = \"cam0\"\nmoments = { max_objects = 10 }\n";
        let masks = BTreeMap::from([("cam0".to_string(), vec![[1, 2, 3, 4]])]);
        let got = with_masks(text, Path::new("rig.toml"), &masks).unwrap();
        assert!(
            got.contains("moments = { max_objects = 10, mask = [[1, 2, 3, 4]] }"),
            "{got}"
        );
    }
}
