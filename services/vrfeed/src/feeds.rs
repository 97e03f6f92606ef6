//! The UDP feeds (`docs/vr.md`): OSC to VirtualMotionTracker and to VMC receivers, and
//! opentrack's "UDP over network" packet. Each is one datagram per body per pose frame, sent
//! and forgotten: a receiver that is not there costs a counted send error, nothing more.

use nalgebra::{Point3, UnitQuaternion};
use rosc::{OscMessage, OscPacket, OscType};
use stereoscope_rig::vr::ConsumerFrame;

/// A pose in a consumer's frame: position in its unit, rotation as x, y, z, w.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConsumerPose {
    pub position: [f64; 3],
    pub quat_xyzw: [f64; 4],
}

/// `world_from_body` in the consumer's frame.
pub fn in_frame(
    frame: &ConsumerFrame,
    position_m: &Point3<f64>,
    rotation: &UnitQuaternion<f64>,
) -> ConsumerPose {
    let p = frame.position(position_m);
    let q = frame.rotation(rotation);
    ConsumerPose {
        position: [p.x, p.y, p.z],
        quat_xyzw: [q.i, q.j, q.k, q.w],
    }
}

fn osc(addr: &str, args: Vec<OscType>) -> Vec<u8> {
    // Encoding a message into a vector cannot fail (rosc writes into memory).
    rosc::encoder::encode(&OscPacket::Message(OscMessage {
        addr: addr.to_string(),
        args,
    }))
    .unwrap_or_default()
}

/// VMT's `/VMT/Room/Driver`: index, enable (1: a tracker), time offset (s), x, y, z,
/// qx, qy, qz, qw — the pose in OpenVR's room space (y up, metres).
pub fn vmt_room_driver(index: i32, pose: &ConsumerPose) -> Vec<u8> {
    let mut args = vec![OscType::Int(index), OscType::Int(1), OscType::Float(0.0)];
    args.extend(
        pose.position
            .iter()
            .chain(&pose.quat_xyzw)
            .map(|v| OscType::Float(*v as f32)),
    );
    osc("/VMT/Room/Driver", args)
}

/// VMC's `/VMC/Ext/Tra/Pos`: the tracker's serial (the body's name), x, y, z, qx, qy, qz, qw
/// in Unity's frame (y up, left-handed, metres).
pub fn vmc_tracker(serial: &str, pose: &ConsumerPose) -> Vec<u8> {
    let mut args = vec![OscType::String(serial.to_string())];
    args.extend(
        pose.position
            .iter()
            .chain(&pose.quat_xyzw)
            .map(|v| OscType::Float(*v as f32)),
    );
    osc("/VMC/Ext/Tra/Pos", args)
}

/// Yaw, pitch and roll (degrees) of a rotation in a y-up frame, `R = Ry(yaw)·Rx(pitch)·Rz(roll)`:
/// yaw about the vertical, pitch about the lateral axis, roll about the forward one — the
/// order a head tracker reports.
pub fn yaw_pitch_roll_deg(q: &UnitQuaternion<f64>) -> [f64; 3] {
    let m = q.to_rotation_matrix();
    let r = m.matrix();
    // R = Ry·Rx·Rz: r12 = −sin(pitch); r02 = sin(yaw)cos(pitch); r22 = cos(yaw)cos(pitch);
    // r10 = cos(pitch)sin(roll); r11 = cos(pitch)cos(roll).
    let pitch = (-r[(1, 2)]).clamp(-1.0, 1.0).asin();
    let yaw = r[(0, 2)].atan2(r[(2, 2)]);
    let roll = r[(1, 0)].atan2(r[(1, 1)]);
    [yaw.to_degrees(), pitch.to_degrees(), roll.to_degrees()]
}

/// opentrack's 48-byte packet: x, y, z (the frame's unit, centimetres by default), yaw, pitch,
/// roll (degrees), six little-endian f64.
pub fn opentrack(pose: &ConsumerPose) -> [u8; 48] {
    let [x, y, z, w] = pose.quat_xyzw;
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
    let [yaw, pitch, roll] = yaw_pitch_roll_deg(&q);
    let mut out = [0u8; 48];
    for (i, v) in pose.position.iter().chain(&[yaw, pitch, roll]).enumerate() {
        out[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn yaw_pitch_roll_round_trip() {
        for &(y, p, r) in &[(30.0, 10.0, -5.0), (-170.0, -45.0, 80.0), (0.0, 0.0, 0.0)] {
            let q = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), f64::to_radians(y))
                * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), f64::to_radians(p))
                * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), f64::to_radians(r));
            let got = yaw_pitch_roll_deg(&q);
            for (a, b) in got.iter().zip([y, p, r]) {
                assert!((a - b).abs() < 1e-9, "{got:?} vs {y} {p} {r}");
            }
        }
    }

    #[test]
    fn packets_have_the_documented_layout() {
        let pose = ConsumerPose {
            position: [1.5, -2.0, 30.0],
            quat_xyzw: [0.0, 0.0, 0.0, 1.0],
        };
        let b = opentrack(&pose);
        assert_eq!(&b[0..8], &1.5f64.to_le_bytes());
        assert_eq!(&b[16..24], &30.0f64.to_le_bytes());
        for k in 3..6 {
            let v = f64::from_le_bytes(b[8 * k..8 * k + 8].try_into().unwrap());
            assert_eq!(v, 0.0);
        }
        let m = vmt_room_driver(2, &pose);
        assert!(m.starts_with(b"/VMT/Room/Driver\0\0\0\0,iiffffffff\0"));
        let m = vmc_tracker("head", &pose);
        assert!(m.starts_with(b"/VMC/Ext/Tra/Pos\0\0\0\0,sfffffff\0\0\0head\0\0\0\0"));
    }
}
