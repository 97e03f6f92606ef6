//! System test of the whole calibration through the real services (`docs/calibration.md`,
//! issue 13): four synthetic ceiling cameras at their true poses; the services record a wand
//! waved through the volume, an L-frame lying on the floor and six markers at known places;
//! `calibrate wand`, `replay --rig` and `calibrate floor` make the rig file; the calibrated
//! cameras are compared with the truth in the floor's world, and the known markers fused
//! again with the calibrated rig are compared with those fused with the true rig. Each
//! recording has its own iceoryx2 prefix and loopback router; every child is reaped.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod chain;

use chain::{ChainWand, ceiling, end_to_end};

#[test]
fn a_rig_calibrated_by_wand_and_floor_measures_as_the_true_rig() {
    let r = end_to_end(&ceiling(), ChainWand::Two, 20.0, 4.0, 60.0);
    println!("{r:?}");
    // The floor's L-frame, seen by 320 × 240 cameras 3 m away, places the world within
    // about 0.06° (docs/performance.md); the cameras follow it.
    assert!(
        r.worst_position_m < 0.01 && r.worst_rotation_deg < 0.15,
        "{r:?}"
    );
    assert!(r.scale_error.abs() < 1e-3, "{r:?}");
    assert!(r.places_seen >= 5 && r.positions > 500, "{r:?}");
    // The rig's geometry: the goal is a calibrated rig that triangulates within 10 % of the
    // true one, and it is met within the noise, not always: +3.8 to +10.8 % over 10 runs
    // (docs/performance.md), the spread coming from which wand frames a live 2-core recording
    // kept. The test guards the calibration against regressions at 15 %: a calibration that
    // is wrong (a one-marker wand without its scale, a bad intrinsic) is +33 % or more.
    assert!(r.fit_calibrated_mm < 1.15 * r.fit_true_mm, "{r:?}");
    assert!(r.rms_calibrated_mm < 3.0, "{r:?}");
}

/// A one-marker wand gives the cameras up to scale; the floor's L-frame (`calibrate floor
/// --scale`) sets the scale. The L's 800 mm arm, measured by 320 × 240 cameras 3 m away,
/// sets it within about 0.05 % (0.038–0.062 % in 8 runs, bounded here at 0.1 %). Apart from
/// that scale the rig's geometry must be the true rig's: after a rigid fit the known places'
/// error is within 20 % of the true rig's combined with what the scale error alone moves them
/// (the error times their distance from their centroid, 0.52 m RMS; docs/calibration.md).
#[test]
fn a_rig_calibrated_by_a_one_marker_wand_and_a_scaling_floor_measures_as_the_true_rig() {
    let r = end_to_end(&ceiling(), ChainWand::One, 20.0, 4.0, 60.0);
    println!("{r:?}");
    assert!(
        r.worst_position_m < 0.01 && r.worst_rotation_deg < 0.15,
        "{r:?}"
    );
    assert!(r.scale_error.abs() < 1e-3, "{r:?}");
    assert!(r.places_seen >= 5 && r.positions > 500, "{r:?}");
    let scale_mm = r.scale_error.abs() * chain::known_rms_radius_m() * 1e3;
    let bound_mm = 1.2 * r.fit_true_mm.hypot(scale_mm);
    assert!(r.fit_calibrated_mm < bound_mm, "bound {bound_mm} mm: {r:?}");
    assert!(r.rms_calibrated_mm < 3.0, "{r:?}");
}
