//! Joints between two rigid clusters — SCoRE centres and SARA axes from one 6 × 6 normal
//! system per pair — and the skeleton's zero pose registered onto the joints measured: the
//! geometry half of [`super`].

use super::clusters::Cluster;
use crate::model::{JointKind, Model};
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Translation3, Vector3, Vector6};

/// A joint's feature fixed in a link: a hinge's axis (a point on it and its direction) or a
/// ball joint's centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Feature {
    Axis(Point3<f64>, Vector3<f64>),
    Centre(Point3<f64>),
}

impl Feature {
    pub(super) fn point(&self) -> Point3<f64> {
        match self {
            Feature::Axis(p, _) | Feature::Centre(p) => *p,
        }
    }

    pub(super) fn transformed(&self, by: &Isometry3<f64>) -> Feature {
        match self {
            Feature::Axis(p, d) => Feature::Axis(by * p, by * d),
            Feature::Centre(p) => Feature::Centre(by * p),
        }
    }
}

/// Two axes closer than this angle are parallel (their distance is the lines' distance).
pub(super) const PARALLEL_RAD: f64 = 0.01;

/// Distance between two features (axis–axis along the common normal, axis–centre, centre–
/// centre) and, for two axes, the angle between them (0 to π/2).
pub(super) fn feature_distance(a: &Feature, b: &Feature) -> (f64, Option<f64>) {
    let line_point = |p: &Point3<f64>, d: &Vector3<f64>, q: &Point3<f64>| (q - p).cross(d).norm();
    match (a, b) {
        (Feature::Centre(p), Feature::Centre(q)) => ((p - q).norm(), None),
        (Feature::Axis(p, d), Feature::Centre(q)) | (Feature::Centre(q), Feature::Axis(p, d)) => {
            (line_point(p, d, q), None)
        }
        (Feature::Axis(p, d), Feature::Axis(q, e)) => {
            let n = d.cross(e);
            let angle = n.norm().asin().clamp(0.0, std::f64::consts::FRAC_PI_2);
            let dist = if angle < PARALLEL_RAD {
                line_point(p, d, q)
            } else {
                ((q - p).dot(&n) / n.norm()).abs()
            };
            (dist, Some(angle))
        }
    }
}

/// The normal equations of `R_a·c_a − R_b·c_b = t_b − t_a` over the frames both clusters are
/// posed in.
pub(super) struct PairSystem {
    pub(super) ata: Matrix6<f64>,
    pub(super) atb: Vector6<f64>,
    pub(super) btb: f64,
    pub(super) frames: usize,
}

impl PairSystem {
    fn new(a: &Cluster, b: &Cluster) -> PairSystem {
        let mut s = PairSystem {
            ata: Matrix6::zeros(),
            atb: Vector6::zeros(),
            btb: 0.0,
            frames: 0,
        };
        for (pa, pb) in a.poses.iter().zip(&b.poses) {
            let (Some(pa), Some(pb)) = (pa, pb) else {
                continue;
            };
            let ra = pa.rotation.to_rotation_matrix().into_inner();
            let rb = pb.rotation.to_rotation_matrix().into_inner();
            let mut row = nalgebra::Matrix3x6::zeros();
            row.fixed_view_mut::<3, 3>(0, 0).copy_from(&ra);
            row.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rb));
            let rhs = pb.translation.vector - pa.translation.vector;
            s.ata += row.transpose() * row;
            s.atb += row.transpose() * rhs;
            s.btb += rhs.norm_squared();
            s.frames += 1;
        }
        s
    }

    /// The least-squares solution, leaving out the `drop` least singular directions, and its
    /// RMS residual per frame (metres).
    fn solve(&self, drop: usize) -> (Vector6<f64>, f64) {
        let eig = self.ata.symmetric_eigen();
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
        let top = eig.eigenvalues[order[0]].max(1e-300);
        let mut x = Vector6::zeros();
        for &k in order.iter().take(6 - drop) {
            let l = eig.eigenvalues[k];
            if l > 1e-12 * top {
                let v = eig.eigenvectors.column(k);
                x += v * (v.dot(&self.atb) / l);
            }
        }
        let sq = (x.dot(&(self.ata * x)) - 2.0 * x.dot(&self.atb) + self.btb).max(0.0);
        (x, (sq / self.frames.max(1) as f64).sqrt())
    }

    /// The hinge axis (direction in a, in b) and its RMS angle residual.
    fn axis(&self) -> (Vector3<f64>, Vector3<f64>, f64) {
        let eig = self.ata.symmetric_eigen();
        let k = (0..6)
            .min_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]))
            .unwrap_or(5);
        let v = eig.eigenvectors.column(k);
        let na = Vector3::new(v[0], v[1], v[2]);
        let nb = Vector3::new(v[3], v[4], v[5]);
        // |R_a·n_a − R_b·n_b|² with |n_a| = |n_b| = 1/√2 is half the squared chord.
        let residual = (2.0 * eig.eigenvalues[k].max(0.0) / self.frames.max(1) as f64).sqrt();
        (
            na.try_normalize(1e-12).unwrap_or_else(Vector3::z),
            nb.try_normalize(1e-12).unwrap_or_else(Vector3::z),
            residual,
        )
    }
}

/// A joint's fit between the clusters of its parent and child link: its features in each
/// cluster's frame, its residual (metres) and the axis residual (radians) of a hinge.
#[derive(Clone)]
pub(super) struct JointMeasure {
    pub(super) in_a: Feature,
    pub(super) in_b: Feature,
    pub(super) residual_m: f64,
    pub(super) axis_rad: Option<f64>,
    pub(super) frames: usize,
}

/// The lever that weighs an axis residual against a centre residual, metres.
pub(super) const AXIS_LEVER_M: f64 = 0.1;

pub(super) fn measure(a: &Cluster, b: &Cluster, hinge: bool) -> JointMeasure {
    let s = PairSystem::new(a, b);
    if hinge {
        let (na, nb, axis_rad) = s.axis();
        let (x, r) = s.solve(1);
        JointMeasure {
            in_a: Feature::Axis(Point3::new(x[0], x[1], x[2]), na),
            in_b: Feature::Axis(Point3::new(x[3], x[4], x[5]), nb),
            residual_m: r,
            axis_rad: Some(axis_rad),
            frames: s.frames,
        }
    } else {
        let (x, r) = s.solve(0);
        JointMeasure {
            in_a: Feature::Centre(Point3::new(x[0], x[1], x[2])),
            in_b: Feature::Centre(Point3::new(x[3], x[4], x[5])),
            residual_m: r,
            axis_rad: None,
            frames: s.frames,
        }
    }
}

impl JointMeasure {
    pub(super) fn cost(&self) -> f64 {
        let axis = self.axis_rad.unwrap_or(0.0) * AXIS_LEVER_M;
        (self.residual_m * self.residual_m + axis * axis).sqrt()
    }
}

/// The skeleton's links bolted together by fixed joints are one rigid body; its movable joints
/// join bodies. Bodies in tree order, each with its first (main) link.
pub(super) struct Bodies {
    pub(super) main_link: Vec<usize>,
    /// Movable joints: (joint index, parent body, child body).
    pub(super) joints: Vec<(usize, usize, usize)>,
}

pub(super) fn bodies(model: &Model) -> Bodies {
    let mut of_link = vec![usize::MAX; model.links.len()];
    let mut main_link = vec![0];
    of_link[0] = 0;
    let mut joints = Vec::new();
    for (j, joint) in model.joints.iter().enumerate() {
        let pb = of_link[joint.parent];
        if joint.kind == JointKind::Fixed {
            of_link[joint.child] = pb;
        } else {
            of_link[joint.child] = main_link.len();
            main_link.push(joint.child);
            joints.push((j, pb, of_link[joint.child]));
        }
    }
    Bodies { main_link, joints }
}

/// Wahba's problem: the rotation taking each `from` direction onto its `to`, weighted.
pub(super) fn wahba(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Option<Matrix3<f64>> {
    let mut b = Matrix3::zeros();
    for (f, t) in from.iter().zip(to) {
        b += t * f.transpose();
    }
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    if svd.singular_values[1] < 1e-6 * svd.singular_values[0].max(1e-300) {
        return None;
    }
    let d = (u * v_t).determinant().signum();
    Some(u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * v_t)
}

/// A registration of the skeleton's zero pose: the root's pose, its cost (metres, directions
/// weighed by the lever) and each joint's (distance, angle).
pub(super) struct Registration {
    pub(super) world_from_root: Isometry3<f64>,
    pub(super) cost_m: f64,
    pub(super) each: Vec<(f64, Option<f64>)>,
}

/// The root's poses registering the skeleton's joint features at the zero pose (`model`, root
/// frame) onto the measured ones (world). Hinge directions are signless: every choice of signs
/// is tried, and every rotation as good as the best is returned (a leg's hip, knee and ankle
/// in a line fit turned half round the line as well; the joints' limits tell them apart).
pub(super) fn register(model: &[Feature], measured: &[Feature]) -> Vec<Registration> {
    let hinges: Vec<usize> = (0..model.len())
        .filter(|&k| matches!(model[k], Feature::Axis(..)))
        .collect();
    let centres: Vec<usize> = (0..model.len())
        .filter(|&k| matches!(model[k], Feature::Centre(..)))
        .collect();
    if hinges.len() > 12 {
        return Vec::new();
    }
    let mut rotations: Vec<(f64, Matrix3<f64>)> = Vec::new();
    for signs in 0u32..(1 << hinges.len()) {
        let (mut from, mut to) = (Vec::new(), Vec::new());
        for (i, &k) in hinges.iter().enumerate() {
            if let (Feature::Axis(_, d), Feature::Axis(_, n)) = (model[k], measured[k]) {
                let s = if signs & (1 << i) != 0 { -1.0 } else { 1.0 };
                from.push(d);
                to.push(n * s);
            }
        }
        for (i, &k) in centres.iter().enumerate() {
            for &l in &centres[i + 1..] {
                let d = model[l].point() - model[k].point();
                let n = measured[l].point() - measured[k].point();
                // Weighed as the lever weighs directions: a centre pair's length is its weight.
                let w = d.norm().min(n.norm()) / AXIS_LEVER_M;
                if let (Some(d), Some(n)) = (d.try_normalize(1e-9), n.try_normalize(1e-9)) {
                    from.push(d * w);
                    to.push(n * w);
                }
            }
        }
        let Some(r) = wahba(&from, &to) else {
            continue;
        };
        let cost: f64 = from
            .iter()
            .zip(&to)
            .map(|(f, t)| (r * f - t).norm_squared())
            .sum();
        rotations.push((cost, r));
    }
    let best = rotations.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
    let mut kept: Vec<Matrix3<f64>> = Vec::new();
    for (c, r) in rotations {
        // As good as the best within noise (0.5° per direction), and not one kept already.
        if c <= best + 1e-4 * model.len() as f64 && kept.iter().all(|k| (k - r).norm() > 1e-3) {
            kept.push(r);
        }
    }
    kept.into_iter()
        .filter_map(|r| translate(model, measured, r))
        .collect()
}

/// The translation for rotation `r` by least squares (a centre onto its centre, an axis point
/// onto its line), and the registration's residuals.
pub(super) fn translate(
    model: &[Feature],
    measured: &[Feature],
    r: Matrix3<f64>,
) -> Option<Registration> {
    let mut m = Matrix3::zeros();
    let mut v = Vector3::zeros();
    for (f, g) in model.iter().zip(measured) {
        let q = r * f.point().coords;
        let p = match g {
            Feature::Centre(_) => Matrix3::identity(),
            Feature::Axis(_, n) => Matrix3::identity() - n * n.transpose(),
        };
        m += p;
        v += p * (g.point().coords - q);
    }
    let t = m.try_inverse()? * v;
    let rot = nalgebra::Rotation3::from_matrix_unchecked(r);
    let pose = Isometry3::from_parts(
        Translation3::from(t),
        nalgebra::UnitQuaternion::from_rotation_matrix(&rot),
    );
    let mut cost = 0.0;
    let mut each = Vec::new();
    for (f, g) in model.iter().zip(measured) {
        let placed = f.transformed(&pose);
        let (d, angle) = match (placed, g) {
            (Feature::Centre(p), Feature::Centre(c)) => ((p - c).norm(), None),
            (Feature::Axis(p, d), Feature::Axis(q, n)) => (
                (p - q).cross(n).norm(),
                Some(d.cross(n).norm().asin().abs()),
            ),
            _ => (f64::INFINITY, None),
        };
        let a = angle.unwrap_or(0.0) * AXIS_LEVER_M;
        cost += d * d + a * a;
        each.push((d, angle));
    }
    Some(Registration {
        world_from_root: pose,
        cost_m: (cost / model.len().max(1) as f64).sqrt(),
        each,
    })
}

/// The share of frames in which a hinge's angle (about `axis_world`, the registered skeleton's
/// axis at the zero pose; zero at the zero pose) lies outside `limits` by more than 3°.
pub(super) fn outside_limits(
    parent: &Cluster,
    child: &Cluster,
    home: (&Isometry3<f64>, &Isometry3<f64>),
    axis_world: &Vector3<f64>,
    limits: crate::model::Limits,
) -> f64 {
    let axis = home.0.rotation.inverse() * axis_world;
    let rel_home = home.0.rotation.inverse() * home.1.rotation;
    let (mut out, mut n) = (0usize, 0usize);
    for (a, b) in parent.poses.iter().zip(&child.poses) {
        let (Some(a), Some(b)) = (a, b) else {
            continue;
        };
        let q = a.rotation.inverse() * b.rotation * rel_home.inverse();
        let angle = 2.0 * q.imag().dot(&axis).atan2(q.w);
        let angle =
            (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        let margin = 3f64.to_radians();
        if angle < limits.lower - margin || angle > limits.upper + margin {
            out += 1;
        }
        n += 1;
    }
    out as f64 / n.max(1) as f64
}
