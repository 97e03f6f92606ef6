//! `stereoscope fit-depth --samples FILE.csv`: the thesis's area-versus-distance models
//! (Eq. 4.15–4.27) fitted to measured `area_px,distance` samples
//! (`stereoscope_geometry::depth`).

use std::io::Write;
use std::path::PathBuf;
use stereoscope_geometry::depth::{AreaModel, DepthFit, fit_three_parameter, fit_two_parameter};
use stereoscope_imageio::csv;
use stereoscope_proto::reports::DepthFitReport;

#[derive(Debug, Clone)]
pub struct FitDepthOptions {
    pub samples: PathBuf,
    pub json: bool,
}

fn report(name: &str, fit: &DepthFit, samples: &[(f64, f64)]) -> DepthFitReport {
    let (a, b, c) = match fit.model {
        AreaModel::TwoParameter { a, b } => (a, b, None),
        AreaModel::ThreeParameter { a, b, c } => (a, b, Some(c)),
    };
    DepthFitReport {
        model: name.to_string(),
        a,
        b,
        c,
        range: [fit.range.0, fit.range.1],
        rms: fit.rms,
        samples: samples
            .iter()
            .zip(&fit.residuals)
            .map(|(&(area, d), &r)| [area, d, d + r, r])
            .collect(),
    }
}

/// Runs the command; a fit that cannot be made is an `Err` naming why.
pub fn run(opts: &FitDepthOptions, out: &mut impl Write) -> anyhow::Result<()> {
    let rows = csv::read(&opts.samples, &["area_px", "distance"])?;
    let file = opts.samples.display();
    let samples = rows
        .iter()
        .map(|r| Ok((r.number(0, "area_px")?, r.number(1, "distance")?)))
        .collect::<Result<Vec<(f64, f64)>, stereoscope_imageio::csv::CsvProblem>>()
        .map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    let mut reports = Vec::new();
    let two = fit_two_parameter(&samples).map_err(|e| anyhow::anyhow!("{file}: {e}"))?;
    reports.push(report("two_parameter", &two, &samples));
    match fit_three_parameter(&samples) {
        Ok(three) => reports.push(report("three_parameter", &three, &samples)),
        Err(e) if samples.len() < 3 => {
            eprintln!("note: {file}: three-parameter model skipped: {e}")
        }
        Err(e) => return Err(anyhow::anyhow!("{file}: {e}")),
    }
    if opts.json {
        for r in &reports {
            writeln!(out, "{}", serde_json::to_string(r)?)?;
        }
        return Ok(());
    }
    writeln!(
        out,
        "{} samples, distances {} to {}",
        samples.len(),
        reports[0].range[0],
        reports[0].range[1]
    )?;
    for r in &reports {
        match r.c {
            Some(c) => writeln!(
                out,
                "three-parameter  AREA = a / (D² + b·D + c):  a = {:.6e}  b = {:.6}  c = {:.6}",
                r.a, r.b, c
            )?,
            None => writeln!(
                out,
                "two-parameter    AREA = a / (D + b)²:        a = {:.6e}  b = {:.6}",
                r.a, r.b
            )?,
        }
        writeln!(out, "  RMS distance error {:.4}", r.rms)?;
        // Ready to paste into the camera's table of a rig file (distances in the samples' unit).
        let (model, c) = match r.c {
            Some(c) => ("three_parameter", format!(", c = {c:?}")),
            None => ("two_parameter", String::new()),
        };
        writeln!(
            out,
            "  depth_from_area = {{ model = \"{model}\", a = {:?}, b = {:?}{c}, range = [{:?}, {:?}] }}",
            r.a, r.b, r.range[0], r.range[1]
        )?;
    }
    writeln!(
        out,
        "{:>12} {:>10} {:>12} {:>10} {:>12} {:>10}",
        "area_px", "distance", "fit (2p)", "error", "fit (3p)", "error"
    )?;
    for (i, s) in reports[0].samples.iter().enumerate() {
        let three = reports.get(1).map(|r| r.samples[i]);
        write!(
            out,
            "{:>12.1} {:>10.3} {:>12.3} {:>10.3}",
            s[0], s[1], s[2], s[3]
        )?;
        match three {
            Some(t) => writeln!(out, " {:>12.3} {:>10.3}", t[2], t[3])?,
            None => writeln!(out)?,
        }
    }
    Ok(())
}
