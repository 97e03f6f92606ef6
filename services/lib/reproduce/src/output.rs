//! The experiments written out: Markdown and CSV tables in the thesis's layout, the summary,
//! the plots, and the tables read back.

use crate::*;

pub(crate) fn table_md(e: &Experiment) -> String {
    let mut s = format!("# {} (thesis Table {})\n\n", e.title, e.thesis_table);
    s.push_str("| Actual height (cm) | Measured height (cm), mean | Standard deviation (cm) | Error (cm) |\n|---|---|---|---|\n");
    for r in &e.rows {
        let _ = writeln!(
            s,
            "| {:.1} | {:.2} | {:.2} | {:.2} |",
            r.actual_cm, r.mean_cm, r.sd_cm, r.error_cm
        );
    }
    let _ = writeln!(
        s,
        "\nRoot-mean-square error: **{:.3} cm** (thesis: {:.2} cm; goal: {:.3} cm).",
        e.rms_cm,
        e.thesis_rms_cm,
        e.goal_cm()
    );
    s
}

pub(crate) fn table_csv(e: &Experiment) -> String {
    let mut s =
        String::from("actual_height_cm,measured_height_cm,standard_deviation_cm,error_cm\n");
    for r in &e.rows {
        let _ = writeln!(
            s,
            "{:.1},{:.4},{:.4},{:.4}",
            r.actual_cm, r.mean_cm, r.sd_cm, r.error_cm
        );
    }
    s
}

/// The summary table: the thesis's RMS next to ours.
pub fn summary_md(r: &Report, opts: &ReproduceOptions) -> String {
    let mut s = String::from("# The thesis's experiments, reproduced\n\n");
    let _ = writeln!(
        s,
        "Setting: 320 × 240 cameras with PAR 0.86, Gaussian noise σ = {} grey levels, defocus blur σ = {} px, target {} levels above a background of {}; {} readings per height; seed {}. Calibration: {} views of a {} × {} dot grid ({} cm), RMS reprojection error {:.3} px.\n",
        opts.noise_sigma,
        opts.blur_sigma_px,
        opts.contrast,
        BACKGROUND,
        opts.readings,
        opts.seed,
        r.calibration_views,
        BOARD.0,
        BOARD.1,
        BOARD.2 * 100.0,
        r.calibration_rms_px
    );
    s.push_str("| experiment | thesis table | thesis RMS (cm) | ours RMS (cm) | goal: ⅕ of the thesis (cm) | met |\n|---|---|---|---|---|---|\n");
    for e in &r.experiments {
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {:.3} | {:.3} | {} |",
            e.title,
            e.thesis_table,
            e.thesis_rms_cm,
            e.rms_cm,
            e.goal_cm(),
            if e.rms_cm <= e.goal_cm() { "yes" } else { "no" }
        );
    }
    let (h_rms, h_max) = r.heading_error_deg();
    let _ = writeln!(
        s,
        "\nHeading of the double ball (an axis: modulo 180°), both cameras, {} readings at the centre, 2–152 cm, headings every 10°: RMS error **{:.3}°**, largest {:.2}° (goal ≤ 1° RMS: {}). The thesis did not measure it.",
        r.heading.len(),
        h_rms,
        h_max,
        if h_rms <= 1.0 { "met" } else { "not met" }
    );
    let both = rms_max(
        r.heat
            .iter()
            .filter(|c| c.method == HeatMethod::BothCameras)
            .map(|c| c.error_cm),
    );
    let one = rms_max(
        r.heat
            .iter()
            .filter(|c| matches!(c.method, HeatMethod::OneCamera(_)))
            .map(|c| c.error_cm),
    );
    let one_raw = rms_max(r.heat.iter().map(|c| c.uncorrected_error_cm));
    let unseen = r
        .heat
        .iter()
        .filter(|c| c.method == HeatMethod::Unseen)
        .count();
    let _ = write!(
        s,
        "\nHeight error across the whole {:.2} × {:.2} m board at {:.0} cm, measured as the live fusion does ({} cells, {:.0} cm apart; `heat_map.csv`, `heat_map.png`):",
        BOARD_SIZE_M.0,
        BOARD_SIZE_M.1,
        HEAT_HEIGHT_M * 100.0,
        r.heat.len(),
        HEAT_CELL_M * 100.0
    );
    if let Some((rms, worst, k)) = both {
        let _ = write!(
            s,
            " both cameras in {k} cells, RMS {rms:.3} cm, largest {worst:.3} cm;"
        );
    }
    if let (Some((rms, worst, k)), Some((raw, _, _))) = (one, one_raw) {
        let _ = write!(
            s,
            " one camera (depth from area, three parameters) in {k} cells, RMS {rms:.3} cm, largest {worst:.3} cm ({raw:.3} cm without the off-axis area correction);"
        );
    }
    let _ = writeln!(s, " {unseen} cells seen whole by neither camera.");
    if !r.noise.is_empty() {
        s.push_str("\nRMS (cm) as the pixel noise grows (other settings as above, at most 10 readings per height):\n\n| noise σ (grey levels) | one camera, 2 parameters | one camera, 3 parameters | two cameras, centre | two cameras, corner |\n|---|---|---|---|---|\n");
        for (sigma, rms) in &r.noise {
            let _ = writeln!(
                s,
                "| {sigma} | {:.3} | {:.3} | {:.3} | {:.3} |",
                rms[0], rms[1], rms[2], rms[3]
            );
        }
    }
    s
}

pub(crate) fn plot_measured(path: &Path, e: &Experiment) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let root = BitMapBackend::new(path, (640, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let top = e
        .rows
        .iter()
        .map(|r| r.actual_cm.max(r.mean_cm))
        .fold(0.0, f64::max)
        + 10.0;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("{} (RMS {:.3} cm)", e.title, e.rms_cm),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0f64..top, 0f64..top)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("actual height (cm)")
        .y_desc("measured height (cm)")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(LineSeries::new([(0.0, 0.0), (top, top)], &BLACK))
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(
            e.rows
                .iter()
                .map(|r| Circle::new((r.actual_cm, r.mean_cm), 3, RED.filled())),
        )
        .map_err(|e| anyhow!("{e}"))?;
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

pub(crate) fn plot_area(path: &Path, r: &Report, cam0_height_cm: f64) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let root = BitMapBackend::new(path, (640, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let max_area = r.area_samples.iter().map(|s| s.1).fold(0.0, f64::max) * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Grey-level area vs height, with the fitted models",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..210f64, 0f64..max_area)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("height (cm)")
        .y_desc("area (px)")
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(
            r.area_samples
                .iter()
                .map(|&(h, a)| Circle::new((h, a), 3, RED.filled())),
        )
        .map_err(|e| anyhow!("{e}"))?;
    for (fit, colour) in [(&r.fit_two, BLUE), (&r.fit_three, BLACK)] {
        let curve = (0..=200).map(|h| {
            let d = cam0_height_cm / 100.0 - (h as f64 / 100.0 + BALL_RADIUS_M);
            (h as f64, fit.model.area_at(d))
        });
        chart
            .draw_series(LineSeries::new(curve, &colour))
            .map_err(|e| anyhow!("{e}"))?;
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

pub(crate) fn plot_heat(path: &Path, r: &Report) -> anyhow::Result<()> {
    use plotters::prelude::*;
    let (hx, hy) = (BOARD_SIZE_M.0 * 50.0, BOARD_SIZE_M.1 * 50.0);
    let root = BitMapBackend::new(path, (1000, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let limit = r
        .heat
        .iter()
        .map(|h| h.error_cm.abs())
        .filter(|e| e.is_finite())
        .fold(0.05, f64::max);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "Height error (cm) at {:.0} cm over the board; colour range ±{limit:.2} cm; bold: both cameras, plain: one camera, grey: neither",
                HEAT_HEIGHT_M * 100.0
            ),
            ("sans-serif", 15),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(-hx..hx, -hy..hy)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("x (cm)")
        .y_desc("y (cm)")
        .disable_mesh()
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    let half = HEAT_CELL_M * 50.0;
    chart
        .draw_series(r.heat.iter().map(|c| {
            let colour = if c.error_cm.is_finite() {
                let t = (c.error_cm / limit).clamp(-1.0, 1.0);
                // Blue below zero, red above, white at zero.
                let (rr, gg, bb) = if t >= 0.0 {
                    (255.0, 255.0 * (1.0 - t), 255.0 * (1.0 - t))
                } else {
                    (255.0 * (1.0 + t), 255.0 * (1.0 + t), 255.0)
                };
                RGBColor(rr as u8, gg as u8, bb as u8)
            } else {
                RGBColor(160, 160, 160)
            };
            Rectangle::new(
                [
                    (c.x_cm - half, c.y_cm - half),
                    (c.x_cm + half, c.y_cm + half),
                ],
                colour.filled(),
            )
        }))
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .draw_series(r.heat.iter().filter(|c| c.error_cm.is_finite()).map(|c| {
            let style = if c.method == HeatMethod::BothCameras {
                ("sans-serif", 12).into_font().style(FontStyle::Bold)
            } else {
                ("sans-serif", 12).into_font()
            };
            Text::new(
                format!("{:+.2}", c.error_cm),
                (c.x_cm - 6.0, c.y_cm + 2.0),
                style,
            )
        }))
        .map_err(|e| anyhow!("{e}"))?;
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Writes the tables (Markdown and CSV), the plots and the summary to `opts.out`, all or
/// nothing: into a fresh folder beside it, renamed into place at the end.
pub fn write(r: &Report, opts: &ReproduceOptions) -> anyhow::Result<()> {
    let out = &opts.out;
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let staging = parent.join(format!(
        ".{}.partial-{}",
        out.file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("reproduce"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&staging);
    std::fs::create_dir_all(&staging)
        .with_context(|| format!("{}: cannot create the output folder", out.display()))?;
    let result = (|| -> anyhow::Result<()> {
        for e in &r.experiments {
            std::fs::write(staging.join(format!("{}.md", e.key)), table_md(e))?;
            std::fs::write(staging.join(format!("{}.csv", e.key)), table_csv(e))?;
        }
        std::fs::write(staging.join("summary.md"), summary_md(r, opts))?;
        let mut h = String::from("height_cm,true_heading_deg,measured_heading_deg,error_deg\n");
        for (hc, t, m, e) in &r.heading {
            let _ = writeln!(h, "{hc:.1},{t:.1},{m:.4},{e:.4}");
        }
        std::fs::write(staging.join("heading.csv"), h)?;
        let mut hm = String::from("x_cm,y_cm,measured_by,mean_error_cm,uncorrected_error_cm\n");
        for c in &r.heat {
            let _ = writeln!(
                hm,
                "{:.1},{:.1},{},{:.4},{:.4}",
                c.x_cm,
                c.y_cm,
                c.method.label(),
                c.error_cm,
                c.uncorrected_error_cm
            );
        }
        std::fs::write(staging.join("heat_map.csv"), hm)?;
        if opts.plots {
            let font = std::fs::read(FONT).with_context(|| {
                format!(
                    "cannot read the font {FONT} for the plots (Debian package fonts-dejavu-core)"
                )
            })?;
            let font: &'static [u8] = Box::leak(font.into_boxed_slice());
            plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, font)
                .map_err(|_| anyhow!("{FONT} is not a usable font"))?;
            for e in &r.experiments {
                plot_measured(&staging.join(format!("{}.png", e.key)), e)?;
            }
            let h0 = Rig::from_toml(THESIS_LAB)
                .map_err(|e| anyhow!("{e}"))?
                .cameras[0]
                .camera
                .position_world()
                .z
                * 100.0;
            plot_area(&staging.join("area_vs_height.png"), r, h0)?;
            plot_heat(&staging.join("heat_map.png"), r)?;
        }
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_dir_all(&staging);
        return Err(e.context(format!(
            "{}: writing the results failed; nothing was written there",
            out.display()
        )));
    }
    if out.exists() {
        std::fs::remove_dir_all(out)
            .with_context(|| format!("{}: cannot replace the old results", out.display()))?;
    }
    std::fs::rename(&staging, out)
        .with_context(|| format!("{}: cannot move the results into place", out.display()))?;
    Ok(())
}

/// Reads a table CSV written by [`write()`] (for checks).
pub fn read_table(path: &Path) -> anyhow::Result<Vec<Row>> {
    let rows = csv::read(
        path,
        &[
            "actual_height_cm",
            "measured_height_cm",
            "standard_deviation_cm",
            "error_cm",
        ],
    )?;
    rows.iter()
        .map(|r| {
            Ok(Row {
                actual_cm: r
                    .number(0, "actual_height_cm")
                    .map_err(anyhow::Error::msg)?,
                mean_cm: r
                    .number(1, "measured_height_cm")
                    .map_err(anyhow::Error::msg)?,
                sd_cm: r
                    .number(2, "standard_deviation_cm")
                    .map_err(anyhow::Error::msg)?,
                error_cm: r.number(3, "error_cm").map_err(anyhow::Error::msg)?,
            })
        })
        .collect()
}
