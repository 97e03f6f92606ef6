//! The QTM RT protocol's bytes (`docs/lab-protocols.md`, "Qualisys RT"): packet framing, the
//! data components a frame is sent as, and the parameters' XML in the layout of the version a
//! client asked for. The server that speaks them is [`super::QualisysServer`].

use super::QualisysConfig;
use crate::output::{BodyDef, OutputFrame};
use nalgebra::{Point3, Rotation3};
use stereoscope_rig::vr::ConsumerFrame;

pub const PACKET_ERROR: u32 = 0;
pub const PACKET_COMMAND: u32 = 1;
pub const PACKET_XML: u32 = 2;
pub const PACKET_DATA: u32 = 3;
pub const PACKET_NO_MORE_DATA: u32 = 4;
pub const PACKET_EVENT: u32 = 6;
/// `EventConnected`: QTM is connected to its cameras and live.
pub const EVENT_CONNECTED: u8 = 1;

/// Component ids in data packets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Component {
    ThreeD = 1,
    ThreeDNoLabels = 2,
    SixD = 5,
    SixDEuler = 6,
    ThreeDRes = 9,
    ThreeDNoLabelsRes = 10,
    SixDRes = 11,
    SixDEulerRes = 12,
}

impl Component {
    pub fn parse(name: &str) -> Option<Component> {
        Some(match name.to_ascii_lowercase().as_str() {
            "3d" => Component::ThreeD,
            "3dnolabels" => Component::ThreeDNoLabels,
            "6d" => Component::SixD,
            "6deuler" => Component::SixDEuler,
            "3dres" => Component::ThreeDRes,
            "3dnolabelsres" => Component::ThreeDNoLabelsRes,
            "6dres" => Component::SixDRes,
            "6deulerres" => Component::SixDEulerRes,
            _ => return None,
        })
    }
}

/// A packet: size, type, body.
pub fn packet(kind: u32, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(8 + body.len());
    out.extend_from_slice(&((8 + body.len()) as u32).to_le_bytes());
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(body);
    out
}

/// A command, XML or error packet: the text and a NUL.
pub fn text_packet(kind: u32, text: &str) -> Vec<u8> {
    let mut b = text.as_bytes().to_vec();
    b.push(0);
    packet(kind, &b)
}

/// Euler angles (degrees) of a rotation, QTM's default convention: `R = Rx(a)·Ry(b)·Rz(c)`,
/// rotations about the body's own axes taken in the order x, y, z; `b` in [−90°, 90°].
pub fn euler_xyz_deg(r: &Rotation3<f64>) -> [f64; 3] {
    let m = r.matrix();
    // R = Rx·Ry·Rz: r02 = sin b; r12 = −sin a cos b; r22 = cos a cos b;
    // r01 = −cos b sin c; r00 = cos b cos c.
    let b = m[(0, 2)].clamp(-1.0, 1.0).asin();
    let a = (-m[(1, 2)]).atan2(m[(2, 2)]);
    let c = (-m[(0, 1)]).atan2(m[(0, 0)]);
    [a.to_degrees(), b.to_degrees(), c.to_degrees()]
}

/// One frame's data packet body with the components asked for.
pub fn data_body(
    f: &OutputFrame,
    bodies: &[BodyDef],
    frame: &ConsumerFrame,
    components: &[Component],
) -> Vec<u8> {
    let mut out = Vec::with_capacity(512);
    out.extend_from_slice(&((f.exposure_ns / 1000) as i64).to_le_bytes());
    out.extend_from_slice(&(f.sequence as u32).to_le_bytes());
    out.extend_from_slice(&(components.len() as u32).to_le_bytes());
    let put = |c: &mut Vec<u8>, v: f64| c.extend_from_slice(&(v as f32).to_le_bytes());
    for &kind in components {
        let mut c = Vec::new();
        let residual = matches!(
            kind,
            Component::ThreeDRes
                | Component::ThreeDNoLabelsRes
                | Component::SixDRes
                | Component::SixDEulerRes
        );
        match kind {
            Component::ThreeD | Component::ThreeDRes => {
                let n: usize = bodies.iter().map(|b| b.markers_m.len()).sum();
                header(&mut c, n);
                for (i, b) in bodies.iter().enumerate() {
                    for k in 0..b.markers_m.len() {
                        let m = f.markers.iter().find(|m| m.label == Some((i, k as u32)));
                        match m {
                            Some(m) => {
                                for v in frame.position(&m.position_m).iter() {
                                    put(&mut c, *v);
                                }
                                if residual {
                                    put(&mut c, 0.0);
                                }
                            }
                            None => {
                                for _ in 0..(3 + usize::from(residual)) {
                                    put(&mut c, f64::NAN);
                                }
                            }
                        }
                    }
                }
            }
            Component::ThreeDNoLabels | Component::ThreeDNoLabelsRes => {
                let loose: Vec<_> = f.markers.iter().filter(|m| m.label.is_none()).collect();
                header(&mut c, loose.len());
                for m in loose {
                    for v in frame.position(&m.position_m).iter() {
                        put(&mut c, *v);
                    }
                    c.extend_from_slice(&m.object_id.to_le_bytes());
                    if residual {
                        put(&mut c, 0.0);
                    }
                }
            }
            Component::SixD
            | Component::SixDRes
            | Component::SixDEuler
            | Component::SixDEulerRes => {
                let euler = matches!(kind, Component::SixDEuler | Component::SixDEulerRes);
                header(&mut c, bodies.len());
                for i in 0..bodies.len() {
                    let o = f.bodies.iter().find(|o| o.index == i && o.tracked);
                    let values: Vec<f64> = match o {
                        None => vec![f64::NAN; if euler { 6 } else { 12 }],
                        Some(o) => {
                            let p =
                                frame.position(&Point3::from(o.world_from_body.translation.vector));
                            let r = frame
                                .rotation(&o.world_from_body.rotation)
                                .to_rotation_matrix();
                            let mut v = vec![p.x, p.y, p.z];
                            if euler {
                                v.extend(euler_xyz_deg(&r));
                            } else {
                                // Column by column.
                                v.extend(r.matrix().iter().copied());
                            }
                            v
                        }
                    };
                    for v in values {
                        put(&mut c, v);
                    }
                    if residual {
                        let r = o.map_or(f64::NAN, |o| o.residual_mm * 1e-3 * frame.units_per_m);
                        put(&mut c, r);
                    }
                }
            }
        }
        out.extend_from_slice(&((8 + c.len()) as u32).to_le_bytes());
        out.extend_from_slice(&(kind as u32).to_le_bytes());
        out.extend_from_slice(&c);
    }
    out
}

/// A component's header: count, 2D drop rate, out-of-sync rate (both 0: no frame was lost
/// that the feed knows of).
fn header(c: &mut Vec<u8>, count: usize) {
    c.extend_from_slice(&(count as u32).to_le_bytes());
    c.extend_from_slice(&0u16.to_le_bytes());
    c.extend_from_slice(&0u16.to_le_bytes());
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// `GetParameters`' XML for the sections asked for, in the layout of protocol 1.`minor`.
pub fn parameters_xml(
    sections: &[&str],
    minor: u32,
    bodies: &[BodyDef],
    cfg: &QualisysConfig,
) -> String {
    use std::fmt::Write as _;
    let want = |s: &str| {
        sections
            .iter()
            .any(|x| x.eq_ignore_ascii_case(s) || x.eq_ignore_ascii_case("all"))
    };
    let mut x = format!("<QTM_Parameters_Ver_1.{minor}>");
    let point = |m: &Point3<f64>| cfg.frame.consumer_from_world * m.coords * cfg.frame.units_per_m;
    if want("general") {
        let _ = write!(
            x,
            "<General><Frequency>{}</Frequency><Capture_Time>0</Capture_Time>\
             <Start_On_External_Trigger>false</Start_On_External_Trigger>\
             <Start_On_Trigger_NO>false</Start_On_Trigger_NO><Start_On_Trigger_NC>false</Start_On_Trigger_NC>\
             <Start_On_Trigger_Software>false</Start_On_Trigger_Software></General>",
            cfg.frequency_hz.round()
        );
    }
    if want("3d") {
        let n: usize = bodies.iter().map(|b| b.markers_m.len()).sum();
        let _ = write!(
            x,
            "<The_3D><AxisUpwards>+Z</AxisUpwards><CalibrationTime></CalibrationTime><Labels>{n}</Labels>"
        );
        for b in bodies {
            for k in 0..b.markers_m.len() {
                let name = xml_escape(&crate::natnet::marker_name(&b.name, k));
                let _ = write!(
                    x,
                    "<Label><Name>{name}</Name><RGBColor>65280</RGBColor><Trajectory_Type>Measured</Trajectory_Type></Label>"
                );
            }
        }
        x.push_str("<Bones></Bones></The_3D>");
    }
    if want("6d") {
        x.push_str("<The_6D>");
        if minor <= 20 {
            let _ = write!(x, "<Bodies>{}</Bodies>", bodies.len());
        }
        for b in bodies {
            let name = xml_escape(&b.name);
            if minor <= 20 {
                let _ = write!(x, "<Body><Name>{name}</Name><RGBColor>255</RGBColor>");
                for m in &b.markers_m {
                    let v = point(m);
                    let _ = write!(
                        x,
                        "<Point><X>{}</X><Y>{}</Y><Z>{}</Z></Point>",
                        v.x, v.y, v.z
                    );
                }
                x.push_str("</Body>");
            } else {
                let _ = write!(
                    x,
                    "<Body><Name>{name}</Name><Enabled>true</Enabled><Color R=\"255\" G=\"0\" B=\"0\"/>\
                     <MaximumResidual>10</MaximumResidual><MinimumMarkersInBody>3</MinimumMarkersInBody>\
                     <BoneLengthTolerance>5</BoneLengthTolerance><Filter Preset=\"No filter\"/><Points>"
                );
                for (k, m) in b.markers_m.iter().enumerate() {
                    let v = point(m);
                    let pname = xml_escape(&crate::natnet::marker_name(&b.name, k));
                    let _ = write!(
                        x,
                        "<Point X=\"{}\" Y=\"{}\" Z=\"{}\" Virtual=\"0\" PhysicalId=\"0\" Name=\"{pname}\"/>",
                        v.x, v.y, v.z
                    );
                }
                x.push_str(
                    "</Points><Data_origin X=\"0\" Y=\"0\" Z=\"0\" Relative_body=\"0\">0</Data_origin>\
                     <Data_orientation R11=\"1\" R12=\"0\" R13=\"0\" R21=\"0\" R22=\"1\" R23=\"0\" R31=\"0\" R32=\"0\" R33=\"1\" Relative_body=\"0\">0</Data_orientation></Body>",
                );
            }
        }
        x.push_str("<Euler><First>X</First><Second>Y</Second><Third>Z</Third></Euler></The_6D>");
    }
    let _ = write!(x, "</QTM_Parameters_Ver_1.{minor}>");
    x
}
