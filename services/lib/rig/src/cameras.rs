//! A rig file's cameras turned into calibrated cameras (thesis Ch. 2, Eq. 2.2–2.8: intrinsics,
//! the pose from §2.3.1's position/look-at/up construction or explicit extrinsics; depth from
//! area, Eq. 4.15–4.27), every value checked and every problem named by its key
//! (`docs/rig.md`). Internally everything is in metres (SI); the file's `units` say what its
//! numbers mean.

use crate::error::{RigError, err};
use crate::schema::{
    AreaModelKind, CameraSpec, DepthFromAreaSpec, DistortionSpec, PoseSpec, RigFile, Units,
};
use nalgebra::{Matrix3, Point3, Vector3};
use stereoscope_geometry::camera::{Camera, Distortion, Intrinsics};
use stereoscope_geometry::depth::AreaModel;
use stereoscope_geometry::transform::{isometry_from_parts, look_at};

/// A single-camera depth model, in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthFromArea {
    pub model: AreaModel,
    pub range_m: (f64, f64),
}

/// One camera of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct RigCamera {
    pub id: String,
    pub camera: Camera,
    pub depth_from_area: Option<DepthFromArea>,
}

fn finite3(key: &str, v: [f64; 3]) -> Result<Vector3<f64>, RigError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(Vector3::new(v[0], v[1], v[2]))
    } else {
        Err(err(key, format!("{v:?} must be finite numbers")))
    }
}

fn intrinsics(spec: &CameraSpec, key: &str) -> Result<Intrinsics, RigError> {
    let [w, h] = spec.image_size;
    if w == 0 || h == 0 {
        return Err(err(
            format!("{key}.image_size"),
            format!("[{w}, {h}] must be at least 1 × 1"),
        ));
    }
    let pp = spec.principal_point.map(|p| (p[0], p[1]));
    let by_pixels = spec.fx.is_some() || spec.fy.is_some();
    let by_lens = spec.focal_length_mm.is_some() || spec.pixel_pitch_um.is_some();
    let map = |e: stereoscope_geometry::GeometryError| match e {
        stereoscope_geometry::GeometryError::InvalidCamera {
            field,
            value,
            reason,
        } => err(format!("{key}.{field}"), format!("{value} {reason}")),
        other => err(key, other.to_string()),
    };
    match (by_pixels, by_lens) {
        (true, true) => Err(err(
            key,
            "give either fx and fy, or focal_length_mm and pixel_pitch_um, not both",
        )),
        (false, false) => Err(err(
            key,
            "missing intrinsics: give fx and fy, or focal_length_mm and pixel_pitch_um",
        )),
        (true, false) => {
            let fx = spec
                .fx
                .ok_or_else(|| err(format!("{key}.fx"), "missing (fy is given)"))?;
            let fy = spec
                .fy
                .ok_or_else(|| err(format!("{key}.fy"), "missing (fx is given)"))?;
            let (cx, cy) = pp.unwrap_or(((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0));
            Intrinsics::new(fx, fy, cx, cy, w, h).map_err(map)
        }
        (false, true) => {
            let f = spec.focal_length_mm.ok_or_else(|| {
                err(
                    format!("{key}.focal_length_mm"),
                    "missing (pixel_pitch_um is given)",
                )
            })?;
            let p = spec.pixel_pitch_um.ok_or_else(|| {
                err(
                    format!("{key}.pixel_pitch_um"),
                    "missing (focal_length_mm is given)",
                )
            })?;
            // Same unit for both: micrometres.
            Intrinsics::from_focal_length(f * 1000.0, p[0], p[1], w, h, pp).map_err(|e| match e {
                stereoscope_geometry::GeometryError::InvalidCamera {
                    field: "focal_length",
                    value,
                    reason,
                } => err(
                    format!("{key}.focal_length_mm"),
                    format!("{} {reason}", value / 1000.0),
                ),
                stereoscope_geometry::GeometryError::InvalidCamera {
                    field: "pixel_width",
                    value,
                    reason,
                } => err(
                    format!("{key}.pixel_pitch_um[0]"),
                    format!("{value} {reason}"),
                ),
                stereoscope_geometry::GeometryError::InvalidCamera {
                    field: "pixel_height",
                    value,
                    reason,
                } => err(
                    format!("{key}.pixel_pitch_um[1]"),
                    format!("{value} {reason}"),
                ),
                other => map(other),
            })
        }
    }
}

fn pose(spec: &PoseSpec, key: &str, scale: f64) -> Result<nalgebra::Isometry3<f64>, RigError> {
    let look = spec.position.is_some() || spec.look_at.is_some() || spec.up.is_some();
    let explicit =
        spec.cam_from_world_rotation.is_some() || spec.cam_from_world_translation.is_some();
    let key = format!("{key}.pose");
    match (look, explicit) {
        (true, true) => Err(err(
            &key,
            "give either position/look_at/up or cam_from_world_rotation/cam_from_world_translation, not both",
        )),
        (false, false) => Err(err(
            &key,
            "missing: give position, look_at and up, or cam_from_world_rotation and cam_from_world_translation",
        )),
        (true, false) => {
            let need = |v: Option<[f64; 3]>, name: &str| {
                v.ok_or_else(|| err(format!("{key}.{name}"), "missing"))
            };
            let p = finite3(&format!("{key}.position"), need(spec.position, "position")?)? * scale;
            let t = finite3(&format!("{key}.look_at"), need(spec.look_at, "look_at")?)? * scale;
            let up = finite3(&format!("{key}.up"), need(spec.up, "up")?)?;
            look_at(Point3::from(p), Point3::from(t), up)
                .map(|w| w.inverse())
                .map_err(|e| err(&key, e.to_string()))
        }
        (false, true) => {
            let r = spec
                .cam_from_world_rotation
                .ok_or_else(|| err(format!("{key}.cam_from_world_rotation"), "missing"))?;
            let t = spec
                .cam_from_world_translation
                .ok_or_else(|| err(format!("{key}.cam_from_world_translation"), "missing"))?;
            let m = Matrix3::from_fn(|i, j| r[i][j]);
            let t = finite3(&format!("{key}.cam_from_world_translation"), t)? * scale;
            isometry_from_parts(m, t, 1e-6)
                .map_err(|e| err(format!("{key}.cam_from_world_rotation"), e.to_string()))
        }
    }
}

fn distortion(spec: &Option<DistortionSpec>, key: &str) -> Result<Distortion, RigError> {
    let d = spec.unwrap_or_default();
    let dist = Distortion {
        k1: d.k1,
        k2: d.k2,
        k3: d.k3,
        p1: d.p1,
        p2: d.p2,
    };
    dist.validate().map_err(|e| match e {
        stereoscope_geometry::GeometryError::InvalidCamera {
            field,
            value,
            reason,
        } => err(
            format!("{key}.distortion.{field}"),
            format!("{value} {reason}"),
        ),
        other => err(key, other.to_string()),
    })?;
    Ok(dist)
}

fn depth_model(spec: &DepthFromAreaSpec, key: &str, scale: f64) -> Result<DepthFromArea, RigError> {
    let key = format!("{key}.depth_from_area");
    let [near, far] = spec.range;
    if !(near.is_finite() && far.is_finite() && near > 0.0 && far > near) {
        return Err(err(
            format!("{key}.range"),
            format!("[{near}, {far}] must be two distances with 0 < near < far"),
        ));
    }
    for (name, v) in [("a", spec.a), ("b", spec.b)] {
        if !v.is_finite() {
            return Err(err(format!("{key}.{name}"), format!("{v} must be finite")));
        }
    }
    if spec.a <= 0.0 {
        return Err(err(
            format!("{key}.a"),
            format!("{} must be above zero (areas are positive)", spec.a),
        ));
    }
    // D_file = D_m / s: a/(D_f² + b·D_f + c) = a·s²/(D_m² + b·s·D_m + c·s²).
    let model = match spec.model {
        AreaModelKind::TwoParameter => {
            if spec.c.is_some() {
                return Err(err(format!("{key}.c"), "the two-parameter model has no c"));
            }
            AreaModel::TwoParameter {
                a: spec.a * scale * scale,
                b: spec.b * scale,
            }
        }
        AreaModelKind::ThreeParameter => {
            let c = spec.c.ok_or_else(|| {
                err(
                    format!("{key}.c"),
                    "missing (the three-parameter model needs a, b and c)",
                )
            })?;
            if !c.is_finite() {
                return Err(err(format!("{key}.c"), format!("{c} must be finite")));
            }
            AreaModel::ThreeParameter {
                a: spec.a * scale * scale,
                b: spec.b * scale,
                c: c * scale * scale,
            }
        }
    };
    Ok(DepthFromArea {
        model,
        range_m: (near * scale, far * scale),
    })
}

/// Builds every camera of a parsed rig file, in metres.
pub(crate) fn build_cameras(file: &RigFile) -> Result<Vec<RigCamera>, RigError> {
    let scale = file.units.metres();
    if file.cameras.is_empty() {
        return Err(err("camera", "the rig has no [[camera]] tables"));
    }
    let mut cameras = Vec::with_capacity(file.cameras.len());
    for (i, spec) in file.cameras.iter().enumerate() {
        let key = format!("camera[{i}] (id {:?})", spec.id);
        if spec.id.trim().is_empty() {
            return Err(err(format!("camera[{i}].id"), "must not be empty"));
        }
        if file.cameras[..i].iter().any(|c| c.id == spec.id) {
            return Err(err(
                format!("camera[{i}].id"),
                format!("{:?} is used by an earlier camera", spec.id),
            ));
        }
        let intr = intrinsics(spec, &key)?;
        let dist = distortion(&spec.distortion, &key)?;
        let cam_from_world = pose(&spec.pose, &key, scale)?;
        let camera =
            Camera::new(intr, dist, cam_from_world).map_err(|e| err(&key, e.to_string()))?;
        let depth_from_area = spec
            .depth_from_area
            .as_ref()
            .map(|d| depth_model(d, &key, scale))
            .transpose()?;
        cameras.push(RigCamera {
            id: spec.id.clone(),
            camera,
            depth_from_area,
        });
    }
    Ok(cameras)
}

/// A camera as a rig-file table, positions in `units`.
pub fn camera_spec(id: &str, camera: &Camera, units: Units) -> CameraSpec {
    let scale = units.metres();
    let r = camera.cam_from_world.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = camera.cam_from_world.translation.vector / scale;
    let d = camera.distortion;
    CameraSpec {
        id: id.to_string(),
        image_size: [camera.intrinsics.width, camera.intrinsics.height],
        fx: Some(camera.intrinsics.fx),
        fy: Some(camera.intrinsics.fy),
        focal_length_mm: None,
        pixel_pitch_um: None,
        principal_point: Some([camera.intrinsics.cx, camera.intrinsics.cy]),
        distortion: (!d.is_zero()).then_some(DistortionSpec {
            k1: d.k1,
            k2: d.k2,
            k3: d.k3,
            p1: d.p1,
            p2: d.p2,
        }),
        pose: PoseSpec {
            cam_from_world_rotation: Some([
                [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
                [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
                [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
            ]),
            cam_from_world_translation: Some([t.x, t.y, t.z]),
            ..Default::default()
        },
        depth_from_area: None,
        host: None,
        source: None,
        moments: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Rig;

    /// The thesis's lab (docs/rig.md): two cameras 20 cm apart on a 280 cm ceiling, camera 1
    /// 2.5 cm lower, 12.5 mm lenses, 320 × 240, PAR 0.86.
    pub const THESIS_LAB: &str = include_str!("../../../../deploy/rigs/thesis-lab.toml");

    #[test]
    fn the_thesis_lab_rig_loads_in_metres() {
        let rig = Rig::from_toml(THESIS_LAB).unwrap();
        assert_eq!(rig.cameras.len(), 2);
        let c0 = &rig.cameras[0].camera;
        assert!((c0.intrinsics.par() - 0.86).abs() < 1e-9);
        assert!((c0.position_world().z - 2.80).abs() < 1e-9);
        let c1 = &rig.cameras[1].camera;
        assert!((c1.position_world().x - c0.position_world().x - 0.20).abs() < 1e-9);
        assert!((c0.position_world().z - c1.position_world().z - 0.025).abs() < 1e-9);
        let depth = rig.cameras[0].depth_from_area.unwrap();
        assert!((depth.range_m.0 - 0.75).abs() < 1e-12);
        // A point on the floor below camera 0 images at its principal point.
        let p = c0
            .project(&Point3::new(
                c0.position_world().x,
                c0.position_world().y,
                0.0,
            ))
            .unwrap();
        assert!((p.x - 159.5).abs() < 1e-9 && (p.y - 119.5).abs() < 1e-9);
    }

    #[test]
    fn bad_values_are_named_by_key() {
        let e = |text: String| Rig::from_toml(&text).unwrap_err().to_string();
        assert!(
            e(THESIS_LAB.replace("focal_length_mm = 12.5", "focal_length_mm = -12.5"))
                .contains("camera[0] (id \"cam0\").focal_length_mm: -12.5")
        );
        let units = e(THESIS_LAB.replace("units = \"cm\"", "units = \"inch\""));
        assert!(units.contains("units") && units.contains("inch"), "{units}");
        assert!(
            e(THESIS_LAB.replace("focal_length_mm = 12.5", "focal_lenght_mm = 12.5"))
                .contains("focal_lenght_mm")
        );
        assert!(e(THESIS_LAB.replace("id = \"cam1\"", "id = \"cam0\"")).contains("camera[1].id"));
        let rotated = THESIS_LAB.replace(
            "pose = { position = [10.0, 0.0, 277.5], look_at = [10.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }",
            "pose = { cam_from_world_rotation = [[1.0, 0.2, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], cam_from_world_translation = [0.0, 0.0, 280.0] }",
        );
        assert!(e(rotated).contains("cam_from_world_rotation: not a rotation"));
        let up_along_ray = THESIS_LAB.replace(
            "look_at = [10.0, 0.0, 0.0], up = [0.0, 1.0, 0.0]",
            "look_at = [10.0, 0.0, 0.0], up = [0.0, 0.0, 1.0]",
        );
        assert!(e(up_along_ray).contains("UP vector is parallel"));
        assert!(
            e(THESIS_LAB.replace("range = [75.0, 275.0]", "range = [275.0, 75.0]"))
                .contains("depth_from_area.range")
        );
        let model = e(THESIS_LAB.replace("model = \"three_parameter\"", "model = \"cubic\""));
        assert!(
            model.contains("cubic") && model.contains("three_parameter"),
            "{model}"
        );
    }

    #[test]
    fn mutated_rig_files_never_panic() {
        let mut rng = stereoscope_numeric::SplitMix64::new(5);
        let bytes = THESIS_LAB.as_bytes();
        let alphabet = b"0123456789-.e[]{}=,\"abcxyz \n";
        for _ in 0..2000 {
            let mut b = bytes.to_vec();
            for _ in 0..1 + rng.next_u64() % 3 {
                let i = (rng.next_u64() % b.len() as u64) as usize;
                b[i] = alphabet[(rng.next_u64() % alphabet.len() as u64) as usize];
            }
            if let Ok(text) = std::str::from_utf8(&b) {
                let _ = Rig::from_toml(text);
            }
        }
    }

    #[test]
    fn calibrated_camera_round_trips_through_a_rig_table() {
        let rig = Rig::from_toml(THESIS_LAB).unwrap();
        let cam = rig.cameras[1].camera;
        let spec = camera_spec("cam1", &cam, Units::Centimetres);
        let file = RigFile {
            name: "x".into(),
            units: Units::Centimetres,
            cameras: vec![spec],
            hosts: Vec::new(),
            fusion: None,
            synthetic: None,
            serial: Vec::new(),
            recorder: None,
            insecure: false,
            bodies: Vec::new(),
            models: Vec::new(),
            vr: None,
            viewer: None,
            realtime: None,
        };
        let back = Rig::from_toml(&file.to_toml().unwrap()).unwrap();
        let b = back.cameras[0].camera;
        assert!(
            (b.cam_from_world.to_homogeneous() - cam.cam_from_world.to_homogeneous())
                .abs()
                .max()
                < 1e-12
        );
        assert_eq!(b.intrinsics, cam.intrinsics);
    }
}
