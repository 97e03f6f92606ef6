//! Smoothing and prediction of a body's pose for VR (`docs/bodies.md`, "Smoothing and
//! prediction"); both off unless the rig asks for them.
//!
//! - The One Euro filter (Casiez, Roussel and Vogel, CHI 2012): a first-order low-pass whose
//!   cut-off rises with the filtered speed, `f_c = min_cutoff + beta·|ẋ|`, with smoothing factor
//!   `α = 1 / (1 + 1/(2π f_c Δt))`. Slow motion is smoothed hard (jitter removed), fast motion
//!   lightly (little lag). The position is filtered per axis; the rotation by spherical
//!   interpolation towards the new one with the same `α`, its speed being the angle turned.
//! - Prediction forward by `predict_s` at constant linear and angular velocity:
//!   `p + v·t`, `exp(ω·t)·R`.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// One Euro settings: `min_cutoff_hz` (jitter at rest: lower is smoother), `beta` (how fast
/// the cut-off rises with speed: higher is less lag), `d_cutoff_hz` (the speed estimate's own
/// low-pass).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OneEuroConfig {
    pub min_cutoff_hz: f64,
    pub beta: f64,
    pub d_cutoff_hz: f64,
}

impl Default for OneEuroConfig {
    fn default() -> Self {
        OneEuroConfig {
            min_cutoff_hz: 1.0,
            beta: 0.5,
            d_cutoff_hz: 1.0,
        }
    }
}

fn alpha(cutoff_hz: f64, dt_s: f64) -> f64 {
    let tau = 1.0 / (std::f64::consts::TAU * cutoff_hz.max(1e-6));
    1.0 / (1.0 + tau / dt_s)
}

/// A One Euro filter of a whole pose.
#[derive(Debug, Clone)]
pub struct PoseFilter {
    cfg: OneEuroConfig,
    last: Option<(Isometry3<f64>, u64)>,
    /// Filtered speeds: metres per second, radians per second.
    speed: (f64, f64),
}

impl PoseFilter {
    pub fn new(cfg: OneEuroConfig) -> Self {
        PoseFilter {
            cfg,
            last: None,
            speed: (0.0, 0.0),
        }
    }

    /// Forgets the past (a body lost and found again starts afresh).
    pub fn reset(&mut self) {
        self.last = None;
        self.speed = (0.0, 0.0);
    }

    /// The filtered pose for a measurement at `t_ns`. A measurement not after the last one is
    /// returned as the last filtered pose (nothing to divide by).
    pub fn filter(&mut self, pose: &Isometry3<f64>, t_ns: u64) -> Isometry3<f64> {
        let Some((prev, prev_ns)) = self.last else {
            self.last = Some((*pose, t_ns));
            return *pose;
        };
        if t_ns <= prev_ns {
            return prev;
        }
        let dt = (t_ns - prev_ns) as f64 * 1e-9;
        let c = self.cfg;
        // Speeds of the raw step, low-passed.
        let step = pose.translation.vector - prev.translation.vector;
        let turn = prev.rotation.angle_to(&pose.rotation);
        let ad = alpha(c.d_cutoff_hz, dt);
        self.speed.0 += ad * (step.norm() / dt - self.speed.0);
        self.speed.1 += ad * (turn / dt - self.speed.1);
        let a_pos = alpha(c.min_cutoff_hz + c.beta * self.speed.0, dt);
        let a_rot = alpha(c.min_cutoff_hz + c.beta * self.speed.1, dt);
        let t = prev.translation.vector + step * a_pos;
        let r = prev
            .rotation
            .try_slerp(&pose.rotation, a_rot, 1e-12)
            .unwrap_or(pose.rotation);
        let out = Isometry3::from_parts(Translation3::from(t), r);
        self.last = Some((out, t_ns));
        out
    }
}

/// `pose` moved forward by `ahead_s` at constant `velocity` (m/s) and `angular` (rad/s,
/// world frame).
pub fn predict(
    pose: &Isometry3<f64>,
    velocity: &Vector3<f64>,
    angular: &Vector3<f64>,
    ahead_s: f64,
) -> Isometry3<f64> {
    let t = pose.translation.vector + velocity * ahead_s;
    let r = UnitQuaternion::from_scaled_axis(angular * ahead_s) * pose.rotation;
    Isometry3::from_parts(Translation3::from(t), r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_numeric::SplitMix64;

    fn at(x: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, 0.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    /// At rest the filter removes most of the jitter; moving steadily it lags little, and less
    /// with a larger beta.
    #[test]
    fn jitter_falls_at_rest_and_lag_stays_small_in_motion() {
        let mut rng = SplitMix64::new(3);
        let mut f = PoseFilter::new(OneEuroConfig::default());
        let (mut raw, mut out) = (0.0, 0.0);
        let dt = 4_166_667u64; // 240 Hz
        for k in 0..2000u64 {
            let noise = 0.001 * rng.normal();
            let p = f.filter(&at(noise, 0.0), k * dt);
            if k > 200 {
                raw += noise * noise;
                out += p.translation.x.powi(2);
            }
        }
        assert!(out < raw / 10.0, "jitter {out} vs raw {raw}");
        // 1 m/s along x: the lag settles to a few millimetres.
        let lag = |beta: f64| {
            let mut f = PoseFilter::new(OneEuroConfig {
                beta,
                ..OneEuroConfig::default()
            });
            let mut last = 0.0;
            for k in 0..480u64 {
                let x = k as f64 * dt as f64 * 1e-9;
                last = x - f.filter(&at(x, 0.0), k * dt).translation.x;
            }
            last
        };
        let (slow, fast) = (lag(0.5), lag(5.0));
        assert!(fast < slow && fast < 0.01 && fast > 0.0, "{slow} {fast}");
        // Rotation too: turning at 1 rad/s it follows within a few degrees.
        let mut f = PoseFilter::new(OneEuroConfig::default());
        let mut e = 0.0;
        for k in 0..480u64 {
            let yaw = k as f64 * dt as f64 * 1e-9;
            e = f
                .filter(&at(0.0, yaw), k * dt)
                .rotation
                .angle_to(&at(0.0, yaw).rotation);
        }
        assert!(e.to_degrees() < 3.0, "{}", e.to_degrees());
    }

    #[test]
    fn prediction_moves_at_constant_velocity() {
        let p = predict(
            &at(0.0, 0.0),
            &Vector3::new(1.0, 0.0, 0.0),
            &Vector3::new(0.0, 0.0, 2.0),
            0.01,
        );
        assert!((p.translation.x - 0.01).abs() < 1e-12);
        assert!((p.rotation.angle() - 0.02).abs() < 1e-12);
        assert!((p.rotation.axis().unwrap().z - 1.0).abs() < 1e-12);
    }
}
