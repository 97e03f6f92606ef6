//! Joint values by one least-squares fit of the whole chain to the triangulated markers of a
//! frame: the thesis's kinematic recovery (§5.3) — where it measured each link's direction from
//! two markers and took lengths as known, every marker here pulls on every joint between it
//! and the root at once, the joints' limits bound the answer, and a link whose markers are all
//! hidden is placed by its neighbours when the chain determines it.
//!
//! Levenberg–Marquardt over the base's six degrees of freedom (floating base) and every
//! joint's own (1 for a hinge or slide, 2 for a universal joint, 3 for a ball joint, as a
//! rotation increment in the joint's frame), with analytic Jacobians: a hinge's column for a
//! marker at `p` is `axis × (p − origin)`, a slide's is its axis. Warm-started from the last
//! frame's answer, so a hinge's angle moves continuously (no wrap, no flip); from nothing, it
//! starts joint by joint down the tree (each link's markers give its joint's value in closed
//! form: a hinge's angle by `atan2`, a ball's rotation by Kabsch about its centre).
//!
//! Which degrees of freedom the markers determine comes from the fit's own normal matrix: a
//! direction in parameter space along which the markers do not move (a near-zero eigenvalue of
//! the column-scaled `JᵀJ`) leaves the joints it involves undetermined, and they are flagged,
//! never reported as measured. A joint must also move some link that shows three markers or
//! more: one or two markers beyond a joint can fix it to first order and still allow other,
//! discrete solutions.

use crate::model::{Base, JointKind, JointValue, Model};
use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, UnitQuaternion, Vector3};

/// The chain's configuration: the root's pose and every joint's value.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainState {
    pub world_from_root: Isometry3<f64>,
    pub values: Vec<JointValue>,
}

/// The fit's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    pub max_iterations: usize,
    /// A frame whose markers' RMS residual is above this is not valid (a wrong marker, a
    /// model that does not match the robot).
    pub max_rms_m: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            max_iterations: 30,
            max_rms_m: 0.005,
        }
    }
}

/// One joint's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointFit {
    /// The markers determine every degree of freedom of the joint.
    pub determined: bool,
    /// A limit held the value.
    pub at_limit: bool,
    /// RMS residual of the visible markers on the joint's child link, metres (`None`: none
    /// visible).
    pub residual_m: Option<f64>,
}

/// What the fit found for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainFit {
    pub state: ChainState,
    pub world_from_link: Vec<Isometry3<f64>>,
    pub joints: Vec<JointFit>,
    /// The base's pose is determined (always, for a fixed base).
    pub base_determined: bool,
    /// RMS over every visible marker, metres.
    pub rms_m: f64,
    pub markers_used: usize,
    pub iterations: usize,
    /// Enough markers, a determined base, and the RMS — over all markers, and over each link's
    /// — within [`FitOptions::max_rms_m`] (one link's markers far off its fit is a wrong
    /// marker, however well the rest fit).
    pub valid: bool,
}

/// Why a frame could not be fitted at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error(
        "model {model:?}: {observed} observations for {markers} markers (one per marker, hidden ones None)"
    )]
    Count {
        model: String,
        observed: usize,
        markers: usize,
    },
    #[error(
        "model {model:?}: no previous frame and {seen} of the root link {link:?}'s markers seen; a start needs 3"
    )]
    NoStart {
        model: String,
        link: String,
        seen: usize,
    },
}

/// Where each degree of freedom sits among the fit's parameters: the base's first (six for a
/// floating base), then each joint's.
struct Layout {
    base_cols: usize,
    offsets: Vec<usize>,
    n: usize,
}

fn layout(model: &Model) -> Layout {
    let base_cols = match model.base {
        Base::Floating => 6,
        Base::Fixed(_) => 0,
    };
    let mut offsets = Vec::with_capacity(model.joints.len());
    let mut n = base_cols;
    for j in &model.joints {
        offsets.push(n);
        n += j.kind.dof();
    }
    Layout {
        base_cols,
        offsets,
        n,
    }
}

/// The rotation that best turns `from` into `to` about the origin (Kabsch without
/// translation); `None` when the points do not fix it (fewer than two directions).
fn rotation_about_origin(
    from: &[Vector3<f64>],
    to: &[Vector3<f64>],
) -> Option<UnitQuaternion<f64>> {
    let mut m = Matrix3::zeros();
    for (a, b) in from.iter().zip(to) {
        m += b * a.transpose();
    }
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut s = svd.singular_values;
    s.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if s[1] <= 1e-9 * s[0].max(1e-12) {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t;
    Some(UnitQuaternion::from_matrix(&r))
}

/// The angle about `axis` (unit) that best turns `from` into `to` (closed form: the
/// objective is `A cos θ + B sin θ + C`).
fn hinge_angle(axis: &Vector3<f64>, from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<f64> {
    let (mut a, mut b) = (0.0, 0.0);
    for (m, y) in from.iter().zip(to) {
        a += y.dot(m) - axis.dot(y) * axis.dot(m);
        b += y.dot(&axis.cross(m));
    }
    (a.hypot(b) > 1e-12).then(|| b.atan2(a))
}

/// The two angles of `r = rot(a0, θ0) · rot(a1, θ1)` (exact for perpendicular axes, the
/// nearest otherwise).
fn universal_angles(a0: &Vector3<f64>, a1: &Vector3<f64>, r: &UnitQuaternion<f64>) -> [f64; 2] {
    let ra1 = r * a1;
    let t0 = a0
        .dot(&a1.cross(&ra1))
        .atan2(a1.dot(&ra1) - a0.dot(a1) * a0.dot(&ra1));
    let rest = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(*a0), -t0) * r;
    let u = a1
        .cross(&if a1.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        })
        .normalize();
    let w = rest * u;
    let t1 = a1.dot(&u.cross(&w)).atan2(u.dot(&w));
    [t0, t1]
}

fn clamp_value(kind: &JointKind, v: JointValue) -> (JointValue, bool) {
    let cl = |l: &Option<crate::model::Limits>, x: f64| match l {
        Some(l) => (l.clamp(x), l.clamp(x) != x),
        None => (x, false),
    };
    match (kind, v) {
        (JointKind::Revolute { limits, .. }, JointValue::Angle(a)) => {
            let (a, at) = cl(limits, a);
            (JointValue::Angle(a), at)
        }
        (JointKind::Prismatic { limits, .. }, JointValue::Offset(d)) => {
            let (d, at) = cl(limits, d);
            (JointValue::Offset(d), at)
        }
        (JointKind::Universal { limits, .. }, JointValue::Angles([a, b])) => {
            let (a, at0) = cl(&limits[0], a);
            let (b, at1) = cl(&limits[1], b);
            (JointValue::Angles([a, b]), at0 || at1)
        }
        _ => (v, false),
    }
}

/// Whether a value sits on one of its joint's limits (where a clamp put it).
fn at_limit(kind: &JointKind, v: JointValue) -> bool {
    let on =
        |l: &Option<crate::model::Limits>, x: f64| l.is_some_and(|l| x == l.lower || x == l.upper);
    match (kind, v) {
        (JointKind::Revolute { limits, .. }, JointValue::Angle(a)) => on(limits, a),
        (JointKind::Prismatic { limits, .. }, JointValue::Offset(d)) => on(limits, d),
        (JointKind::Universal { limits, .. }, JointValue::Angles([a, b])) => {
            on(&limits[0], a) || on(&limits[1], b)
        }
        _ => false,
    }
}

/// A start from nothing: the root by Kabsch of its markers, then each joint in tree order
/// from its child link's markers given its parent's pose.
pub fn initial_state(
    model: &Model,
    observed: &[Option<Point3<f64>>],
) -> Result<ChainState, FitError> {
    let world_from_root = match &model.base {
        Base::Fixed(p) => *p,
        Base::Floating => {
            let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = model
                .markers
                .iter()
                .zip(observed)
                .filter(|(m, _)| m.link == 0)
                .filter_map(|(m, o)| o.map(|o| (m.in_link_m, o)))
                .unzip();
            let start = stereoscope_bodies::kabsch(&a, &b, &vec![1.0; a.len()]).map(|(p, _)| p);
            start.ok_or_else(|| FitError::NoStart {
                model: model.name.clone(),
                link: model.links[0].name.clone(),
                seen: a.len(),
            })?
        }
    };
    let mut values = model.zero();
    let mut poses = vec![Isometry3::identity(); model.links.len()];
    poses[0] = world_from_root;
    for (j, joint) in model.joints.iter().enumerate() {
        let world_from_joint = poses[joint.parent] * joint.parent_from_joint;
        let inv = world_from_joint.inverse();
        let (from, to): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = model
            .markers
            .iter()
            .zip(observed)
            .filter(|(m, _)| m.link == joint.child)
            .filter_map(|(m, o)| o.map(|o| (m.in_link_m.coords, (inv * o).coords)))
            .unzip();
        let v = match &joint.kind {
            JointKind::Fixed => Some(JointValue::Fixed),
            JointKind::Revolute { axis, .. } => {
                hinge_angle(axis, &from, &to).map(JointValue::Angle)
            }
            JointKind::Prismatic { axis, .. } => (!from.is_empty()).then(|| {
                let d = from
                    .iter()
                    .zip(&to)
                    .map(|(m, y)| axis.dot(&(y - m)))
                    .sum::<f64>()
                    / from.len() as f64;
                JointValue::Offset(d)
            }),
            JointKind::Spherical => rotation_about_origin(&from, &to).map(JointValue::Rotation),
            JointKind::Universal { axes, .. } => rotation_about_origin(&from, &to)
                .map(|r| JointValue::Angles(universal_angles(&axes[0], &axes[1], &r))),
        };
        if let Some(v) = v {
            values[j] = clamp_value(&joint.kind, v).0;
        }
        poses[joint.child] = world_from_joint * values[j].motion(&joint.kind);
    }
    Ok(ChainState {
        world_from_root,
        values,
    })
}

/// Residuals (observed − predicted would flip signs; here predicted − observed) and, when
/// `jac` is given, the Jacobian, for the visible markers.
fn evaluate(
    model: &Model,
    state: &ChainState,
    observed: &[Option<Point3<f64>>],
    lay: &Layout,
    poses: &mut Vec<Isometry3<f64>>,
    r: &mut DVector<f64>,
    jac: Option<&mut DMatrix<f64>>,
) {
    model.forward(&state.world_from_root, &state.values, poses);
    let mut row = 0;
    for (m, o) in model.markers.iter().zip(observed) {
        if let Some(o) = o {
            let p = poses[m.link] * m.in_link_m;
            let d = p - o;
            r[row] = d.x;
            r[row + 1] = d.y;
            r[row + 2] = d.z;
            row += 3;
        }
    }
    let Some(jac) = jac else { return };
    jac.fill(0.0);
    let mut row = 0;
    let root_origin = state.world_from_root.translation.vector;
    for (m, o) in model.markers.iter().zip(observed) {
        if o.is_none() {
            continue;
        }
        let p = (poses[m.link] * m.in_link_m).coords;
        let mut put = |col: usize, v: Vector3<f64>| {
            jac[(row, col)] = v.x;
            jac[(row + 1, col)] = v.y;
            jac[(row + 2, col)] = v.z;
        };
        if lay.base_cols == 6 {
            for k in 0..3 {
                put(k, Vector3::ith(k, 1.0));
                put(3 + k, Vector3::<f64>::ith(k, 1.0).cross(&(p - root_origin)));
            }
        }
        for &j in model.path(m.link) {
            let joint = &model.joints[j];
            let wj = poses[joint.parent] * joint.parent_from_joint;
            let o = wj.translation.vector;
            let c = lay.offsets[j];
            match (&joint.kind, state.values[j]) {
                (JointKind::Revolute { axis, .. }, _) => {
                    put(c, (wj.rotation * axis.into_inner()).cross(&(p - o)));
                }
                (JointKind::Prismatic { axis, .. }, _) => {
                    put(c, wj.rotation * axis.into_inner());
                }
                (JointKind::Universal { axes, .. }, JointValue::Angles([t0, _])) => {
                    let a0 = wj.rotation * axes[0].into_inner();
                    let a1 = wj.rotation
                        * (UnitQuaternion::from_axis_angle(&axes[0], t0) * axes[1].into_inner());
                    put(c, a0.cross(&(p - o)));
                    put(c + 1, a1.cross(&(p - o)));
                }
                (JointKind::Spherical, _) => {
                    for k in 0..3 {
                        put(c + k, (wj.rotation * Vector3::ith(k, 1.0)).cross(&(p - o)));
                    }
                }
                _ => {}
            }
        }
        row += 3;
    }
}

/// The state moved by `delta`, clamped to the limits; whether each joint sits at a limit.
fn step(model: &Model, s: &ChainState, delta: &DVector<f64>, lay: &Layout) -> ChainState {
    let mut next = s.clone();
    if lay.base_cols == 6 {
        let dt = Vector3::new(delta[0], delta[1], delta[2]);
        let dw = Vector3::new(delta[3], delta[4], delta[5]);
        next.world_from_root = Isometry3::from_parts(
            (s.world_from_root.translation.vector + dt).into(),
            UnitQuaternion::from_scaled_axis(dw) * s.world_from_root.rotation,
        );
    }
    for (j, joint) in model.joints.iter().enumerate() {
        let c = lay.offsets[j];
        let v = match s.values[j] {
            JointValue::Angle(a) => JointValue::Angle(a + delta[c]),
            JointValue::Offset(d) => JointValue::Offset(d + delta[c]),
            JointValue::Angles([a, b]) => JointValue::Angles([a + delta[c], b + delta[c + 1]]),
            JointValue::Rotation(q) => JointValue::Rotation(
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    delta[c],
                    delta[c + 1],
                    delta[c + 2],
                )) * q,
            ),
            JointValue::Fixed => JointValue::Fixed,
        };
        next.values[j] = clamp_value(&joint.kind, v).0;
    }
    next
}

/// Fits the chain to one frame's markers (`observed[i]` for `model.markers[i]`, `None` when
/// hidden), warm-started from `previous` (the last frame's state) or, without one, from
/// [`initial_state`].
pub fn fit_chain(
    model: &Model,
    observed: &[Option<Point3<f64>>],
    previous: Option<&ChainState>,
    opts: &FitOptions,
) -> Result<ChainFit, FitError> {
    if observed.len() != model.markers.len() {
        return Err(FitError::Count {
            model: model.name.clone(),
            observed: observed.len(),
            markers: model.markers.len(),
        });
    }
    let mut state = match previous {
        Some(p) if p.values.len() == model.joints.len() => p.clone(),
        _ => initial_state(model, observed)?,
    };
    let lay = layout(model);
    let (base_cols, n) = (lay.base_cols, lay.n);
    let visible = observed.iter().filter(|o| o.is_some()).count();
    let rows = 3 * visible;
    let mut poses = Vec::new();
    let mut r = DVector::zeros(rows);
    let mut jac = DMatrix::zeros(rows, n);
    let mut cost;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut trial_r = DVector::zeros(rows);
    let mut trial_poses = Vec::new();
    loop {
        // The residuals and Jacobian at the current state (new after an accepted step).
        evaluate(
            model,
            &state,
            observed,
            &lay,
            &mut poses,
            &mut r,
            Some(&mut jac),
        );
        cost = r.norm_squared();
        if iterations >= opts.max_iterations || n == 0 || rows == 0 {
            break;
        }
        iterations += 1;
        let h = jac.tr_mul(&jac);
        let g = jac.tr_mul(&r);
        let scale = (0..n).map(|i| h[(i, i)]).fold(0.0f64, f64::max).max(1e-12);
        let mut improved = false;
        for _ in 0..10 {
            let mut a = h.clone();
            for i in 0..n {
                a[(i, i)] += lambda * h[(i, i)] + 1e-9 * scale;
            }
            let Some(chol) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = -chol.solve(&g);
            let trial = step(model, &state, &delta, &lay);
            evaluate(
                model,
                &trial,
                observed,
                &lay,
                &mut trial_poses,
                &mut trial_r,
                None,
            );
            let trial_cost = trial_r.norm_squared();
            if trial_cost <= cost {
                let small = delta.norm() < 1e-10 || cost - trial_cost <= 1e-14 * cost.max(1e-30);
                state = trial;
                lambda = (lambda / 3.0).max(1e-9);
                improved = !small;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    // What the markers determine: null directions of the column-scaled normal matrix.
    let mut determined = vec![true; n];
    if n > 0 {
        let norms: Vec<f64> = (0..n).map(|c| jac.column(c).norm()).collect();
        let top = norms.iter().copied().fold(0.0f64, f64::max);
        let live: Vec<usize> = (0..n)
            .filter(|&c| norms[c] > 1e-9 * top.max(1e-12))
            .collect();
        for c in 0..n {
            if !live.contains(&c) {
                determined[c] = false;
            }
        }
        if !live.is_empty() {
            let mut scaled = DMatrix::zeros(rows, live.len());
            for (k, &c) in live.iter().enumerate() {
                scaled.set_column(k, &(jac.column(c) / norms[c]));
            }
            let eig = scaled.tr_mul(&scaled).symmetric_eigen();
            let biggest = eig.eigenvalues.iter().copied().fold(0.0f64, f64::max);
            for (i, &ev) in eig.eigenvalues.iter().enumerate() {
                if ev < 1e-8 * biggest {
                    for (k, &c) in live.iter().enumerate() {
                        if eig.eigenvectors[(k, i)].abs() > 0.05 {
                            determined[c] = false;
                        }
                    }
                }
            }
        }
    }
    let base_determined = determined[..base_cols].iter().all(|d| *d) && rows > 0;
    // A joint moved only by one or two markers may be determined to first order yet have
    // several discrete solutions (a marker on a circle about each of two axes): it counts as
    // determined only when some link it moves shows three markers or more.
    let mut seen_on = vec![0usize; model.links.len()];
    for (m, o) in model.markers.iter().zip(observed) {
        if o.is_some() {
            seen_on[m.link] += 1;
        }
    }
    let moves_a_cluster: Vec<bool> = (0..model.joints.len())
        .map(|j| (0..model.links.len()).any(|l| seen_on[l] >= 3 && model.path(l).contains(&j)))
        .collect();
    let joints: Vec<JointFit> = model
        .joints
        .iter()
        .enumerate()
        .map(|(j, joint)| {
            let c = lay.offsets[j];
            let resid: Vec<f64> = model
                .markers
                .iter()
                .zip(observed)
                .filter(|(m, _)| m.link == joint.child)
                .filter_map(|(m, o)| o.map(|o| (poses[m.link] * m.in_link_m - o).norm_squared()))
                .collect();
            JointFit {
                determined: base_determined
                    && (joint.kind.dof() == 0 || moves_a_cluster[j])
                    && determined[c..c + joint.kind.dof()].iter().all(|d| *d),
                at_limit: at_limit(&joint.kind, state.values[j]),
                residual_m: (!resid.is_empty())
                    .then(|| (resid.iter().sum::<f64>() / resid.len() as f64).sqrt()),
            }
        })
        .collect();
    let rms_m = if visible > 0 {
        (cost / visible as f64).sqrt()
    } else {
        f64::INFINITY
    };
    Ok(ChainFit {
        valid: visible >= 3
            && base_determined
            && rms_m <= opts.max_rms_m
            && joints
                .iter()
                .all(|j: &JointFit| j.residual_m.is_none_or(|r| r <= opts.max_rms_m)),
        state,
        world_from_link: poses,
        joints,
        base_determined,
        rms_m,
        markers_used: visible,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn universal_angles_invert_their_rotation() {
        let a0 = Vector3::x();
        let a1 = Vector3::y();
        for (t0, t1) in [(0.3, -0.7), (-1.2, 0.4), (2.0, 1.1)] {
            let r = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), t0)
                * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), t1);
            let [u0, u1] = universal_angles(&a0, &a1, &r);
            assert!(
                (u0 - t0).abs() < 1e-12 && (u1 - t1).abs() < 1e-12,
                "{u0} {u1}"
            );
        }
    }

    #[test]
    fn the_hinge_angle_in_closed_form() {
        let axis = Vector3::z();
        let from = [Vector3::new(0.1, 0.0, 0.2), Vector3::new(0.0, 0.3, -0.1)];
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2.5);
        let to: Vec<Vector3<f64>> = from.iter().map(|v| q * v).collect();
        let a = hinge_angle(&axis, &from, &to).unwrap();
        assert!((a - 2.5).abs() < 1e-12, "{a}");
        // Markers on the axis do not give an angle.
        assert_eq!(hinge_angle(&axis, &[Vector3::z()], &[Vector3::z()]), None);
    }
}
