//! `stereoscope calibrate wand --live` (`docs/calibration.md`): the running rig's
//! observations collected until every camera's image is covered by the wand, a bar per camera
//! filling meanwhile on the terminal, and the coverage published on Zenoh for the viewer.

use crate::wand::{COVERAGE_CELLS, MAX_ROWS, blob_pixels, cell_of, share};
use anyhow::bail;
use std::io::Write;
use stereoscope_geometry::Camera;
use stereoscope_geometry::wand::Wand;
use stereoscope_proto::messages::{
    CameraCoverage, Observation, SCHEMA_VERSION, WandCoverage, now_ns,
};
use stereoscope_rig::Rig;
use stereoscope_transport::{Counters, Inlet};

/// `--live`: how long to collect and what is enough.
#[derive(Debug, Clone)]
pub struct LiveWand {
    /// A Zenoh router to ask (default: the rig's first host's).
    pub connect: Option<String>,
    pub tls: stereoscope_service::context::TlsArgs,
    /// Longest collection, seconds.
    pub max_seconds: f64,
    /// Share of each camera's image cells to cover before solving.
    pub target: f64,
    /// Fewest wand samples per camera before solving.
    pub min_samples: u64,
}

/// Collects the running rig's observations until every camera's image is covered (or
/// `max_seconds` pass): a bar per camera on `err`, and the coverage published on Zenoh
/// (`stereoscope/<rig>/calibration/coverage`) for the viewer, twice a second.
pub fn collect_live(
    rig: &Rig,
    cams: &[Camera],
    wand: &Wand,
    live: &LiveWand,
    err: &mut impl Write,
) -> anyhow::Result<Vec<Observation>> {
    use stereoscope_proto::names::zenoh as keys;
    use stereoscope_transport::net;
    let ids: Vec<String> = rig.cameras.iter().map(|c| c.id.clone()).collect();
    let (session, endpoint) = crate::mask::client_session(rig, live.connect.clone(), &live.tls)?;
    let mut refused = Counters::default();
    let inlet = observations_inlet(&session, rig)?;
    let publisher = net::JsonPublisher::new(&session, &keys::wand_coverage(&rig.name))?;
    let (cx, cy) = COVERAGE_CELLS;
    let mut counts = vec![vec![0u32; cx * cy]; ids.len()];
    let mut samples = vec![0u64; ids.len()];
    let mut all = Vec::new();
    let start = std::time::Instant::now();
    let every = std::time::Duration::from_millis(500);
    let mut next_report = start;
    writeln!(
        err,
        "wave the wand through the volume ({endpoint}); each camera's bar fills as the wand covers its image (goal {:.0} %, {} samples) …",
        100.0 * live.target,
        live.min_samples
    )?;
    loop {
        if let Some(o) = inlet.next_within(std::time::Duration::from_millis(50), &mut refused) {
            let more = std::iter::from_fn(|| inlet.try_next(&mut refused));
            for o in std::iter::once(o).chain(more.collect::<Vec<_>>()) {
                if all.len() >= MAX_ROWS {
                    bail!("more than {MAX_ROWS} observations collected");
                }
                if let Some(c) = ids.iter().position(|id| *id == o.camera) {
                    let px = blob_pixels(&o);
                    if px.len() == wand.markers() {
                        samples[c] += 1;
                        for p in &px {
                            counts[c][cell_of(&cams[c], p)] += 1;
                        }
                    }
                }
                all.push(o);
            }
        }
        let cov: Vec<f64> = counts.iter().map(|c| share(c)).collect();
        let covered = cov
            .iter()
            .zip(&samples)
            .all(|(&f, &n)| f >= live.target && n >= live.min_samples);
        let out_of_time = start.elapsed().as_secs_f64() >= live.max_seconds;
        let done = covered || out_of_time;
        if std::time::Instant::now() >= next_report || done {
            next_report += every;
            let bars: Vec<String> = ids
                .iter()
                .zip(&cov)
                .zip(&samples)
                .map(|((id, f), n)| {
                    let full = (f * 10.0).round() as usize;
                    format!(
                        "{id} [{}{}] {:3.0} % {n}",
                        "#".repeat(full),
                        "-".repeat(10 - full.min(10)),
                        f * 100.0
                    )
                })
                .collect();
            write!(err, "\r{}", bars.join("  "))?;
            let msg = WandCoverage {
                schema: SCHEMA_VERSION,
                rig: rig.name.clone(),
                published_ns: now_ns(),
                target: live.target,
                done,
                cameras: ids
                    .iter()
                    .enumerate()
                    .map(|(c, id)| CameraCoverage {
                        camera: id.clone(),
                        cols: cx as u32,
                        rows: cy as u32,
                        counts: counts[c].clone(),
                        coverage: cov[c],
                        samples: samples[c],
                    })
                    .collect(),
            };
            // The viewer's picture only: a failed put loses nothing of the calibration.
            let _ = publisher.put(&msg);
        }
        if done {
            writeln!(err)?;
            if !covered {
                writeln!(
                    err,
                    "warning: out of time ({} s) before every camera was covered; solving with what there is",
                    live.max_seconds
                )?;
            }
            if let Some(r) = refused.refusals() {
                writeln!(err, "observations {r}")?;
            }
            return Ok(all);
        }
    }
}

/// Every camera's observations of `rig` on the router, each checked: of this rig, and of the
/// camera whose key it came on (a camera the rig does not have is refused).
pub fn observations_inlet(
    session: &zenoh::Session,
    rig: &Rig,
) -> anyhow::Result<Inlet<Observation>> {
    use stereoscope_proto::names::zenoh as keys;
    let (name, ids): (String, Vec<String>) = (
        rig.name.clone(),
        rig.cameras.iter().map(|c| c.id.clone()).collect(),
    );
    let inlet = Inlet::zenoh(
        session,
        &[keys::all_observations(&rig.name)],
        &rig.name,
        "observation",
        100_000,
    )?
    .expecting(move |key, o: &Observation| {
        if !ids.contains(&o.camera) {
            Err(format!("of camera {:?}, not one of the rig's", o.camera).into())
        } else if key != keys::observations(&name, &o.camera) {
            Err(format!("of camera {:?} on another camera's key", o.camera).into())
        } else {
            Ok(())
        }
    });
    Ok(inlet)
}
