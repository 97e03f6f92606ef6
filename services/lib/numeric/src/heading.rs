//! A continuous 0–360° heading from per-frame axis angles.
//!
//! Thesis: §4.1.1 "for consecutive rotations" and its `track_orientation`: moment angles live in
//! (−90°, 90°] (Eq. 4.14b) and are unwrapped over frames by the direction of the shortest step.
//! That is the shortest step modulo 180°, and it silently turns a rotation of 90° or more per
//! frame into one the other way. Here:
//!
//! - the step is taken relative to a constant-angular-velocity prediction (optional), so steady
//!   fast rotations unwrap correctly;
//! - a step whose residual against the prediction exceeds `ambiguous_step_deg` is reported as
//!   [`HeadingStatus::Ambiguous`], and a near-circular blob (roundness above
//!   `max_roundness`, where the axis angle is noise) as [`HeadingStatus::NearCircular`] with the
//!   heading held;
//! - when third-order moments give a trusted direction (`moments::directed_angle_deg`), the 180°
//!   ambiguity is resolved from it ([`HeadingStatus::Directed`]).
//!
//! Angles are degrees, counter-clockwise as seen on screen (`docs/conventions.md`).

use crate::angle::{wrap, wrap_half_turn_deg, wrap_turn_deg};

/// An angle in [0, 360).
fn to_turn(d: f64) -> f64 {
    let w = wrap(d, 180.0);
    if w < 0.0 { w + 360.0 } else { w }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingConfig {
    /// A step further than this from the prediction is flagged ambiguous (it may have been the
    /// step 180° the other way). Must be below 90.
    pub ambiguous_step_deg: f64,
    /// Above this minor/major axis ratio the blob counts as round and the axis is ignored.
    pub max_roundness: f64,
    /// Predict each step from the last one (constant angular velocity).
    pub predict_angular_velocity: bool,
}

impl Default for HeadingConfig {
    fn default() -> Self {
        HeadingConfig {
            ambiguous_step_deg: 60.0,
            max_roundness: 0.9,
            predict_angular_velocity: true,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadingStatus {
    /// First measurement: the heading is the axis angle mapped to [0, 180) (or the directed
    /// angle when known).
    Initial,
    /// Unwrapped from the previous heading.
    Tracked,
    /// Resolved to 0–360° by third-order moments.
    Directed,
    /// The step was too large to tell its sign; the heading may be 180° off from here on.
    Ambiguous,
    /// The blob is nearly round: the heading is held, not measured.
    NearCircular,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingUpdate {
    /// Heading in [0, 360).
    pub heading_deg: f64,
    /// The change applied this frame, degrees.
    pub step_deg: f64,
    pub status: HeadingStatus,
}

/// Unwraps one object's axis angles over frames.
#[derive(Debug, Clone)]
pub struct HeadingTracker {
    cfg: HeadingConfig,
    heading_deg: Option<f64>,
    omega_deg: f64,
}

impl HeadingTracker {
    pub fn new(cfg: HeadingConfig) -> Self {
        HeadingTracker {
            cfg,
            heading_deg: None,
            omega_deg: 0.0,
        }
    }

    pub fn heading_deg(&self) -> Option<f64> {
        self.heading_deg
    }

    pub fn config(&self) -> &HeadingConfig {
        &self.cfg
    }

    pub fn reset(&mut self) {
        self.heading_deg = None;
        self.omega_deg = 0.0;
    }

    /// Feeds one frame: the major-axis angle in (−90, 90], the blob's roundness (minor/major
    /// axis ratio) and, when available, the direction from third-order moments in [0, 360).
    pub fn update(
        &mut self,
        axis_deg: f64,
        roundness: f64,
        directed_deg: Option<f64>,
    ) -> HeadingUpdate {
        // NaN (degenerate moments) counts as round.
        let round = roundness.is_nan() || roundness > self.cfg.max_roundness;
        let Some(prev) = self.heading_deg else {
            if round {
                // Nothing to measure yet; report 0 and stay uninitialised.
                return HeadingUpdate {
                    heading_deg: 0.0,
                    step_deg: 0.0,
                    status: HeadingStatus::NearCircular,
                };
            }
            let (h, status) = match directed_deg {
                Some(d) => (to_turn(d), HeadingStatus::Directed),
                None => {
                    let a = wrap(axis_deg, 90.0);
                    (if a < 0.0 { a + 180.0 } else { a }, HeadingStatus::Initial)
                }
            };
            self.heading_deg = Some(h);
            return HeadingUpdate {
                heading_deg: h,
                step_deg: 0.0,
                status,
            };
        };
        if round {
            self.omega_deg = 0.0;
            return HeadingUpdate {
                heading_deg: prev,
                step_deg: 0.0,
                status: HeadingStatus::NearCircular,
            };
        }
        let omega = if self.cfg.predict_angular_velocity {
            self.omega_deg
        } else {
            0.0
        };
        let predicted = prev + omega;
        let residual = wrap_half_turn_deg(axis_deg - predicted);
        let mut new = predicted + residual;
        let mut status = if residual.abs() > self.cfg.ambiguous_step_deg {
            HeadingStatus::Ambiguous
        } else {
            HeadingStatus::Tracked
        };
        if let Some(d) = directed_deg {
            if wrap_turn_deg(d - new).abs() > 90.0 {
                new += 180.0;
            }
            status = HeadingStatus::Directed;
        }
        let step = wrap_turn_deg(new - prev);
        self.omega_deg = if status == HeadingStatus::Ambiguous {
            0.0
        } else {
            step
        };
        let h = to_turn(new);
        self.heading_deg = Some(h);
        HeadingUpdate {
            heading_deg: h,
            step_deg: step,
            status,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Axis angle in (−90, 90] of a heading.
    fn axis_of(heading: f64) -> f64 {
        let a = heading.rem_euclid(180.0);
        if a > 90.0 { a - 180.0 } else { a }
    }

    #[test]
    fn wraps() {
        assert_eq!(wrap_half_turn_deg(90.0), 90.0);
        assert_eq!(wrap_half_turn_deg(-90.0), 90.0);
        assert_eq!(wrap_half_turn_deg(100.0), -80.0);
        assert_eq!(wrap_turn_deg(-180.0), 180.0);
        assert_eq!(wrap_turn_deg(370.0), 10.0);
    }

    #[test]
    fn unwraps_a_full_turn_both_ways() {
        for dir in [1.0, -1.0] {
            let mut t = HeadingTracker::new(HeadingConfig {
                predict_angular_velocity: false,
                ..Default::default()
            });
            let start = 10.0;
            let mut truth = start;
            t.update(axis_of(truth), 0.3, None);
            for _ in 0..100 {
                truth += dir * 7.3;
                let u = t.update(axis_of(truth), 0.3, None);
                assert_eq!(u.status, HeadingStatus::Tracked);
                assert!(
                    wrap_turn_deg(u.heading_deg - truth.rem_euclid(360.0)).abs() < 1e-9,
                    "{} vs {truth}",
                    u.heading_deg
                );
            }
        }
    }

    #[test]
    fn fast_steady_rotation_unwraps_with_prediction_and_is_flagged_without() {
        // 100°/frame: the shortest step says −80°.
        let mut with = HeadingTracker::new(HeadingConfig::default());
        let mut without = HeadingTracker::new(HeadingConfig {
            predict_angular_velocity: false,
            ..Default::default()
        });
        let mut truth = 20.0;
        with.update(axis_of(truth), 0.3, None);
        without.update(axis_of(truth), 0.3, None);
        // Spin up gently so the predictor learns the rate.
        for step in [30.0, 60.0, 85.0, 100.0] {
            truth += step;
            with.update(axis_of(truth), 0.3, None);
            without.update(axis_of(truth), 0.3, None);
        }
        let mut flagged = false;
        for _ in 0..20 {
            truth += 100.0;
            let u = with.update(axis_of(truth), 0.3, None);
            assert_eq!(u.status, HeadingStatus::Tracked);
            assert!(wrap_turn_deg(u.heading_deg - truth).abs() < 1e-9);
            flagged |= without.update(axis_of(truth), 0.3, None).status == HeadingStatus::Ambiguous;
        }
        assert!(flagged);
    }

    #[test]
    fn directed_angles_fix_the_half_turn() {
        let mut t = HeadingTracker::new(HeadingConfig::default());
        let u = t.update(axis_of(250.0), 0.5, Some(250.0));
        assert_eq!((u.heading_deg, u.status), (250.0, HeadingStatus::Directed));
        // Even a 150° jump is resolved by the direction.
        let u = t.update(axis_of(40.0), 0.5, Some(40.0));
        assert!((u.heading_deg - 40.0).abs() < 1e-9, "{}", u.heading_deg);
    }

    #[test]
    fn round_blobs_hold_the_heading() {
        let mut t = HeadingTracker::new(HeadingConfig::default());
        assert_eq!(
            t.update(12.0, 0.99, None).status,
            HeadingStatus::NearCircular
        );
        assert_eq!(t.heading_deg(), None);
        t.update(-30.0, 0.4, None);
        assert_eq!(t.heading_deg(), Some(150.0));
        let mut t0 = HeadingTracker::new(HeadingConfig::default());
        t0.update(0.0, 0.4, None);
        assert_eq!(t0.heading_deg(), Some(0.0));
        let u = t.update(77.0, 0.95, None);
        assert_eq!(
            (u.heading_deg, u.status),
            (150.0, HeadingStatus::NearCircular)
        );
        // NaN roundness (degenerate moments) counts as round.
        assert_eq!(
            t.update(0.0, f64::NAN, None).status,
            HeadingStatus::NearCircular
        );
    }
}
