//! Scripted motion: where each target is at time t, deterministic from a seed, with its
//! heading about the vertical axis (degrees counter-clockwise from world +x seen from above,
//! `docs/geometry.md`).

use crate::scene::{Scene, Shape, Target};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use stereoscope_numeric::SplitMix64;

/// A target's state at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    pub position: Point3<f64>,
    pub heading_deg: f64,
    /// A rotation in the body frame before the heading (a head's nod and tilt); identity for
    /// targets that only turn about the vertical.
    pub tilt: UnitQuaternion<f64>,
}

impl State {
    /// The body pose: at `position`, tilted by `tilt`, then turned `heading_deg` about world +z.
    pub fn world_from_body(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(self.position.coords),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.heading_deg.to_radians())
                * self.tilt,
        )
    }
}

/// How a target moves.
#[derive(Debug, Clone, PartialEq)]
pub enum Motion {
    Static {
        position: Point3<f64>,
        heading_deg: f64,
    },
    /// Back and forth between two points (a triangle wave), facing along the line.
    Line {
        from: Point3<f64>,
        to: Point3<f64>,
        period_s: f64,
    },
    /// Round a horizontal circle, heading along the tangent.
    Circle {
        centre: Point3<f64>,
        radius_m: f64,
        period_s: f64,
    },
    /// In place, turning about the vertical axis.
    Spin {
        position: Point3<f64>,
        deg_per_s: f64,
    },
    /// A smooth random wander (three sinusoids per axis with random frequencies and phases)
    /// within `extent_m` of `centre`, heading along the motion.
    Wander {
        centre: Point3<f64>,
        extent_m: Vector3<f64>,
        seed: u64,
    },
    /// A head: round a horizontal circle of `radius_m` about `centre` every `period_s`, turning
    /// through 360° about the vertical every `turn_period_s` (independently of the path), while
    /// nodding (pitch) and tilting (roll) by up to `nod_deg`.
    Head {
        centre: Point3<f64>,
        radius_m: f64,
        period_s: f64,
        turn_period_s: f64,
        nod_deg: f64,
    },
    /// One link of a kinematic model moved joint by joint: the root at `world_from_root`, each
    /// degree of freedom on its swing (`stereoscope_kinematics::Model::swing_values`); the
    /// target's pose is the link's.
    Link {
        model: std::sync::Arc<stereoscope_kinematics::Model>,
        link: usize,
        world_from_root: Isometry3<f64>,
        swings: Vec<stereoscope_kinematics::Swing>,
    },
    /// A random walk: every `step_s` seconds a Gaussian step of `step_m` standard deviation per
    /// axis, reflected back inside `extent_m` of `centre`; straight between steps, heading along
    /// the motion. Starts at `centre`.
    RandomWalk {
        centre: Point3<f64>,
        extent_m: Vector3<f64>,
        step_m: f64,
        step_s: f64,
        seed: u64,
    },
}

/// The walk's positions at steps `0..=n` (deterministic from the seed).
fn walk(
    centre: &Point3<f64>,
    extent: &Vector3<f64>,
    step_m: f64,
    n: usize,
    seed: u64,
) -> Vec<Point3<f64>> {
    let mut rng = SplitMix64::new(seed);
    let mut p = *centre;
    let mut out = Vec::with_capacity(n + 1);
    out.push(p);
    for _ in 0..n {
        for i in 0..3 {
            let mut v = p[i] + step_m * rng.normal();
            let (lo, hi) = (centre[i] - extent[i], centre[i] + extent[i]);
            // Reflect at the bounds (twice at most for steps smaller than the box).
            for _ in 0..2 {
                if v > hi {
                    v = 2.0 * hi - v;
                }
                if v < lo {
                    v = 2.0 * lo - v;
                }
            }
            p[i] = v.clamp(lo, hi);
        }
        out.push(p);
    }
    out
}

fn wander_terms(seed: u64) -> [[(f64, f64, f64); 3]; 3] {
    let mut rng = SplitMix64::new(seed);
    let mut t = [[(0.0, 0.0, 0.0); 3]; 3];
    for axis in &mut t {
        for (k, term) in axis.iter_mut().enumerate() {
            // amplitude share, frequency (Hz), phase
            *term = (
                1.0 / (k + 1) as f64,
                rng.range(0.05, 0.4) * (k + 1) as f64,
                rng.range(0.0, std::f64::consts::TAU),
            );
        }
    }
    t
}

impl Motion {
    pub fn at(&self, t_s: f64) -> State {
        match self {
            Motion::Link {
                model,
                link,
                world_from_root,
                swings,
            } => {
                let values = model.swing_values(swings, t_s);
                let mut poses = Vec::new();
                model.forward(world_from_root, &values, &mut poses);
                let p = poses.get(*link).copied().unwrap_or(*world_from_root);
                State {
                    position: Point3::from(p.translation.vector),
                    heading_deg: 0.0,
                    tilt: p.rotation,
                }
            }
            Motion::Static {
                position,
                heading_deg,
            } => State {
                position: *position,
                heading_deg: *heading_deg,
                tilt: UnitQuaternion::identity(),
            },
            Motion::Line { from, to, period_s } => {
                let phase = (t_s / period_s.max(1e-9)).rem_euclid(1.0);
                let (s, forward) = if phase < 0.5 {
                    (2.0 * phase, true)
                } else {
                    (2.0 - 2.0 * phase, false)
                };
                let d = to - from;
                let heading = d.y.atan2(d.x).to_degrees() + if forward { 0.0 } else { 180.0 };
                State {
                    position: from + d * s,
                    heading_deg: heading.rem_euclid(360.0),
                    tilt: UnitQuaternion::identity(),
                }
            }
            Motion::Circle {
                centre,
                radius_m,
                period_s,
            } => {
                let a = std::f64::consts::TAU * t_s / period_s.max(1e-9);
                State {
                    position: centre + Vector3::new(radius_m * a.cos(), radius_m * a.sin(), 0.0),
                    heading_deg: (a.to_degrees() + 90.0).rem_euclid(360.0),
                    tilt: UnitQuaternion::identity(),
                }
            }
            Motion::Head {
                centre,
                radius_m,
                period_s,
                turn_period_s,
                nod_deg,
            } => {
                let tau = std::f64::consts::TAU;
                let a = tau * t_s / period_s.max(1e-9);
                let nod = nod_deg.to_radians();
                let pitch = nod * (tau * 0.31 * t_s).sin();
                let roll = 0.6 * nod * (tau * 0.17 * t_s + 1.0).sin();
                State {
                    position: centre + Vector3::new(radius_m * a.cos(), radius_m * a.sin(), 0.0),
                    heading_deg: (360.0 * t_s / turn_period_s.max(1e-9)).rem_euclid(360.0),
                    tilt: UnitQuaternion::from_euler_angles(roll, pitch, 0.0),
                }
            }
            Motion::Spin {
                position,
                deg_per_s,
            } => State {
                position: *position,
                heading_deg: (deg_per_s * t_s).rem_euclid(360.0),
                tilt: UnitQuaternion::identity(),
            },
            Motion::RandomWalk {
                centre,
                extent_m,
                step_m,
                step_s,
                seed,
            } => {
                let t = t_s.max(0.0) / step_s.max(1e-9);
                let k = t.floor() as usize;
                let pts = walk(centre, extent_m, *step_m, k + 1, *seed);
                let (a, b) = (pts[k], pts[k + 1]);
                let d = b - a;
                State {
                    position: a + d * (t - k as f64),
                    heading_deg: d.y.atan2(d.x).to_degrees().rem_euclid(360.0),
                    tilt: UnitQuaternion::identity(),
                }
            }
            Motion::Wander {
                centre,
                extent_m,
                seed,
            } => {
                let terms = wander_terms(*seed);
                let eval = |t: f64| -> Vector3<f64> {
                    Vector3::from_fn(|i, _| {
                        let norm: f64 = terms[i].iter().map(|x| x.0).sum();
                        extent_m[i]
                            * terms[i]
                                .iter()
                                .map(|&(a, f, p)| a * (std::f64::consts::TAU * f * t + p).sin())
                                .sum::<f64>()
                            / norm
                    })
                };
                let (p, q) = (eval(t_s), eval(t_s + 1e-3));
                let v = q - p;
                State {
                    position: centre + p,
                    heading_deg: v.y.atan2(v.x).to_degrees().rem_euclid(360.0),
                    tilt: UnitQuaternion::identity(),
                }
            }
        }
    }
}

/// A target that moves: its shape, brightness and motion, and when it is hidden.
#[derive(Debug, Clone, PartialEq)]
pub struct Actor {
    pub shape: Shape,
    pub contrast: f64,
    pub motion: Motion,
    pub hidden: Option<Blink>,
}

/// Hidden again and again: at scene times `t` with `t mod every_s < for_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Blink {
    pub every_s: f64,
    pub for_s: f64,
}

impl Blink {
    pub fn hides_at(&self, t_s: f64) -> bool {
        t_s.rem_euclid(self.every_s) < self.for_s
    }
}

/// The scene at time `t_s`: `base` (background, light, distractors) with every actor placed,
/// and the actors' true states.
pub fn scene_at(base: &Scene, actors: &[Actor], t_s: f64) -> (Scene, Vec<State>) {
    let states: Vec<State> = actors.iter().map(|a| a.motion.at(t_s)).collect();
    let mut scene = base.clone();
    scene.targets = actors
        .iter()
        .zip(&states)
        .map(|(a, s)| Target {
            // A hidden actor keeps its place in the list (its truth: not visible), no shape.
            shape: if a.hidden.is_some_and(|h| h.hides_at(t_s)) {
                Shape::Markers {
                    spheres: Vec::new(),
                }
            } else {
                a.shape.clone()
            },
            world_from_body: s.world_from_body(),
            contrast: a.contrast,
        })
        .collect();
    (scene, states)
}
