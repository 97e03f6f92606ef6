//! Accuracy on rendered images with known truth (issue: moment engine, "Proof").
//!
//! - centroid error ≤ 0.05 px RMS for discs of radius ≥ 3 px under Gaussian noise σ = 2 grey
//!   levels, intensity-weighted mode;
//! - orientation error ≤ 0.5° for ellipses with axis ratio ≥ 2 on pixels with PAR 0.86
//!   (intensity-weighted moments; binary moments are checked to 1°), and the thesis's Eq. 3.44
//!   read literally failing the same test.

use stereoscope_numeric::SplitMix64;
use stereoscope_numeric::angle::wrap_half_turn_deg;
use stereoscope_vision::raster::{Ellipse, add_gaussian_noise, draw_ellipse, fill_background};
use stereoscope_vision::{ExtractConfig, Extractor, GrayImage, Histogram, Weighting};

const BACKGROUND: f64 = 20.0;
const CONTRAST: f64 = 150.0;

fn rms(errors: &[f64]) -> f64 {
    (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt()
}

#[test]
fn weighted_centroid_of_noisy_discs_is_within_five_hundredths_of_a_pixel() {
    let mut rng = SplitMix64::new(2024);
    for radius in [3.0, 4.0, 6.0, 10.0] {
        let (mut weighted_err, mut binary_err) = (Vec::new(), Vec::new());
        for _ in 0..150 {
            let (cx, cy) = (rng.range(30.0, 34.0), rng.range(30.0, 34.0));
            let mut img = GrayImage::filled(64, 64, 0u8).unwrap();
            fill_background(&mut img, BACKGROUND, 0.0);
            draw_ellipse(
                &mut img,
                &Ellipse::disc(cx, cy, radius),
                1.0,
                BACKGROUND,
                BACKGROUND + CONTRAST,
                16,
            );
            add_gaussian_noise(&mut img, 2.0, &mut rng);
            // As a user would: background level and threshold from the histogram.
            let hist = Histogram::of(&img.view());
            let background = hist.mode().unwrap();
            let threshold = hist.triangle().unwrap().max(background + 8);
            let mut ex = Extractor::new(ExtractConfig {
                weighting: Weighting::Intensity { background },
                min_area_px: 5,
                ..Default::default()
            });
            let blobs = ex.extract(img.view(), threshold, &[]).unwrap();
            assert_eq!(
                blobs.len(),
                1,
                "radius {radius} at ({cx:.2}, {cy:.2}), threshold {threshold}"
            );
            let (wx, wy) = blobs[0].best_centroid_px();
            let (bx, by) = blobs[0].centroid_px();
            weighted_err.push(((wx - cx).powi(2) + (wy - cy).powi(2)).sqrt());
            binary_err.push(((bx - cx).powi(2) + (by - cy).powi(2)).sqrt());
        }
        let (w, b) = (rms(&weighted_err), rms(&binary_err));
        println!("radius {radius}: weighted RMS {w:.4} px, binary RMS {b:.4} px");
        assert!(
            w <= 0.05,
            "radius {radius}: weighted centroid RMS {w:.4} px"
        );
    }
}

/// The thesis's Eq. 3.44 as printed: PAR on the y terms.
fn thesis_eq_3_44_deg(mu20: f64, mu02: f64, mu11: f64, par: f64) -> f64 {
    0.5 * (-2.0 * par * mu11)
        .atan2(mu20 - par * par * mu02)
        .to_degrees()
}

#[test]
fn orientation_with_par_0_86_is_within_half_a_degree() {
    let par = 0.86;
    let mut rng = SplitMix64::new(7);
    let mut worst: f64 = 0.0;
    let mut thesis_worst: f64 = 0.0;
    let mut uncorrected_worst: f64 = 0.0;
    let mut binary_worst: f64 = 0.0;
    for ratio in [2.0, 3.0] {
        for step in 0..72 {
            let angle = -87.5 + 2.5 * step as f64;
            let e = Ellipse {
                cx_px: rng.range(60.0, 61.0),
                cy_px: rng.range(60.0, 61.0),
                semi_major: 16.0,
                semi_minor: 16.0 / ratio,
                angle_deg: angle,
            };
            let mut img = GrayImage::filled(128, 128, 0u8).unwrap();
            fill_background(&mut img, BACKGROUND, 0.0);
            draw_ellipse(&mut img, &e, par, BACKGROUND, BACKGROUND + CONTRAST, 16);
            add_gaussian_noise(&mut img, 2.0, &mut rng);
            let mut ex = Extractor::new(ExtractConfig {
                min_area_px: 10,
                weighting: Weighting::Intensity {
                    background: BACKGROUND as u32,
                },
                ..Default::default()
            });
            let blobs = ex
                .extract(img.view(), (BACKGROUND + 20.0) as u32, &[])
                .unwrap();
            assert_eq!(blobs.len(), 1);
            let err =
                wrap_half_turn_deg(blobs[0].best_central().orientation_deg(par) - angle).abs();
            worst = worst.max(err);
            binary_worst =
                binary_worst.max(wrap_half_turn_deg(blobs[0].orientation_deg(par) - angle).abs());
            let c = blobs[0].central();
            thesis_worst = thesis_worst.max(
                wrap_half_turn_deg(thesis_eq_3_44_deg(c.mu20, c.mu02, c.mu11, par) - angle).abs(),
            );
            uncorrected_worst = uncorrected_worst
                .max(wrap_half_turn_deg(blobs[0].orientation_deg(1.0) - angle).abs());
        }
    }
    println!(
        "PAR 0.86: worst error {worst:.3}° (weighted), {binary_worst:.3}° (binary), \
         Eq. 3.44 literal {thesis_worst:.2}°, no PAR {uncorrected_worst:.2}°"
    );
    assert!(worst <= 0.5, "worst orientation error {worst:.3}°");
    assert!(
        binary_worst <= 1.0,
        "worst binary orientation error {binary_worst:.3}°"
    );
    // The printed equation and ignoring PAR both miss by degrees: the correction matters.
    assert!(thesis_worst > 3.0, "{thesis_worst}");
    assert!(uncorrected_worst > 3.0, "{uncorrected_worst}");
}

#[test]
fn exact_moments_on_a_4k_frame_match_closed_forms() {
    // A 3001×1501 rectangle in the corner of a 3840×2160 frame: exact integers throughout.
    let mut img = GrayImage::filled(3840, 2160, 0u8).unwrap();
    for y in 600..2101u32 {
        for p in &mut img.row_mut(y)[800..3801] {
            *p = 255;
        }
    }
    for threads in [1, 2] {
        let mut ex = Extractor::new(ExtractConfig {
            threads,
            ..Default::default()
        });
        let b = ex.extract(img.view(), 128, &[]).unwrap()[0];
        let (w, h) = (3001.0f64, 1501.0f64);
        assert_eq!(b.area_px(), 3001 * 1501);
        let (cx, cy) = b.centroid_px();
        assert_eq!((cx, cy), (2300.0, 1350.0));
        let c = b.central();
        assert_eq!(c.mu20, h * w * (w * w - 1.0) / 12.0);
        assert_eq!(c.mu02, w * h * (h * h - 1.0) / 12.0);
        assert_eq!(c.mu11, 0.0);
    }
}
