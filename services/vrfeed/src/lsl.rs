//! A Lab Streaming Layer outlet (`docs/lab-protocols.md`, "LSL"): one stream per rig, so LSL
//! recorders (LabRecorder) and analysis align motion with EEG, EMG and eye tracking on one clock.
//! It drives **liblsl itself** (the reference implementation, its C API) loaded at run time:
//! building liblsl from source (the `lsl` crate's route) would cost the 15-minute CI more than it
//! has, and the library is a runtime dependency of every LSL program anyway — pylsl's wheel, the
//! LSL releases' packages and conda all carry it.
//!
//! *Stream.* Name `Stereoscope <rig>`, type `MoCap`, seven `double64` channels per body
//! (`<body>_X`, `_Y`, `_Z` in metres, `_QX`, `_QY`, `_QZ`, `_QW`), described in the stream's
//! `desc/channels` (label, type `PositionX` … `OrientationW`, unit) as the XDF MoCap meta-data
//! asks; the nominal rate is the rig's; the source id is stable across restarts
//! (`stereoscope/<rig>` by default), so recorders reconnect by themselves. A body not measured
//! in a frame is NaN in its channels.
//!
//! *Time.* Each sample is stamped with its exposure on LSL's clock (`lsl_local_clock`): the
//! exposure's Unix time less the offset between the system clock and LSL's, read when the
//! sample goes out (the closest-read of three readings); inlets then correct for the clock offset between PCs as LSL does.

use crate::output::{Counts, Output, OutputFrame};
use nalgebra::Point3;
use std::ffi::{CString, c_char, c_double, c_int, c_void};
use stereoscope_rig::vr::{ConsumerFrame, LslSettings};

/// `cft_double64` in liblsl's `lsl_channel_format_t`.
const CFT_DOUBLE64: c_int = 2;
/// Channels per body.
pub const CHANNELS_PER_BODY: usize = 7;
const SUFFIXES: [(&str, &str, &str); 7] = [
    ("X", "PositionX", "metres"),
    ("Y", "PositionY", "metres"),
    ("Z", "PositionZ", "metres"),
    ("QX", "OrientationX", "quaternion"),
    ("QY", "OrientationY", "quaternion"),
    ("QZ", "OrientationZ", "quaternion"),
    ("QW", "OrientationW", "quaternion"),
];

type CreateInfo = unsafe extern "C" fn(
    *const c_char,
    *const c_char,
    i32,
    c_double,
    c_int,
    *const c_char,
) -> *mut c_void;
type GetDesc = unsafe extern "C" fn(*mut c_void) -> *mut c_void;
type AppendChild = unsafe extern "C" fn(*mut c_void, *const c_char) -> *mut c_void;
type AppendChildValue =
    unsafe extern "C" fn(*mut c_void, *const c_char, *const c_char) -> *mut c_void;
type CreateOutlet = unsafe extern "C" fn(*mut c_void, i32, i32) -> *mut c_void;
type PushSample = unsafe extern "C" fn(*mut c_void, *const c_double, c_double, i32) -> i32;
type LocalClock = unsafe extern "C" fn() -> c_double;
type Destroy = unsafe extern "C" fn(*mut c_void);
type HaveConsumers = unsafe extern "C" fn(*mut c_void) -> i32;

/// The liblsl functions used, resolved from the loaded library.
struct Api {
    push: PushSample,
    clock: LocalClock,
    destroy_outlet: Destroy,
    have_consumers: HaveConsumers,
    // Last: the functions above point into it.
    _lib: libloading::Library,
}

/// Channel labels of `names`' bodies, in order.
pub fn channel_labels(names: &[String]) -> Vec<String> {
    names
        .iter()
        .flat_map(|n| SUFFIXES.iter().map(move |(s, _, _)| format!("{n}_{s}")))
        .collect()
}

/// One frame's sample: each body's position (output frame and unit) and quaternion, NaN for a
/// body not measured in it.
pub fn sample(f: &OutputFrame, bodies: usize, frame: &ConsumerFrame) -> Vec<f64> {
    let mut v = vec![f64::NAN; bodies * CHANNELS_PER_BODY];
    for o in f.bodies.iter().filter(|o| o.tracked && o.index < bodies) {
        let p = frame.position(&Point3::from(o.world_from_body.translation.vector));
        let q = frame.rotation(&o.world_from_body.rotation);
        v[o.index * CHANNELS_PER_BODY..(o.index + 1) * CHANNELS_PER_BODY]
            .copy_from_slice(&[p.x, p.y, p.z, q.i, q.j, q.k, q.w]);
    }
    v
}

/// The outlet.
pub struct LslOutlet {
    api: Api,
    outlet: *mut c_void,
    bodies: usize,
    frame: ConsumerFrame,
    counts: Counts,
}

// SAFETY: liblsl's outlets are thread-safe (its documentation: "push" may be called from any
// thread); the pointer is only used through this owner.
unsafe impl Send for LslOutlet {}

impl std::fmt::Debug for LslOutlet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LslOutlet({} bodies)", self.bodies)
    }
}

fn other(m: String) -> std::io::Error {
    std::io::Error::other(m)
}

fn cstring(s: &str, what: &str) -> std::io::Result<CString> {
    CString::new(s).map_err(|_| other(format!("LSL: {what} {s:?} holds a NUL byte")))
}

impl LslOutlet {
    /// Loads liblsl (the rig's `library`, else `liblsl.so.2` then `liblsl.so` on the
    /// system's library path) and opens the outlet.
    pub fn open(
        cfg: &LslSettings,
        rig: &str,
        names: &[String],
        fps: f64,
    ) -> std::io::Result<LslOutlet> {
        let candidates: Vec<String> = match &cfg.library {
            Some(p) => vec![p.clone()],
            None => vec!["liblsl.so.2".into(), "liblsl.so".into()],
        };
        let mut last = String::new();
        let mut lib = None;
        for c in &candidates {
            // SAFETY: loading liblsl runs its initialisers, which only set up its own state.
            match unsafe { libloading::Library::new(c) } {
                Ok(l) => {
                    lib = Some(l);
                    break;
                }
                Err(e) => last = format!("{c}: {e}"),
            }
        }
        let lib = lib.ok_or_else(|| {
            other(format!(
                "LSL: liblsl not found ({last}); install it (pylsl's wheel, an LSL release) or give [vr] lsl.library"
            ))
        })?;
        macro_rules! sym {
            ($name:literal, $ty:ty) => {{
                // SAFETY: the symbol has this C signature in liblsl's lsl_c.h (1.13 and later).
                let s: libloading::Symbol<$ty> = unsafe { lib.get($name) }
                    .map_err(|e| other(format!("LSL: {}: {e}", String::from_utf8_lossy($name))))?;
                *s
            }};
        }
        let create_info = sym!(b"lsl_create_streaminfo\0", CreateInfo);
        let get_desc = sym!(b"lsl_get_desc\0", GetDesc);
        let append_child = sym!(b"lsl_append_child\0", AppendChild);
        let append_value = sym!(b"lsl_append_child_value\0", AppendChildValue);
        let create_outlet = sym!(b"lsl_create_outlet\0", CreateOutlet);
        let destroy_info = sym!(b"lsl_destroy_streaminfo\0", Destroy);
        let api = Api {
            push: sym!(b"lsl_push_sample_dtp\0", PushSample),
            clock: sym!(b"lsl_local_clock\0", LocalClock),
            destroy_outlet: sym!(b"lsl_destroy_outlet\0", Destroy),
            have_consumers: sym!(b"lsl_have_consumers\0", HaveConsumers),
            _lib: lib,
        };
        let name = cstring(&format!("Stereoscope {rig}"), "stream name")?;
        let kind = cstring("MoCap", "type")?;
        let source = cstring(
            &cfg.source_id
                .clone()
                .unwrap_or(format!("stereoscope/{rig}")),
            "source id",
        )?;
        let channels = (names.len() * CHANNELS_PER_BODY) as i32;
        // SAFETY: liblsl's C API with valid NUL-terminated strings; every handle it returns is
        // checked before use, the stream info destroyed once the outlet holds its copy.
        unsafe {
            let info = create_info(
                name.as_ptr(),
                kind.as_ptr(),
                channels,
                fps.max(0.0),
                CFT_DOUBLE64,
                source.as_ptr(),
            );
            if info.is_null() {
                return Err(other("LSL: lsl_create_streaminfo failed".into()));
            }
            let desc = get_desc(info);
            let tag = |s: &str| CString::new(s).unwrap_or_default();
            let chans = append_child(desc, tag("channels").as_ptr());
            for (label, (_, ty, unit)) in channel_labels(names).iter().zip(SUFFIXES.iter().cycle())
            {
                let ch = append_child(chans, tag("channel").as_ptr());
                append_value(ch, tag("label").as_ptr(), tag(label).as_ptr());
                append_value(ch, tag("type").as_ptr(), tag(ty).as_ptr());
                append_value(ch, tag("unit").as_ptr(), tag(unit).as_ptr());
            }
            let acq = append_child(desc, tag("acquisition").as_ptr());
            append_value(
                acq,
                tag("manufacturer").as_ptr(),
                tag("Stereoscope").as_ptr(),
            );
            // One sample per chunk, buffered for 10 s of a slow consumer.
            let outlet = create_outlet(info, 1, 10);
            destroy_info(info);
            if outlet.is_null() {
                return Err(other("LSL: lsl_create_outlet failed".into()));
            }
            Ok(LslOutlet {
                api,
                outlet,
                bodies: names.len(),
                frame: cfg.frame,
                counts: Counts::default(),
            })
        }
    }

    /// The system clock less LSL's, seconds: of three readings of the pair, the one read
    /// closest together (a preemption between the two reads would put the stamp off by it).
    fn clock_offset_s(&self) -> f64 {
        (0..3)
            .map(|_| {
                let a = stereoscope_proto::messages::now_ns() as f64 * 1e-9;
                // SAFETY: liblsl's clock, no arguments.
                let lsl = unsafe { (self.api.clock)() };
                let b = stereoscope_proto::messages::now_ns() as f64 * 1e-9;
                (b - a, (a + b) / 2.0 - lsl)
            })
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .map_or(0.0, |(_, offset)| offset)
    }
}

impl Drop for LslOutlet {
    fn drop(&mut self) {
        // SAFETY: the outlet was created by this library and is destroyed once.
        unsafe { (self.api.destroy_outlet)(self.outlet) }
    }
}

impl Output for LslOutlet {
    fn name(&self) -> &'static str {
        "lsl"
    }

    fn poll(&mut self) {}

    fn send(&mut self, f: &OutputFrame) {
        let v = sample(f, self.bodies, &self.frame);
        let stamp = f.exposure_ns as f64 * 1e-9 - self.clock_offset_s();
        // SAFETY: liblsl's push with a buffer of the outlet's channel count.
        let r = unsafe { (self.api.push)(self.outlet, v.as_ptr(), stamp, 1) };
        if r != 0 {
            self.counts
                .send_error(format!("LSL: lsl_push_sample_dtp returned {r}"));
        }
        self.counts.frames += 1;
    }

    fn counts(&mut self) -> &mut Counts {
        &mut self.counts
    }

    fn clients(&self) -> Option<usize> {
        // SAFETY: a query on a live outlet.
        let n = unsafe { (self.api.have_consumers)(self.outlet) };
        Some(usize::from(n > 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::OutputBody;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn samples_hold_seven_channels_a_body_and_nan_when_unmeasured() {
        let names = vec!["head".to_string(), "wand".to_string()];
        assert_eq!(channel_labels(&names)[7], "wand_X");
        assert_eq!(channel_labels(&names).len(), 14);
        let b = [OutputBody {
            index: 1,
            world_from_body: Isometry3::from_parts(
                Translation3::new(0.1, 0.2, 0.3),
                UnitQuaternion::identity(),
            ),
            residual_mm: 0.0,
            tracked: true,
            velocity_m_per_s: [0.0; 3],
            angular_velocity_rad_per_s: [0.0; 3],
        }];
        let f = OutputFrame {
            sequence: 1,
            exposure_ns: 0,
            received_ns: 0,
            bodies: &b,
            markers: &[],
            models: &[],
        };
        let s = sample(&f, 2, &ConsumerFrame::identity());
        assert!(s[..7].iter().all(|v| v.is_nan()));
        assert_eq!(&s[7..], &[0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn a_missing_library_is_named() {
        let cfg = LslSettings {
            library: Some("/nonexistent/liblsl.so".into()),
            source_id: None,
            frame: ConsumerFrame::identity(),
        };
        let e = LslOutlet::open(&cfg, "demo", &["head".into()], 30.0).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/liblsl.so"), "{e}");
    }
}
