//! GenICam industrial cameras (GigE Vision, USB3 Vision) through **Aravis** (`libaravis-0.8`,
//! the open GenICam implementation every Linux distribution packages), driven through its C API
//! loaded at run time: no build-time dependency (the `aravis` crate needs the library's
//! headers, pkg-config and GLib's at build), and a rig without a GenICam camera never loads it.
//! Debian: `apt install libaravis-0.8-0` (or `aravis-tools`, which brings it and the fake camera
//! the tests use).
//!
//! The camera is opened by its Aravis device id (`Vendor-Model-Serial`, as `arv-tool-0.8`
//! lists) or its address; its region is set to the rig's `image_size` (offset 0, 0), its pixel
//! format to `Mono8`, or `Mono10`, `Mono12`, `Mono16` (16-bit containers, read as 16-bit grey;
//! the packed formats are not read), acquisition continuous, and the frame rate, exposure time
//! and gain the rig gives, each first checked against the range the camera states (an error
//! names the feature and the range) and then set (an error names the camera's message).
//! Frames stream into eight Aravis buffers and are copied once, row for row, into the
//! shared-memory frame; a buffer the camera or the network left incomplete (missing packets)
//! is a bad frame, counted, and the stream goes on. A camera silent for two reads (2 s:
//! unplugged, restarted, its link down) is opened again as it was asked, on a thread of its own
//! so the capture service goes on reporting, and again after two more silent reads until it
//! answers; its fresh frame numbers continue the sequence, by the frame periods it was away.
//!
//! **Timestamps.** Each buffer carries the camera's timestamp (ns on its own clock, latched at
//! the start of exposure by GenICam's convention) and the host's time of its arrival. With
//! `timestamps = "mapped"` (the default) the camera's clock is moved onto the host's by the
//! smallest (arrival − camera stamp) of the last 256 frames — stamps are then late by the
//! link's shortest transfer — and with `"ptp"` it is taken as Unix time (a camera whose clock
//! PTP keeps on the host's). Half the exposure time is added: mid-exposure. The camera's frame
//! id (16 bits on GigE Vision, continued past its wrap) numbers the frame, so frames the camera
//! or the network lost are gaps the moment worker counts.

use crate::source::{BadFrame, FrameSource, Read, SourceError};
use std::ffi::{CStr, CString, c_char, c_double, c_int, c_uint, c_void};
use stereoscope_proto::frame::PixelFormat;

const MONO8: u32 = 0x0108_0001;
/// Mono10 and Mono12 unpacked: 16-bit little-endian containers, read as 16-bit grey.
const MONO10: u32 = 0x0110_0003;
const MONO12: u32 = 0x0110_0005;
const MONO16: u32 = 0x0110_0007;
/// `ARV_ACQUISITION_MODE_CONTINUOUS`.
const CONTINUOUS: c_int = 0;
/// Buffers the stream holds.
const BUFFERS: usize = 8;
/// How long a read waits for a frame, microseconds (short, so the capture service reports its
/// health while a camera is silent).
const POP_TIMEOUT_US: u64 = 1_000_000;
/// Frames over which the clock offset's minimum is taken.
const OFFSET_WINDOW: usize = 256;

/// How the camera's timestamps become the rig's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Clock {
    Mapped,
    Ptp,
}

/// The pixel formats read (the packed Mono10p/Mono12p are not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mono {
    Eight,
    Ten,
    Twelve,
    Sixteen,
}

impl Mono {
    fn code(self) -> u32 {
        match self {
            Mono::Eight => MONO8,
            Mono::Ten => MONO10,
            Mono::Twelve => MONO12,
            Mono::Sixteen => MONO16,
        }
    }
}

/// What the rig asks of a GenICam camera.
#[derive(Debug, Clone)]
pub struct GenicamRequest {
    pub camera: String,
    pub size_px: (u32, u32),
    pub format: Mono,
    pub fps: Option<f64>,
    pub exposure_us: Option<f64>,
    pub gain_db: Option<f64>,
    pub clock: Clock,
    /// The trigger to set; `None` leaves the camera's own setting.
    pub trigger: Option<Trigger>,
    /// The library to load (default `libaravis-0.8.so.0`).
    pub library: Option<String>,
}

/// How the camera's exposures are started.
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// Free-running: every trigger off (the camera exposes at its frame rate).
    Free,
    /// `TriggerSource` (a hardware line, `Line1`, or `Software`) for `FrameStart`, trigger
    /// mode on, on the rising edge where the camera has `TriggerActivation`. With `Software`
    /// the source fires the camera's `TriggerSoftware` once per period of the rig's `fps`.
    Source(String),
}

#[repr(C)]
struct GError {
    domain: u32,
    code: c_int,
    message: *const c_char,
}

type Err = *mut *mut GError;

/// The Aravis and GLib functions used.
struct Api {
    camera_new: unsafe extern "C" fn(*const c_char, Err) -> *mut c_void,
    set_pixel_format: unsafe extern "C" fn(*mut c_void, u32, Err),
    get_pixel_format: unsafe extern "C" fn(*mut c_void, Err) -> u32,
    set_region: unsafe extern "C" fn(*mut c_void, c_int, c_int, c_int, c_int, Err),
    get_region:
        unsafe extern "C" fn(*mut c_void, *mut c_int, *mut c_int, *mut c_int, *mut c_int, Err),
    set_frame_rate: unsafe extern "C" fn(*mut c_void, c_double, Err),
    frame_rate_bounds: unsafe extern "C" fn(*mut c_void, *mut c_double, *mut c_double, Err),
    exposure_bounds: unsafe extern "C" fn(*mut c_void, *mut c_double, *mut c_double, Err),
    gain_bounds: unsafe extern "C" fn(*mut c_void, *mut c_double, *mut c_double, Err),
    get_frame_rate: unsafe extern "C" fn(*mut c_void, Err) -> c_double,
    set_exposure: unsafe extern "C" fn(*mut c_void, c_double, Err),
    get_exposure: unsafe extern "C" fn(*mut c_void, Err) -> c_double,
    set_gain: unsafe extern "C" fn(*mut c_void, c_double, Err),
    trigger_sources: unsafe extern "C" fn(*mut c_void, *mut c_uint, Err) -> *mut *const c_char,
    set_trigger: unsafe extern "C" fn(*mut c_void, *const c_char, Err),
    clear_triggers: unsafe extern "C" fn(*mut c_void, Err),
    software_trigger: unsafe extern "C" fn(*mut c_void, Err),
    get_trigger_source: unsafe extern "C" fn(*mut c_void, Err) -> *const c_char,
    set_acquisition_mode: unsafe extern "C" fn(*mut c_void, c_int, Err),
    get_payload: unsafe extern "C" fn(*mut c_void, Err) -> c_uint,
    create_stream: unsafe extern "C" fn(*mut c_void, *mut c_void, *mut c_void, Err) -> *mut c_void,
    start: unsafe extern "C" fn(*mut c_void, Err),
    stop: unsafe extern "C" fn(*mut c_void, Err),
    buffer_new: unsafe extern "C" fn(usize, *mut c_void) -> *mut c_void,
    push: unsafe extern "C" fn(*mut c_void, *mut c_void),
    pop: unsafe extern "C" fn(*mut c_void, u64) -> *mut c_void,
    status: unsafe extern "C" fn(*mut c_void) -> c_int,
    data: unsafe extern "C" fn(*mut c_void, *mut usize) -> *const c_void,
    timestamp: unsafe extern "C" fn(*mut c_void) -> u64,
    system_timestamp: unsafe extern "C" fn(*mut c_void) -> u64,
    frame_id: unsafe extern "C" fn(*mut c_void) -> u64,
    unref: unsafe extern "C" fn(*mut c_void),
    error_free: unsafe extern "C" fn(*mut GError),
    g_free: unsafe extern "C" fn(*mut c_void),
    _gobject: libloading::Library,
    _glib: libloading::Library,
    _aravis: libloading::Library,
}

/// What failed in Aravis or in loading it.
#[derive(Debug, thiserror::Error)]
enum AravisError {
    #[error("{path} (install libaravis-0.8-0, or give the source's library)")]
    Load {
        path: String,
        #[source]
        source: libloading::Error,
    },
    #[error("{symbol} is not in the library")]
    Symbol {
        symbol: String,
        #[source]
        source: libloading::Error,
    },
    /// A `GError` Aravis set: its code and message.
    #[error("{message} (Aravis error {code})")]
    Camera { code: i32, message: String },
}

fn load(path: &str) -> Result<libloading::Library, AravisError> {
    // SAFETY: loading Aravis or GLib runs their initialisers, which set up their own state.
    unsafe { libloading::Library::new(path) }.map_err(|source| AravisError::Load {
        path: path.to_string(),
        source,
    })
}

impl Api {
    fn load(library: Option<&str>) -> Result<Api, AravisError> {
        let aravis = load(library.unwrap_or("libaravis-0.8.so.0"))?;
        let gobject = load("libgobject-2.0.so.0")?;
        let glib = load("libglib-2.0.so.0")?;
        macro_rules! sym {
            ($lib:expr, $name:literal) => {{
                // SAFETY: the symbol has the signature of the field it fills, as Aravis 0.8's
                // and GLib's headers declare it.
                *unsafe { $lib.get($name) }.map_err(|source| AravisError::Symbol {
                    symbol: String::from_utf8_lossy(&$name[..$name.len() - 1]).into_owned(),
                    source,
                })?
            }};
        }
        Ok(Api {
            camera_new: sym!(aravis, b"arv_camera_new\0"),
            set_pixel_format: sym!(aravis, b"arv_camera_set_pixel_format\0"),
            get_pixel_format: sym!(aravis, b"arv_camera_get_pixel_format\0"),
            set_region: sym!(aravis, b"arv_camera_set_region\0"),
            get_region: sym!(aravis, b"arv_camera_get_region\0"),
            set_frame_rate: sym!(aravis, b"arv_camera_set_frame_rate\0"),
            frame_rate_bounds: sym!(aravis, b"arv_camera_get_frame_rate_bounds\0"),
            exposure_bounds: sym!(aravis, b"arv_camera_get_exposure_time_bounds\0"),
            gain_bounds: sym!(aravis, b"arv_camera_get_gain_bounds\0"),
            get_frame_rate: sym!(aravis, b"arv_camera_get_frame_rate\0"),
            set_exposure: sym!(aravis, b"arv_camera_set_exposure_time\0"),
            get_exposure: sym!(aravis, b"arv_camera_get_exposure_time\0"),
            set_gain: sym!(aravis, b"arv_camera_set_gain\0"),
            trigger_sources: sym!(aravis, b"arv_camera_dup_available_trigger_sources\0"),
            set_trigger: sym!(aravis, b"arv_camera_set_trigger\0"),
            clear_triggers: sym!(aravis, b"arv_camera_clear_triggers\0"),
            software_trigger: sym!(aravis, b"arv_camera_software_trigger\0"),
            get_trigger_source: sym!(aravis, b"arv_camera_get_trigger_source\0"),
            set_acquisition_mode: sym!(aravis, b"arv_camera_set_acquisition_mode\0"),
            get_payload: sym!(aravis, b"arv_camera_get_payload\0"),
            create_stream: sym!(aravis, b"arv_camera_create_stream\0"),
            start: sym!(aravis, b"arv_camera_start_acquisition\0"),
            stop: sym!(aravis, b"arv_camera_stop_acquisition\0"),
            buffer_new: sym!(aravis, b"arv_buffer_new\0"),
            push: sym!(aravis, b"arv_stream_push_buffer\0"),
            pop: sym!(aravis, b"arv_stream_timeout_pop_buffer\0"),
            status: sym!(aravis, b"arv_buffer_get_status\0"),
            data: sym!(aravis, b"arv_buffer_get_data\0"),
            timestamp: sym!(aravis, b"arv_buffer_get_timestamp\0"),
            system_timestamp: sym!(aravis, b"arv_buffer_get_system_timestamp\0"),
            frame_id: sym!(aravis, b"arv_buffer_get_frame_id\0"),
            unref: sym!(gobject, b"g_object_unref\0"),
            error_free: sym!(glib, b"g_error_free\0"),
            g_free: sym!(glib, b"g_free\0"),
            _gobject: gobject,
            _glib: glib,
            _aravis: aravis,
        })
    }

    /// Runs `f` with a fresh `GError` slot; the error, if it set one.
    fn call<T>(&self, f: impl FnOnce(Err) -> T) -> Result<T, AravisError> {
        let mut e: *mut GError = std::ptr::null_mut();
        let v = f(&mut e);
        if e.is_null() {
            return Ok(v);
        }
        // SAFETY: Aravis set a GError: its message is a NUL-terminated string it owns until the
        // error is freed, right after it is copied.
        let error = unsafe {
            let message = if (*e).message.is_null() {
                "unknown error".to_string()
            } else {
                CStr::from_ptr((*e).message).to_string_lossy().into_owned()
            };
            let code = (*e).code;
            (self.error_free)(e);
            AravisError::Camera { code, message }
        };
        Err(error)
    }
}

/// The camera's frame id (16 bits on GigE Vision), continued past its wrap.
#[derive(Debug, Default)]
struct FrameIds {
    last: Option<u64>,
    wraps: u64,
}

impl FrameIds {
    fn extend(&mut self, id: u64) -> u64 {
        let modulus: u64 = if id <= u64::from(u16::MAX) {
            1 << 16
        } else {
            0
        };
        if let Some(last) = self.last
            && modulus > 0
            && id < last
            && last - id > modulus / 2
        {
            self.wraps += 1;
        }
        self.last = Some(id);
        self.wraps * modulus + id
    }
}

/// The camera clock → host clock offset: the smallest (arrival − stamp) over a window.
#[derive(Debug, Default)]
struct Offset {
    recent: std::collections::VecDeque<i128>,
}

impl Offset {
    fn update(&mut self, camera_ns: u64, arrival_ns: u64) -> i128 {
        if self.recent.len() == OFFSET_WINDOW {
            self.recent.pop_front();
        }
        self.recent
            .push_back(i128::from(arrival_ns) - i128::from(camera_ns));
        self.recent.iter().copied().min().unwrap_or(0)
    }
}

pub struct GenicamSource {
    api: Api,
    camera: *mut c_void,
    stream: *mut c_void,
    name: String,
    width: u32,
    height: u32,
    format: PixelFormat,
    fps: Option<f64>,
    exposure_us: Option<f64>,
    clock: Clock,
    /// The trigger set, in words (`None`: the camera's own setting, left alone).
    trigger: Option<String>,
    /// With a software trigger: the period and when the next trigger is due.
    software: Option<(std::time::Duration, std::time::Instant)>,
    ids: FrameIds,
    offset: Offset,
    acquiring: bool,
    /// What was asked, to open the camera again when it went away.
    req: GenicamRequest,
    /// Reads in a row that found no frame.
    silent: u32,
    /// After the camera was opened again: its frame numbers start afresh; the sequence goes on
    /// from the last one given (`None`: not yet rebased).
    last_sequence: Option<u64>,
    sequence_base: Option<i128>,
    /// The host's time of the last frame's arrival: the frames the camera made while it was
    /// away become a gap in the numbers.
    last_arrival_ns: Option<u64>,
    /// The camera being opened again on a thread of its own (opening and releasing a camera
    /// that is gone can block for seconds).
    reopening: Option<std::sync::mpsc::Receiver<Result<Box<GenicamSource>, SourceError>>>,
}

// SAFETY: the camera and stream objects are used only through this owner, from one thread at
// a time (the capture service's); Aravis's objects are not bound to the thread that made them.
unsafe impl Send for GenicamSource {}

impl std::fmt::Debug for GenicamSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GenicamSource({})", self.name)
    }
}

/// A GenICam error naming the camera and what was being done: Aravis's own (kept as the
/// source) or this source's words.
fn gerr(
    camera: &str,
    doing: &str,
    why: impl Into<Box<dyn std::error::Error + Send + Sync>>,
) -> SourceError {
    SourceError::io(camera, doing.to_string(), std::io::Error::other(why))
}

impl GenicamSource {
    pub fn open(req: &GenicamRequest) -> Result<GenicamSource, SourceError> {
        let name = req.camera.clone();
        let api =
            Api::load(req.library.as_deref()).map_err(|e| gerr(&name, "loading Aravis", e))?;
        let c_name = CString::new(name.as_str())
            .map_err(|_| gerr(&name, "opening", "the camera's name holds a NUL byte"))?;
        // SAFETY (this block and the calls below): Aravis's C API on a camera object it made,
        // every out-pointer a live local, every GError collected by `Api::call`.
        let camera = api
            .call(|e| unsafe { (api.camera_new)(c_name.as_ptr(), e) })
            .map_err(|m| gerr(&name, "opening", m))?;
        if camera.is_null() {
            return Err(gerr(&name, "opening", "no such camera"));
        }
        let mut s = GenicamSource {
            api,
            camera,
            stream: std::ptr::null_mut(),
            name: name.clone(),
            width: 0,
            height: 0,
            format: PixelFormat::Gray8,
            fps: None,
            exposure_us: None,
            clock: req.clock,
            trigger: None,
            software: None,
            ids: FrameIds::default(),
            offset: Offset::default(),
            acquiring: false,
            req: req.clone(),
            silent: 0,
            last_sequence: None,
            sequence_base: Some(0),
            last_arrival_ns: None,
            reopening: None,
        };
        let cam = s.camera;
        let api = &s.api;
        let fmt = req.format.code();
        api.call(|e| unsafe { (api.set_pixel_format)(cam, fmt, e) })
            .map_err(|m| gerr(&name, "setting PixelFormat", m))?;
        let (w, h) = req.size_px;
        api.call(|e| unsafe { (api.set_region)(cam, 0, 0, w as c_int, h as c_int, e) })
            .map_err(|m| gerr(&name, &format!("setting the region to {w}×{h}"), m))?;
        api.call(|e| unsafe { (api.set_acquisition_mode)(cam, CONTINUOUS, e) })
            .map_err(|m| gerr(&name, "setting AcquisitionMode Continuous", m))?;
        // Each value checked against the range the camera states before it is set.
        type Bounds = unsafe extern "C" fn(*mut c_void, *mut c_double, *mut c_double, Err);
        type Set = unsafe extern "C" fn(*mut c_void, c_double, Err);
        let settings: [(&str, &str, Option<f64>, Bounds, Set); 3] = [
            (
                "AcquisitionFrameRate",
                "fps",
                req.fps,
                api.frame_rate_bounds,
                api.set_frame_rate,
            ),
            (
                "ExposureTime",
                "µs",
                req.exposure_us,
                api.exposure_bounds,
                api.set_exposure,
            ),
            ("Gain", "", req.gain_db, api.gain_bounds, api.set_gain),
        ];
        for (feature, unit, value, bounds, set) in settings {
            let Some(v) = value else { continue };
            let (mut lo, mut hi) = (f64::NAN, f64::NAN);
            if api
                .call(|e| unsafe { bounds(cam, &mut lo, &mut hi, e) })
                .is_ok()
                && lo.is_finite()
                && hi.is_finite()
                && !(lo..=hi).contains(&v)
            {
                return Err(gerr(
                    &name,
                    &format!("setting {feature} {v} {unit}"),
                    format!("the camera allows {lo} to {hi} {unit}"),
                ));
            }
            api.call(|e| unsafe { set(cam, v, e) })
                .map_err(|m| gerr(&name, &format!("setting {feature} {v} {unit}"), m))?;
        }
        match &req.trigger {
            None => {}
            Some(Trigger::Free) => {
                api.call(|e| unsafe { (api.clear_triggers)(cam, e) })
                    .map_err(|m| gerr(&name, "turning the triggers off", m))?;
                s.trigger = Some("free-running".into());
            }
            Some(Trigger::Source(source)) => {
                let doing = format!("setting TriggerSource {source}");
                let sources = trigger_sources(api, cam).map_err(|m| gerr(&name, &doing, m))?;
                if !sources.iter().any(|s| s == source) {
                    return Err(gerr(
                        &name,
                        &doing,
                        format!(
                            "the camera's trigger sources are {}",
                            if sources.is_empty() {
                                "none".to_string()
                            } else {
                                sources.join(", ")
                            }
                        ),
                    ));
                }
                let c_source = CString::new(source.as_str())
                    .map_err(|_| gerr(&name, &doing, "a NUL byte in the name"))?;
                api.call(|e| unsafe { (api.set_trigger)(cam, c_source.as_ptr(), e) })
                    .map_err(|m| gerr(&name, &doing, m))?;
                // What the camera took.
                let got = api
                    .call(|e| unsafe { (api.get_trigger_source)(cam, e) })
                    .ok()
                    .filter(|p| !p.is_null())
                    .map(|p| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
                    .unwrap_or_default();
                if &got != source {
                    return Err(gerr(
                        &name,
                        &doing,
                        format!("the camera reads back TriggerSource {got:?}"),
                    ));
                }
                if source == "Software" {
                    let Some(fps) = req.fps else {
                        return Err(gerr(
                            &name,
                            &doing,
                            "a software trigger needs the source's fps (how often to fire it)",
                        ));
                    };
                    let period = std::time::Duration::from_secs_f64(1.0 / fps);
                    s.software = Some((period, std::time::Instant::now()));
                    s.trigger = Some(format!("software trigger at {fps} fps"));
                } else {
                    s.trigger = Some(format!("triggered by {source}"));
                }
            }
        }
        // What the camera took.
        let (mut x, mut y, mut cw, mut ch) = (0, 0, 0, 0);
        api.call(|e| unsafe { (api.get_region)(cam, &mut x, &mut y, &mut cw, &mut ch, e) })
            .map_err(|m| gerr(&name, "reading the region", m))?;
        let got = api
            .call(|e| unsafe { (api.get_pixel_format)(cam, e) })
            .map_err(|m| gerr(&name, "reading PixelFormat", m))?;
        let format = match got {
            MONO8 => PixelFormat::Gray8,
            MONO10 | MONO12 | MONO16 => PixelFormat::Gray16,
            other => {
                return Err(gerr(
                    &name,
                    "reading PixelFormat",
                    format!(
                        "the camera gives format 0x{other:08x}, not Mono8, Mono10, Mono12 or Mono16"
                    ),
                ));
            }
        };
        let fps = api
            .call(|e| unsafe { (api.get_frame_rate)(cam, e) })
            .ok()
            .filter(|f| f.is_finite() && *f > 0.0);
        let exposure_us = api
            .call(|e| unsafe { (api.get_exposure)(cam, e) })
            .ok()
            .filter(|x| x.is_finite() && *x > 0.0);
        let payload = api
            .call(|e| unsafe { (api.get_payload)(cam, e) })
            .map_err(|m| gerr(&name, "reading the payload size", m))?;
        let stream = api
            .call(|e| unsafe {
                (api.create_stream)(cam, std::ptr::null_mut(), std::ptr::null_mut(), e)
            })
            .map_err(|m| gerr(&name, "creating the stream", m))?;
        if stream.is_null() {
            return Err(gerr(&name, "creating the stream", "no stream"));
        }
        for _ in 0..BUFFERS {
            unsafe {
                let b = (api.buffer_new)(payload as usize, std::ptr::null_mut());
                (api.push)(stream, b);
            }
        }
        api.call(|e| unsafe { (api.start)(cam, e) })
            .map_err(|m| gerr(&name, "starting acquisition", m))?;
        s.stream = stream;
        s.acquiring = true;
        s.width = cw.max(0) as u32;
        s.height = ch.max(0) as u32;
        s.format = format;
        s.fps = fps;
        s.exposure_us = exposure_us;
        Ok(s)
    }
}

/// The trigger sources the camera lists.
fn trigger_sources(api: &Api, cam: *mut c_void) -> Result<Vec<String>, AravisError> {
    let mut n: c_uint = 0;
    // SAFETY: Aravis returns an array of `n` strings that its feature nodes own (valid while
    // the camera lives) in a container the caller frees with g_free, after they are copied.
    unsafe {
        let list = api.call(|e| (api.trigger_sources)(cam, &mut n, e))?;
        if list.is_null() {
            return Ok(Vec::new());
        }
        let names = (0..n as usize)
            .map(|i| *list.add(i))
            .filter(|p| !p.is_null())
            .map(|p| CStr::from_ptr(p).to_string_lossy().into_owned())
            .collect();
        (api.g_free)(list as *mut c_void);
        Ok(names)
    }
}

impl GenicamSource {
    /// Opens the camera again, as it was asked, on a thread of its own.
    fn reopen(&mut self) {
        let (tx, rx) = std::sync::mpsc::channel();
        let req = self.req.clone();
        std::thread::spawn(move || {
            let r = GenicamSource::open(&req).map(Box::new);
            let _ = tx.send(r);
        });
        self.reopening = Some(rx);
    }
}

impl Drop for GenicamSource {
    fn drop(&mut self) {
        let api = &self.api;
        // SAFETY: stopping and releasing the objects this source made, once.
        unsafe {
            if self.acquiring {
                let _ = api.call(|e| (api.stop)(self.camera, e));
            }
            if !self.stream.is_null() {
                (api.unref)(self.stream);
            }
            (api.unref)(self.camera);
        }
    }
}

/// `ArvBufferStatus` names, for the log.
fn status_name(s: c_int) -> &'static str {
    match s {
        1 => "cleared",
        2 => "timeout",
        3 => "missing packets",
        4 => "wrong packet id",
        5 => "size mismatch",
        6 => "filling",
        7 => "aborted",
        8 => "payload not supported",
        _ => "unknown status",
    }
}

impl FrameSource for GenicamSource {
    fn describe(&self) -> String {
        format!(
            "genicam {} {:?} {}×{}{}{}{}, timestamps {}",
            self.name,
            self.format,
            self.width,
            self.height,
            self.fps.map(|f| format!(" {f} fps")).unwrap_or_default(),
            self.exposure_us
                .map(|x| format!(", exposure {x} µs"))
                .unwrap_or_default(),
            self.trigger
                .as_deref()
                .map(|t| format!(", {t}"))
                .unwrap_or_default(),
            match self.clock {
                Clock::Mapped => "mapped from the camera's clock at mid-exposure",
                Clock::Ptp => "the camera's (PTP) at mid-exposure",
            }
        )
    }

    fn format(&self) -> PixelFormat {
        self.format
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn fps(&self) -> Option<f64> {
        self.fps
    }

    fn realtime(&self) -> bool {
        false
    }

    fn read(&mut self, _i: u64, _t: f64, out: &mut [u8]) -> Result<Read, SourceError> {
        if let Some(rx) = &self.reopening {
            let waited = rx.recv_timeout(std::time::Duration::from_millis(500));
            let gone = |m: String| {
                Err(BadFrame::Camera {
                    device: self.name.clone(),
                    source: m.into(),
                }
                .into())
            };
            match waited {
                Ok(Ok(fresh)) => {
                    let (last, arrival) = (self.last_sequence, self.last_arrival_ns);
                    let old = std::mem::replace(self, *fresh);
                    self.last_sequence = last;
                    self.last_arrival_ns = arrival;
                    self.sequence_base = None;
                    // Releasing the lost camera can block: not on the capture's thread.
                    std::thread::spawn(move || drop(old));
                }
                Ok(Err(e)) => {
                    self.reopening = None;
                    self.silent = 0;
                    // The error and its causes, as the capture's log shows a chain.
                    let mut why = e.to_string();
                    let mut cause = std::error::Error::source(&e);
                    while let Some(c) = cause {
                        why = format!("{why}: {c}");
                        cause = c.source();
                    }
                    return gone(format!("opening the camera again: {why}"));
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    return gone("opening the camera again".into());
                }
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                    self.reopening = None;
                    return gone("opening the camera again failed".into());
                }
            }
        }
        if let Some((period, due)) = &mut self.software {
            // One trigger per period, on the host's clock; a read that fell behind by more
            // than a period starts the beat again rather than firing a burst.
            let now = std::time::Instant::now();
            if *due > now {
                std::thread::sleep(*due - now);
            }
            let now = std::time::Instant::now();
            *due = if now.duration_since(*due) > *period {
                now + *period
            } else {
                *due + *period
            };
            let api = &self.api;
            let cam = self.camera;
            // SAFETY: a command on this source's camera.
            api.call(|e| unsafe { (api.software_trigger)(cam, e) })
                .map_err(|e| BadFrame::Camera {
                    device: self.name.clone(),
                    source: format!("firing TriggerSoftware: {e}").into(),
                })?;
        }
        let api = &self.api;
        // SAFETY: popping, reading and pushing back buffers of this source's stream; the data
        // pointer is valid for `size` bytes until the buffer is pushed back, after the copy.
        unsafe {
            let b = (api.pop)(self.stream, POP_TIMEOUT_US);
            if b.is_null() {
                self.silent += 1;
                if self.silent >= 2 && self.reopening.is_none() {
                    self.reopen();
                }
                let waiting = match &self.req.trigger {
                    Some(Trigger::Source(line)) if line != "Software" => {
                        format!(" (it waits for its trigger on {line})")
                    }
                    _ => String::new(),
                };
                return Err(BadFrame::Camera {
                    device: self.name.clone(),
                    source: format!(
                        "no frame within {} s{waiting}; opening the camera again",
                        POP_TIMEOUT_US / 1_000_000
                    )
                    .into(),
                }
                .into());
            }
            self.silent = 0;
            let status = (api.status)(b);
            let id = self.ids.extend((api.frame_id)(b));
            let camera_ns = (api.timestamp)(b);
            let arrival_ns = (api.system_timestamp)(b);
            let result = if status != 0 {
                Err(format!("frame {id}: {}", status_name(status)))
            } else {
                let mut size = 0usize;
                let data = (api.data)(b, &mut size) as *const u8;
                let need = out.len();
                if data.is_null() || size < need {
                    Err(format!("frame {id}: {size} bytes, {need} expected"))
                } else {
                    out.copy_from_slice(std::slice::from_raw_parts(data, need));
                    Ok(())
                }
            };
            (api.push)(self.stream, b);
            result.map_err(|m| BadFrame::Camera {
                device: self.name.clone(),
                source: m.into(),
            })?;
            let start_ns = match self.clock {
                Clock::Ptp => i128::from(camera_ns),
                Clock::Mapped => i128::from(camera_ns) + self.offset.update(camera_ns, arrival_ns),
            };
            let half = self.exposure_us.map_or(0.0, |us| us * 500.0) as i128;
            // After a reopen the camera numbers afresh: continue from the last number given,
            // by the frame periods it was away.
            let (last, last_arrival, fps) = (self.last_sequence, self.last_arrival_ns, self.fps);
            let base = *self.sequence_base.get_or_insert_with(|| {
                i128::from(crate::source::number_after(
                    last,
                    last_arrival,
                    Some(arrival_ns),
                    fps,
                )) - i128::from(id)
            });
            let sequence = u64::try_from(i128::from(id) + base).unwrap_or(id);
            self.last_sequence = Some(sequence);
            self.last_arrival_ns = Some(arrival_ns);
            Ok(Read::Frame {
                timestamp_ns: u64::try_from(start_ns + half).ok(),
                sequence: Some(sequence),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ids_continue_past_the_16_bit_wrap() {
        let mut f = FrameIds::default();
        assert_eq!(f.extend(65534), 65534);
        assert_eq!(f.extend(65535), 65535);
        assert_eq!(f.extend(1), 65537);
        // A 64-bit id (USB3 Vision) is taken as it is.
        let mut g = FrameIds::default();
        assert_eq!(g.extend(1 << 40), 1 << 40);
    }

    #[test]
    fn the_offset_is_the_smallest_transfer_seen() {
        let mut o = Offset::default();
        assert_eq!(o.update(1_000, 6_000), 5_000);
        assert_eq!(o.update(2_000, 6_500), 4_500);
        assert_eq!(o.update(3_000, 9_000), 4_500);
    }

    #[test]
    fn a_missing_library_is_named() {
        let e = GenicamSource::open(&GenicamRequest {
            camera: "Aravis-Fake-GV01".into(),
            size_px: (512, 512),
            format: Mono::Eight,
            fps: None,
            exposure_us: None,
            gain_db: None,
            clock: Clock::Mapped,
            trigger: None,
            library: Some("/nonexistent/libaravis.so".into()),
        })
        .unwrap_err();
        let m = format!("{e:#}");
        assert!(m.contains("Aravis-Fake-GV01"), "{m}");
    }
}
