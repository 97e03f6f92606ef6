//! One reading of a rendered frame: the target's blob by the moment engine (auto threshold,
//! coverage-weighted moments, thesis Eq. 3.33–3.44), its area, centroid and axis.

use crate::*;

/// The target in a frame: its grey-level area (px) and its coverage centroid.
///
/// Two weightings of the same blob, each where it is best. The **area** is the grey-level area
/// Σ(pixel − background)/contrast: every pixel weighs its full brightness, so pixel noise
/// hardly moves it, and the ball's shading is the same at every height for a camera looking
/// down (a pixel count is about six times noisier). The **centroid** uses coverage weights
/// (`Weighting::Coverage`) saturating `FULL_ABOVE_BACKGROUND` levels above the background —
/// below the ball's darkest part, its rim — i.e. the silhouette with sub-pixel edges: grey-level
/// weights pull it towards the lit top of the ball, which the two cameras see from different
/// sides, a 2–3 mm height bias when triangulating.
pub(crate) fn measure(img: &GrayImage<u8>, contrast: f64) -> Option<(f64, Point2<f64>)> {
    let bg = background(img)?;
    // Σ(pixel − background) over the blob's box widened by 2 px: the dim edge pixels below the
    // threshold count too (they are a larger share of a small, far blob), and the background's
    // noise averages out.
    let b = target_blob(img, Weighting::Binary)?;
    let (w, h) = (img.width(), img.height());
    let (x0, y0) = (b.bbox.x0.saturating_sub(2), b.bbox.y0.saturating_sub(2));
    let (x1, y1) = ((b.bbox.x1 + 2).min(w - 1), (b.bbox.y1 + 2).min(h - 1));
    let view = img.view();
    let mut sum = 0.0;
    for y in y0..=y1 {
        sum += view.row(y)[x0 as usize..=x1 as usize]
            .iter()
            .map(|&p| p as f64 - bg as f64)
            .sum::<f64>();
    }
    let area = sum / contrast;
    let (x, y) = target_blob(img, coverage(img, bg)?)?.best_centroid_px();
    Some((area, Point2::new(x, y)))
}

/// The background level: the histogram's mode.
pub(crate) fn background(img: &GrayImage<u8>) -> Option<u32> {
    Histogram::of(&img.view()).mode().ok()
}

/// The blob threshold: the histogram's background knee, at least 12 levels above it.
pub(crate) fn threshold(img: &GrayImage<u8>, bg: u32) -> Option<u32> {
    Some(
        Histogram::of(&img.view())
            .threshold::<u8>(ThresholdMethod::Triangle)
            .ok()?
            .max(bg + 12)
            .min(254),
    )
}

/// Coverage weights saturating `FULL_ABOVE_BACKGROUND` above the background.
pub(crate) fn coverage(img: &GrayImage<u8>, bg: u32) -> Option<Weighting> {
    Some(Weighting::Coverage {
        background: bg,
        full: (bg + FULL_ABOVE_BACKGROUND).max(threshold(img, bg)? + 1),
    })
}

/// The largest blob (the target) with the given weights.
pub(crate) fn target_blob(
    img: &GrayImage<u8>,
    weighting: Weighting,
) -> Option<stereoscope_vision::Blob> {
    let bg = background(img)?;
    let mut ex = Extractor::new(ExtractConfig {
        weighting,
        min_area_px: 10,
        ..Default::default()
    });
    let blobs = ex.extract(img.view(), threshold(img, bg)?, &[]).ok()?;
    // A blob cut by the frame's edge is no measurement of the target (the live system flags it).
    blobs
        .iter()
        .max_by_key(|b| b.area_px())
        .copied()
        .filter(|b| {
            !b.flags
                .contains(stereoscope_vision::BlobFlags::TOUCHES_BORDER)
        })
}

/// The target's coverage centroid, major-axis angle (degrees CCW on screen, PAR-corrected) and
/// roundness in a frame.
pub(crate) fn measure_axis(img: &GrayImage<u8>, par: f64) -> Option<(Point2<f64>, f64, f64)> {
    let b = target_blob(img, coverage(img, background(img)?)?)?;
    let (x, y) = b.best_centroid_px();
    let shape = b.best_central().axis_shape(par);
    Some((Point2::new(x, y), shape.angle_deg, shape.roundness()))
}
