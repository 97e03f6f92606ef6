//! Pivot calibration (not in the thesis): the point of a body that stays put while the body
//! turns about it — a pointer's tip held in a divot, a joint's centre — from the body's poses.
//! Each pose `world_from_body_k = (R_k, t_k)` gives `R_k·p_body + t_k = p_world` for the one
//! point; the three unknowns of each side are found together by linear least squares over
//! every frame (`[R_k  −I]·[p_body; p_world] = −t_k`, normal equations, 6 × 6). The turn must
//! span enough angle to fix the point (a body that only slides fixes nothing), and the fit's
//! residual says whether the point really stayed put.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Vector6};

/// A pivot found: where it is in the body's frame and in the world, the RMS distance between
/// the frames' images of it, and how far the body turned.
#[derive(Debug, Clone, PartialEq)]
pub struct Pivot {
    pub in_body_m: Point3<f64>,
    pub in_world_m: Point3<f64>,
    pub rms_m: f64,
    /// The largest angle between the first pose's rotation and any other's, degrees.
    pub turn_deg: f64,
    pub frames: usize,
}

/// The fewest poses, the least turn and the largest residual a pivot is found with.
pub const MIN_POSES: usize = 10;
pub const MIN_TURN_DEG: f64 = 15.0;
pub const MAX_RMS_M: f64 = 0.002;
/// The least eigenvalue per pose of the normal matrix that fixes the point in every
/// direction (turns of ±10° about a second axis give about 0.005).
const MIN_EIGEN_PER_POSE: f64 = 0.002;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PivotError {
    #[error("{found} poses of the body; a pivot needs {MIN_POSES} or more while it turns")]
    TooFew { found: usize },
    #[error(
        "the body turned {turn_deg:.1}° at most; turn it at least {MIN_TURN_DEG}° about the point it pivots on"
    )]
    TooLittleTurn { turn_deg: f64 },
    #[error(
        "the body turned about one axis only, which leaves the point anywhere along it: tilt it too"
    )]
    OneAxis,
    #[error(
        "no point stayed put: the best one moved {rms_mm:.1} mm RMS (at most {} mm); keep the pivot still while the body turns",
        MAX_RMS_M * 1e3
    )]
    Moved { rms_mm: f64 },
}

/// The point fixed in the body while it took `poses` (`world_from_body` each).
pub fn pivot(poses: &[Isometry3<f64>]) -> Result<Pivot, PivotError> {
    if poses.len() < MIN_POSES {
        return Err(PivotError::TooFew { found: poses.len() });
    }
    let first = poses[0].rotation;
    let turn_deg = poses
        .iter()
        .map(|p| first.angle_to(&p.rotation).to_degrees())
        .fold(0.0, f64::max);
    if !(turn_deg >= MIN_TURN_DEG) {
        return Err(PivotError::TooLittleTurn { turn_deg });
    }
    let mut ata = Matrix6::<f64>::zeros();
    let mut atb = Vector6::<f64>::zeros();
    for p in poses {
        let r: Matrix3<f64> = p.rotation.to_rotation_matrix().into_inner();
        let t = p.translation.vector;
        // A = [R  −I]: AᵀA = [[RᵀR, −Rᵀ], [−R, I]] = [[I, −Rᵀ], [−R, I]]; Aᵀb with b = −t.
        let mut a = nalgebra::Matrix3x6::<f64>::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        a.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-Matrix3::identity()));
        ata += a.transpose() * a;
        atb += a.transpose() * (-t);
    }
    // Turns about one axis only leave the point free along it: the normal matrix's least
    // eigenvalue, per pose, is then ~0 (about 1 − cos θ for turns of θ about two axes).
    let least = ata
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    if !(least / poses.len() as f64 >= MIN_EIGEN_PER_POSE) {
        return Err(PivotError::OneAxis);
    }
    let x = ata.lu().solve(&atb).ok_or(PivotError::OneAxis)?;
    let in_body = Point3::new(x[0], x[1], x[2]);
    let in_world = Point3::new(x[3], x[4], x[5]);
    let sq: f64 = poses
        .iter()
        .map(|p| (p * in_body - in_world).norm_squared())
        .sum();
    let rms_m = (sq / poses.len() as f64).sqrt();
    if !(rms_m <= MAX_RMS_M) {
        return Err(PivotError::Moved {
            rms_mm: rms_m * 1e3,
        });
    }
    Ok(Pivot {
        in_body_m: in_body,
        in_world_m: in_world,
        rms_m,
        turn_deg,
        frames: poses.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};
    use stereoscope_numeric::random::SplitMix64;

    fn pose(rotation: UnitQuaternion<f64>, translation: Vector3<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(translation.into(), rotation)
    }

    /// A pointer whose tip (0.15 m along its x) sits in a divot at (0.3, −0.2, 0.05) while it
    /// is swung through ±40° in two directions, its poses measured with 0.2 mm and 0.1° of
    /// noise: the tip found within 0.5 mm in the body and in the world.
    #[test]
    fn a_pointers_tip_is_found_from_its_swings() {
        let tip_body = Point3::new(0.15, 0.0, 0.0);
        let divot = Point3::new(0.3, -0.2, 0.05);
        let mut rng = SplitMix64::new(4);
        let poses: Vec<Isometry3<f64>> = (0..200)
            .map(|k| {
                let s = k as f64 / 200.0 * std::f64::consts::TAU;
                let rot = UnitQuaternion::from_euler_angles(
                    40f64.to_radians() * s.sin(),
                    40f64.to_radians() * (2.0 * s).cos(),
                    0.3 * s,
                );
                let noise = UnitQuaternion::from_euler_angles(
                    0.1f64.to_radians() * rng.normal(),
                    0.1f64.to_radians() * rng.normal(),
                    0.1f64.to_radians() * rng.normal(),
                );
                let rot = rot * noise;
                // The tip lands on the divot: t = divot − R·tip.
                let t = divot.coords - rot * tip_body.coords
                    + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.0002;
                pose(rot, t)
            })
            .collect();
        let p = pivot(&poses).unwrap();
        assert!((p.in_body_m - tip_body).norm() < 0.0005, "{p:?}");
        assert!((p.in_world_m - divot).norm() < 0.0005, "{p:?}");
        assert!(p.rms_m < 0.001 && p.turn_deg > 40.0, "{p:?}");
    }

    /// Too few poses, a body that only slides, and one whose "pivot" wanders are refused,
    /// saying what to do.
    #[test]
    fn a_slide_or_a_wandering_pivot_is_refused() {
        let few: Vec<Isometry3<f64>> = (0..5).map(|_| Isometry3::identity()).collect();
        assert_eq!(pivot(&few), Err(PivotError::TooFew { found: 5 }));
        let slide: Vec<Isometry3<f64>> = (0..50)
            .map(|k| {
                pose(
                    UnitQuaternion::identity(),
                    Vector3::new(k as f64 * 0.01, 0.0, 0.0),
                )
            })
            .collect();
        assert!(matches!(
            pivot(&slide),
            Err(PivotError::TooLittleTurn { .. })
        ));
        // Turned about z only: the point is free along z.
        let spin: Vec<Isometry3<f64>> = (0..50)
            .map(|k| {
                let rot = UnitQuaternion::from_euler_angles(0.0, 0.0, k as f64 * 0.02);
                pose(rot, -(rot * Vector3::new(0.1, 0.0, 0.0)))
            })
            .collect();
        assert_eq!(pivot(&spin), Err(PivotError::OneAxis));
        // Turning about a point that moves 5 cm along y as it turns.
        let wander: Vec<Isometry3<f64>> = (0..50)
            .map(|k| {
                let a = k as f64 * 0.02;
                let rot = UnitQuaternion::from_euler_angles(0.5 * (5.0 * a).sin(), 0.0, a);
                let centre = Vector3::new(0.0, 0.05 * (k as f64 * 0.3).sin(), 0.0);
                pose(rot, centre - rot * Vector3::new(0.1, 0.0, 0.0))
            })
            .collect();
        let e = pivot(&wander).unwrap_err();
        assert!(matches!(e, PivotError::Moved { .. }), "{e}");
        assert!(e.to_string().contains("keep the pivot still"), "{e}");
    }
}
