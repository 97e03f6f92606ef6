//! The error over the whole board (two cameras, each method), measured as fusion would: the
//! heat map beside the thesis's centre and corner (Tables 4.3, 4.4).

use crate::*;

/// The height error over the whole board at [`HEAT_HEIGHT_M`] ([`HeatCell`]).
pub(crate) fn heat_map(
    lab: &mut Lab,
    fit: &DepthFit,
    opts: &ReproduceOptions,
) -> anyhow::Result<Vec<HeatCell>> {
    let n = opts.readings.clamp(1, 5);
    let (cols, rows) = (
        (BOARD_SIZE_M.0 / HEAT_CELL_M).floor() as i32 / 2,
        (BOARD_SIZE_M.1 / HEAT_CELL_M).floor() as i32 / 2,
    );
    let mut cells = Vec::new();
    for iy in -rows..=rows {
        for ix in -cols..=cols {
            let (x, y) = (HEAT_CELL_M * ix as f64, HEAT_CELL_M * iy as f64);
            // Each reading: how it was measured, the height, and (one camera) the height
            // without the off-axis correction.
            let mut readings: Vec<(HeatMethod, f64, f64)> = Vec::new();
            for _ in 0..n {
                let mut seen = Vec::new();
                for c in 0..2 {
                    let img = lab.frame(c, x, y, HEAT_HEIGHT_M)?;
                    if let Some(m) = measure(&img, opts.contrast) {
                        seen.push((c, m));
                    }
                }
                readings.push(match seen.as_slice() {
                    [(c0, (_, p0)), (c1, (_, p1))] => {
                        let obs = [
                            Observation {
                                camera: *c0,
                                pixel: *p0,
                            },
                            Observation {
                                camera: *c1,
                                pixel: *p1,
                            },
                        ];
                        let z = triangulate(&lab.calibrated, &obs)?.point_world.z;
                        (HeatMethod::BothCameras, z, f64::NAN)
                    }
                    [(c, (area, p))] => {
                        let cam = &lab.calibrated[*c];
                        let corrected = on_axis_area(cam, *p, *area)?;
                        let d = fit.model.depth_from_area(corrected, fit.range)?;
                        let d_raw = fit.model.depth_from_area(*area, fit.range)?;
                        (
                            HeatMethod::OneCamera(*c),
                            point_from_depth(cam, *p, d.depth)?.z,
                            point_from_depth(cam, *p, d_raw.depth)?.z,
                        )
                    }
                    _ => (HeatMethod::Unseen, f64::NAN, f64::NAN),
                });
            }
            // Noise can hide a target at the edge of a view in some readings: the cell is
            // measured the way most of its readings were, from those readings.
            let count = |m: HeatMethod| readings.iter().filter(|r| r.0 == m).count();
            let method = [
                HeatMethod::BothCameras,
                HeatMethod::OneCamera(0),
                HeatMethod::OneCamera(1),
                HeatMethod::Unseen,
            ]
            .into_iter()
            .max_by_key(|&m| count(m))
            .unwrap_or(HeatMethod::Unseen);
            let used: Vec<&(HeatMethod, f64, f64)> =
                readings.iter().filter(|r| r.0 == method).collect();
            let err = |pick: fn(&(HeatMethod, f64, f64)) -> f64| {
                let mean = used.iter().map(|r| pick(r)).sum::<f64>() / used.len().max(1) as f64;
                (HEAT_HEIGHT_M - (mean - BALL_RADIUS_M)) * 100.0
            };
            let (error_cm, uncorrected_error_cm) = match method {
                HeatMethod::BothCameras => (err(|r| r.1), f64::NAN),
                HeatMethod::OneCamera(_) => (err(|r| r.1), err(|r| r.2)),
                HeatMethod::Unseen => (f64::NAN, f64::NAN),
            };
            cells.push(HeatCell {
                x_cm: x * 100.0,
                y_cm: y * 100.0,
                method,
                error_cm,
                uncorrected_error_cm,
            });
        }
    }
    Ok(cells)
}

/// RMS and largest absolute value of the finite values.
pub(crate) fn rms_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64, usize)> {
    let v: Vec<f64> = values.filter(|e| e.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let rms = (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt();
    Some((rms, v.iter().map(|e| e.abs()).fold(0.0, f64::max), v.len()))
}
