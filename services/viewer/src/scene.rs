//! What the page draws that does not move: each camera as its centre and the four corners of
//! its image at a display depth (a frustum), the bodies' definitions, each model's links and
//! their parents (the chain it draws), and the volume the cameras span — computed here from
//! the rig, so the page does no camera geometry.

use nalgebra::{Point2, Point3};
use serde_json::{Value, json};
use stereoscope_rig::Rig;

fn point(p: &Point3<f64>) -> Value {
    json!([p.x, p.y, p.z])
}

/// The rig as the page reads it (`GET /api/rig`), every length in metres in the world frame.
pub fn rig_json(rig: &Rig) -> Value {
    let centres: Vec<Point3<f64>> = rig
        .cameras
        .iter()
        .map(|c| c.camera.position_world())
        .collect();
    // The volume from the floor (z = 0) up to the cameras.
    let (mut lo, mut hi) = (Point3::origin(), Point3::origin());
    for c in &centres {
        lo = lo.inf(c);
        hi = hi.sup(c);
    }
    // Frustums drawn a sixth of the rig's span deep: visible, not crossing the volume.
    let span = (hi - lo).norm();
    let depth_m = (span / 6.0).clamp(0.05, 1.0);
    let cameras: Vec<Value> = rig
        .cameras
        .iter()
        .zip(&centres)
        .map(|(c, centre)| {
            let k = &c.camera.intrinsics;
            let world_from_cam = c.camera.cam_from_world.inverse();
            let (w, h) = (k.width as f64, k.height as f64);
            let corners: Vec<Value> = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
                .iter()
                .map(|&(u, v)| {
                    let n = k.to_normalised(Point2::new(u, v));
                    point(&(world_from_cam * Point3::new(n.x * depth_m, n.y * depth_m, depth_m)))
                })
                .collect();
            json!({
                "id": c.id,
                "width_px": k.width,
                "height_px": k.height,
                "centre_m": point(centre),
                "frustum_m": corners,
            })
        })
        .collect();
    let m = rig.metres_per_unit();
    let bodies: Vec<Value> = rig
        .spec
        .bodies
        .iter()
        .map(|b| {
            let markers: Vec<Value> = b
                .markers
                .iter()
                .map(|p| json!([p[0] * m, p[1] * m, p[2] * m]))
                .collect();
            json!({"name": b.name, "markers_m": markers})
        })
        .collect();
    // Each model's links with their parent link (the joint's), for drawing the chain.
    let models: Vec<Value> = rig
        .models
        .iter()
        .map(|rm| {
            let m = &rm.model;
            let links: Vec<Value> = m
                .links
                .iter()
                .map(|l| {
                    let parent = l.joint.and_then(|j| m.joints.get(j)).map(|j| j.parent);
                    json!({"name": l.name, "parent": parent})
                })
                .collect();
            json!({"name": m.name, "links": links})
        })
        .collect();
    json!({
        "rig": rig.name,
        "cameras": cameras,
        "bodies": bodies,
        "models": models,
        "extent_m": {"min": point(&lo), "max": point(&hi)},
        "frustum_depth_m": depth_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model's links go to the page with their parents: the root none, every other link
    /// its joint's parent.
    #[test]
    fn a_models_links_come_with_their_parents() {
        let urdf = concat!(env!("CARGO_MANIFEST_DIR"), "/../../deploy/models/arm6.urdf");
        let text = include_str!("../../../deploy/rigs/robot-arm.toml")
            .replace("\"../models/arm6.urdf\"", &format!("{urdf:?}"));
        let rig = Rig::from_toml(&text).unwrap();
        let v = rig_json(&rig);
        let links = v["models"][0]["links"].as_array().unwrap();
        let m = &rig.models[0].model;
        assert_eq!(links.len(), m.links.len());
        assert_eq!(links[0]["parent"], Value::Null);
        for (i, l) in links.iter().enumerate().skip(1) {
            let p = l["parent"].as_u64().unwrap() as usize;
            assert!(p < i, "{l}");
            let j = m.links[i].joint.unwrap();
            assert_eq!(m.joints[j].parent, p);
            assert_eq!(l["name"], m.links[i].name.as_str());
        }
    }

    /// A frustum's corners are the image corners seen at the display depth: projected back,
    /// they land on the corners, and the centre is the camera's.
    #[test]
    fn frustum_corners_project_to_the_image_corners() {
        let rig = Rig::from_toml(include_str!("../../../deploy/rigs/demo.toml")).unwrap();
        let v = rig_json(&rig);
        let cams = v["cameras"].as_array().unwrap();
        assert_eq!(cams.len(), rig.cameras.len());
        for (c, rc) in cams.iter().zip(&rig.cameras) {
            let k = &rc.camera.intrinsics;
            let want = [(0.0, 0.0), (k.width as f64, 0.0)];
            for (corner, (u, v)) in c["frustum_m"].as_array().unwrap().iter().zip(want) {
                let p: Vec<f64> = corner
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|x| x.as_f64().unwrap())
                    .collect();
                let px = rc
                    .camera
                    .project_cam(&(rc.camera.cam_from_world * Point3::new(p[0], p[1], p[2])))
                    .unwrap();
                // Distortion is left out of the drawing: within a few pixels at the corner.
                assert!(
                    (px.x - u).abs() < 5.0 && (px.y - v).abs() < 5.0,
                    "{px} {u} {v}"
                );
            }
            let centre = rc.camera.position_world();
            assert!((c["centre_m"][0].as_f64().unwrap() - centre.x).abs() < 1e-9);
        }
    }
}
