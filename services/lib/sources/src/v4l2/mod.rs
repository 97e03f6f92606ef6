//! V4L2 cameras, in every build on Linux (no bindgen, no libclang: the kernel interface is
//! written out in `sys.rs`). Memory-mapped streaming with four buffers; GREY and Y16 frames are
//! copied row by row into the frame buffer, YUYV gives its luma bytes, MJPEG is decoded to grey.
//! The frame size is the rig's `image_size`, asked of the driver; exposure and gain through the
//! standard controls; the frame rate through the capture parameters.
//!
//! **Timestamps.** A frame's `timestamp_ns` is its mid-exposure on the rig's clock (the
//! system's real-time clock, as every service stamps): the driver's buffer timestamp (on
//! `CLOCK_MONOTONIC`) is moved onto the real-time clock by the two clocks' offset, read once
//! when the stream starts (a later step of the real-time clock, by NTP or by hand, is not
//! followed: restart the capture), then to mid-exposure — half the exposure later when the driver stamps the start of
//! exposure, half earlier when it stamps the end of the frame (most drivers, UVC included;
//! V4L2 does not know the sensor's readout time). The exposure is the
//! camera's `exposure_time_absolute` when it has one, else unknown, and then the stamp stays
//! the driver's; the rig's `readout_us` (from the end of exposure to the end-of-frame stamp)
//! is subtracted from an end-of-frame stamp when given. A driver that does not stamp on the monotonic clock is stamped at dequeue.
//! [`V4lSource::describe`] says which applies. The driver's sequence number numbers the frame,
//! so frames the driver dropped are counted by the moment worker as gaps.
//!
//! **A camera that goes away** (unplugged, its driver reset: the device answers `ENODEV` or
//! `EIO`) or gives no frame for 2 s is closed at once and opened again as it was asked, once a
//! second, on a thread of its own; meanwhile each read is a bad frame naming why, and frames
//! then resume in the same process, their numbers going on ([`V4lSource`]).

mod controls;
mod convert;
mod stamps;
pub(crate) mod sys;

pub use convert::{ConvertError, Wire, convert, wire_of};

use crate::source::{BadFrame, FormatProblem, FrameSource, Read, SourceError};
use controls::{control_value, list_controls};
use stamps::{Sequence, Stamp, clock_ns, clock_offset_ns, mid_exposure_ns};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use stereoscope_proto::frame::PixelFormat;
use stereoscope_rig::schema::ControlValue;

/// What the rig asks of a V4L2 camera.
#[derive(Debug, Clone, Default)]
pub struct V4lRequest<'a> {
    /// "GREY", "Y16", "YUYV" or "MJPG"; the first of those the camera offers if absent.
    pub format: Option<&'a str>,
    /// The frame size (the rig's `image_size`); the driver's current size if absent.
    pub size_px: Option<(u32, u32)>,
    pub fps: Option<f64>,
    /// Exposure, 100 µs units (V4L2's `exposure_time_absolute`); manual exposure when given.
    pub exposure: Option<i64>,
    pub gain: Option<i64>,
    /// Other controls by name (see [`stereoscope_rig::schema::ControlValue`]).
    pub controls: Vec<(&'a str, &'a ControlValue)>,
    /// From the end of exposure to an end-of-frame stamp, ns (the sensor's readout, which
    /// V4L2 does not report: the rig gives it).
    pub readout_ns: Option<u64>,
}

struct Mapped {
    ptr: *mut libc::c_void,
    len: usize,
}

// SAFETY: the mapping is owned by the source and only read through `&mut self`.
unsafe impl Send for Mapped {}

impl Drop for Mapped {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` are a mapping this source made and nothing else unmaps.
        unsafe {
            libc::munmap(self.ptr, self.len);
        }
    }
}

/// One open, streaming device.
struct Stream {
    device: String,
    card: String,
    // Declared before `fd`: unmapped before the device is closed.
    buffers: Vec<Mapped>,
    fd: OwnedFd,
    wire: Wire,
    width: u32,
    height: u32,
    stride: usize,
    fps: Option<f64>,
    exposure_ns: Option<u64>,
    readout_ns: Option<u64>,
    stamp: Option<Stamp>,
    /// The real-time clock minus the monotonic one, read once when the stream started.
    realtime_minus_monotonic_ns: i128,
    sequence: Sequence,
    streaming: bool,
}

/// A V4L2 camera as the capture service reads it: its stream, opened again when the device
/// goes away (unplugged, its driver reset) or stops giving frames for 2 s — closed at once
/// (the device can come back only when nothing holds it open), then opened as it was asked
/// once a second on a thread of its own, so the service goes on reporting; frames then resume
/// in the same process, their numbers going on from the last.
pub struct V4lSource {
    device: String,
    asked: Asked,
    stream: Option<Stream>,
    /// What the first stream gave (a stream opened again as asked gives the same).
    format: PixelFormat,
    size: (u32, u32),
    fps: Option<f64>,
    described: String,
    reopening: Option<std::sync::mpsc::Receiver<Stream>>,
    /// The last frame number given, and what to add to a reopened stream's numbers.
    last_sequence: Option<u64>,
    sequence_base: Option<i128>,
    /// The last frame's time: the frames the camera made while it was away become a gap.
    last_ns: Option<u64>,
    /// Held while the source lives: a reopening thread stops when it is gone.
    alive: std::sync::Arc<()>,
}

/// A [`V4lRequest`] kept, to open the device again.
#[derive(Debug, Clone)]
struct Asked {
    format: Option<String>,
    size_px: Option<(u32, u32)>,
    fps: Option<f64>,
    exposure: Option<i64>,
    gain: Option<i64>,
    controls: Vec<(String, ControlValue)>,
    readout_ns: Option<u64>,
}

impl Asked {
    fn of(want: &V4lRequest) -> Asked {
        Asked {
            format: want.format.map(str::to_string),
            size_px: want.size_px,
            fps: want.fps,
            exposure: want.exposure,
            gain: want.gain,
            controls: want
                .controls
                .iter()
                .map(|(k, v)| (k.to_string(), (*v).clone()))
                .collect(),
            readout_ns: want.readout_ns,
        }
    }

    fn request(&self) -> V4lRequest<'_> {
        V4lRequest {
            format: self.format.as_deref(),
            size_px: self.size_px,
            fps: self.fps,
            exposure: self.exposure,
            gain: self.gain,
            controls: self.controls.iter().map(|(k, v)| (k.as_str(), v)).collect(),
            readout_ns: self.readout_ns,
        }
    }
}

/// Whether a read's failure means the device went away or stopped (open it again) rather
/// than a fault of this build or rig.
fn gone(e: &SourceError) -> Option<String> {
    let SourceError::Io { doing, source, .. } = e else {
        return None;
    };
    let lost = source.kind() == std::io::ErrorKind::TimedOut
        || matches!(
            source.raw_os_error(),
            Some(libc::ENODEV | libc::EIO | libc::ENXIO | libc::EPIPE)
        );
    lost.then(|| format!("{doing}: {source}"))
}

impl V4lSource {
    pub fn open(device: &str, want: &V4lRequest) -> Result<Self, SourceError> {
        let stream = Stream::open(device, want)?;
        Ok(V4lSource {
            device: device.to_string(),
            asked: Asked::of(want),
            format: stream.format(),
            size: (stream.width, stream.height),
            fps: stream.fps,
            described: stream.describe(),
            stream: Some(stream),
            reopening: None,
            last_sequence: None,
            sequence_base: Some(0),
            last_ns: None,
            alive: std::sync::Arc::new(()),
        })
    }

    /// Closes the stream now and opens the device again, once a second, on a thread of its
    /// own, until it answers or this source is dropped.
    fn reopen(&mut self) {
        self.stream = None;
        let (tx, rx) = std::sync::mpsc::channel();
        let device = self.device.clone();
        let asked = self.asked.clone();
        let alive = std::sync::Arc::downgrade(&self.alive);
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(std::time::Duration::from_secs(1));
                // The source was dropped: nobody waits any more.
                if alive.upgrade().is_none() {
                    return;
                }
                if let Ok(s) = Stream::open(&device, &asked.request()) {
                    let _ = tx.send(s);
                    return;
                }
            }
        });
        self.reopening = Some(rx);
    }
}

impl FrameSource for V4lSource {
    fn describe(&self) -> String {
        match &self.stream {
            Some(s) => s.describe(),
            None => self.described.clone(),
        }
    }

    fn format(&self) -> PixelFormat {
        self.format
    }

    fn size(&self) -> (u32, u32) {
        self.size
    }

    fn fps(&self) -> Option<f64> {
        self.fps
    }

    fn realtime(&self) -> bool {
        false
    }

    fn read(&mut self, _i: u64, _t: f64, out: &mut [u8]) -> Result<Read, SourceError> {
        let device = self.device.clone();
        let camera = |m: String| -> SourceError {
            BadFrame::Camera {
                device: device.clone(),
                source: m.into(),
            }
            .into()
        };
        if let Some(rx) = &self.reopening {
            match rx.recv_timeout(std::time::Duration::from_millis(500)) {
                Ok(fresh) => {
                    self.reopening = None;
                    self.stream = Some(fresh);
                    // A device opened again numbers its frames afresh.
                    self.sequence_base = None;
                }
                Err(_) => return Err(camera("the camera is gone; opening it again".into())),
            }
        }
        let Some(stream) = &mut self.stream else {
            self.reopen();
            return Err(camera("the camera is gone; opening it again".into()));
        };
        match stream.read(out) {
            Ok(Read::Frame {
                timestamp_ns,
                sequence: Some(n),
            }) => {
                let (last, last_ns, fps) = (self.last_sequence, self.last_ns, self.fps);
                let base = *self.sequence_base.get_or_insert_with(|| {
                    i128::from(crate::source::number_after(
                        last,
                        last_ns,
                        timestamp_ns,
                        fps,
                    )) - i128::from(n)
                });
                let sequence = u64::try_from(i128::from(n) + base).unwrap_or(n);
                self.last_sequence = Some(sequence);
                self.last_ns = timestamp_ns;
                Ok(Read::Frame {
                    timestamp_ns,
                    sequence: Some(sequence),
                })
            }
            Err(e) => match gone(&e) {
                Some(why) => {
                    self.reopen();
                    Err(camera(format!("{why}; opening the camera again")))
                }
                None => Err(e),
            },
            other => other,
        }
    }
}

impl std::fmt::Debug for V4lSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "V4lSource({})", self.device)
    }
}

fn ioctl<T>(fd: &OwnedFd, request: libc::c_ulong, arg: &mut T) -> std::io::Result<()> {
    loop {
        // SAFETY: `arg` is the structure `request` is defined with (sys.rs pairs them), and
        // lives across the call.
        let r = unsafe { libc::ioctl(fd.as_raw_fd(), request as _, arg as *mut T) };
        if r != -1 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

impl Stream {
    fn open(device: &str, want: &V4lRequest) -> Result<Self, SourceError> {
        let io = |doing: &str, e| SourceError::io(device, doing, e);
        let format_problem = |problem| SourceError::Format {
            device: device.to_string(),
            problem,
        };
        let path = std::ffi::CString::new(device).map_err(|_| {
            io(
                "opening",
                std::io::Error::new(std::io::ErrorKind::InvalidInput, "a NUL in the path"),
            )
        })?;
        // SAFETY: a NUL-terminated path; the descriptor is owned below.
        let raw = unsafe { libc::open(path.as_ptr(), libc::O_RDWR | libc::O_NONBLOCK) };
        if raw < 0 {
            return Err(io("opening", std::io::Error::last_os_error()));
        }
        // SAFETY: `raw` is an open descriptor nothing else owns.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };

        let mut cap: sys::Capability = sys::zeroed();
        ioctl(&fd, sys::VIDIOC_QUERYCAP, &mut cap)
            .map_err(|e| io("asking what it is (VIDIOC_QUERYCAP; not a V4L2 device?)", e))?;
        let caps = if cap.capabilities & sys::CAP_DEVICE_CAPS != 0 {
            cap.device_caps
        } else {
            cap.capabilities
        };
        if caps & sys::CAP_VIDEO_CAPTURE == 0 || caps & sys::CAP_STREAMING == 0 {
            return Err(io(
                "opening",
                std::io::Error::new(
                    std::io::ErrorKind::Unsupported,
                    format!(
                        "{} is not a video capture device with streaming I/O",
                        sys::c_name(&cap.card)
                    ),
                ),
            ));
        }
        let card = format!("{}: {}", sys::c_name(&cap.driver), sys::c_name(&cap.card));

        let mut offered = Vec::new();
        for index in 0..256 {
            let mut d: sys::FmtDesc = sys::zeroed();
            d.index = index;
            d.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
            if ioctl(&fd, sys::VIDIOC_ENUM_FMT, &mut d).is_err() {
                break;
            }
            offered.push(sys::fourcc_str(d.pixelformat));
        }
        let wanted = match want.format {
            Some(f) => {
                if wire_of(f).is_none() {
                    return Err(format_problem(FormatProblem::Unsupported {
                        requested: f.to_string(),
                    }));
                }
                if !offered.iter().any(|o| o.trim_end() == f.trim_end()) {
                    return Err(format_problem(FormatProblem::NotOffered {
                        requested: f.to_string(),
                        offered,
                    }));
                }
                f.to_string()
            }
            None => offered
                .iter()
                .find(|o| wire_of(o).is_some())
                .cloned()
                .ok_or_else(|| {
                    format_problem(FormatProblem::NoneUsable {
                        offered: offered.clone(),
                    })
                })?,
        };
        let mut code = [b' '; 4];
        for (c, b) in code.iter_mut().zip(wanted.bytes()) {
            *c = b;
        }

        let mut fmt: sys::Format = sys::zeroed();
        fmt.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
        ioctl(&fd, sys::VIDIOC_G_FMT, &mut fmt).map_err(|e| io("reading the format", e))?;
        // SAFETY: a capture format's union holds `pix`.
        let mut pix = unsafe { fmt.fmt.pix };
        pix.pixelformat = sys::fourcc(&code);
        if let Some((w, h)) = want.size_px {
            pix.width = w;
            pix.height = h;
        }
        pix.field = sys::FIELD_NONE;
        pix.bytesperline = 0;
        pix.sizeimage = 0;
        fmt.fmt.pix = pix;
        ioctl(&fd, sys::VIDIOC_S_FMT, &mut fmt)
            .map_err(|e| io(&format!("setting format {}", wanted.trim_end()), e))?;
        // SAFETY: as above; the driver wrote back what it chose.
        let pix = unsafe { fmt.fmt.pix };
        let got = sys::fourcc_str(pix.pixelformat);
        let wire = wire_of(&got).ok_or_else(|| {
            format_problem(FormatProblem::DriverChose {
                chosen: got.clone(),
            })
        })?;

        if let Some(f) = want.fps {
            let mut parm: sys::StreamParm = sys::zeroed();
            parm.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
            // Frame intervals as a fraction of seconds: 1/f, in thousandths for 29.97 and the like.
            parm.parm.capture = sys::CaptureParm {
                timeperframe: sys::Fract {
                    numerator: 1000,
                    denominator: (f * 1000.0).round().clamp(1.0, u32::MAX as f64) as u32,
                },
                ..sys::zeroed()
            };
            ioctl(&fd, sys::VIDIOC_S_PARM, &mut parm)
                .map_err(|e| io(&format!("setting {f} fps"), e))?;
        }
        let set = |id: u32, value: i64, what: &str| -> Result<(), SourceError> {
            let value = i32::try_from(value).map_err(|_| {
                io(
                    what,
                    std::io::Error::new(std::io::ErrorKind::InvalidInput, "out of range"),
                )
            })?;
            ioctl(&fd, sys::VIDIOC_S_CTRL, &mut sys::Control { id, value }).map_err(|e| io(what, e))
        };
        if let Some(x) = want.exposure {
            set(
                sys::CID_EXPOSURE_AUTO,
                sys::EXPOSURE_MANUAL as i64,
                "setting manual exposure",
            )?;
            set(
                sys::CID_EXPOSURE_ABSOLUTE,
                x,
                &format!("setting exposure {x} (100 µs units)"),
            )?;
        }
        if let Some(g) = want.gain {
            set(sys::CID_GAIN, g, &format!("setting gain {g}"))?;
        }
        if !want.controls.is_empty() {
            let known = list_controls(&fd);
            for (name, value) in &want.controls {
                let (id, v) = control_value(&fd, &known, name, value).map_err(|problem| {
                    SourceError::Control {
                        device: device.to_string(),
                        control: name.to_string(),
                        problem,
                    }
                })?;
                set(id, v, &format!("setting control {name} = {value}"))?;
            }
        }
        let mut parm: sys::StreamParm = sys::zeroed();
        parm.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
        let fps = match ioctl(&fd, sys::VIDIOC_G_PARM, &mut parm) {
            // SAFETY: a capture stream's union holds `capture`.
            Ok(()) => {
                let t = unsafe { parm.parm.capture.timeperframe };
                (t.numerator > 0 && t.denominator > 0)
                    .then(|| t.denominator as f64 / t.numerator as f64)
            }
            Err(_) => None,
        }
        .or(want.fps);
        if let (Some(asked), Some(got)) = (want.fps, fps)
            && (got - asked).abs() > 0.01 * asked
        {
            return Err(format_problem(FormatProblem::RateRefused {
                requested: asked,
                got: (got * 1000.0).round() / 1000.0,
                size_px: (pix.width, pix.height),
            }));
        }
        let mut exposure = sys::Control {
            id: sys::CID_EXPOSURE_ABSOLUTE,
            value: 0,
        };
        let exposure_ns = ioctl(&fd, sys::VIDIOC_G_CTRL, &mut exposure)
            .ok()
            .filter(|_| exposure.value > 0)
            .map(|_| exposure.value as u64 * 100_000);

        let mut req = sys::RequestBuffers {
            count: 4,
            type_: sys::BUF_TYPE_VIDEO_CAPTURE,
            memory: sys::MEMORY_MMAP,
            ..sys::zeroed()
        };
        ioctl(&fd, sys::VIDIOC_REQBUFS, &mut req).map_err(|e| io("asking for buffers", e))?;
        if req.count == 0 {
            return Err(io(
                "asking for buffers",
                std::io::Error::new(std::io::ErrorKind::OutOfMemory, "the driver gave none"),
            ));
        }
        let mut buffers = Vec::with_capacity(req.count as usize);
        for index in 0..req.count {
            let mut b: sys::Buffer = sys::zeroed();
            b.index = index;
            b.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
            b.memory = sys::MEMORY_MMAP;
            ioctl(&fd, sys::VIDIOC_QUERYBUF, &mut b)
                .map_err(|e| io(&format!("querying buffer {index}"), e))?;
            // SAFETY: maps the driver's buffer at the offset it gave; checked for failure.
            let ptr = unsafe {
                libc::mmap(
                    std::ptr::null_mut(),
                    b.length as usize,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED,
                    fd.as_raw_fd(),
                    b.m.offset as libc::off_t,
                )
            };
            if ptr == libc::MAP_FAILED {
                return Err(io(
                    &format!("mapping buffer {index}"),
                    std::io::Error::last_os_error(),
                ));
            }
            buffers.push(Mapped {
                ptr,
                len: b.length as usize,
            });
            ioctl(&fd, sys::VIDIOC_QBUF, &mut b)
                .map_err(|e| io(&format!("queueing buffer {index}"), e))?;
        }
        let mut kind = sys::BUF_TYPE_VIDEO_CAPTURE as i32;
        ioctl(&fd, sys::VIDIOC_STREAMON, &mut kind).map_err(|e| io("starting the stream", e))?;
        Ok(Stream {
            device: device.to_string(),
            card,
            buffers,
            fd,
            wire,
            width: pix.width,
            height: pix.height,
            stride: pix.bytesperline as usize,
            fps,
            exposure_ns,
            readout_ns: want.readout_ns,
            stamp: None,
            realtime_minus_monotonic_ns: clock_offset_ns(),
            sequence: Sequence::default(),
            streaming: true,
        })
    }

    /// Waits up to two seconds for a frame and dequeues it.
    fn dequeue(&mut self) -> Result<sys::Buffer, SourceError> {
        let mut pfd = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        loop {
            // SAFETY: one valid pollfd.
            let r = unsafe { libc::poll(&mut pfd, 1, 2000) };
            if r > 0 {
                break;
            }
            if r == 0 {
                return Err(SourceError::io(
                    &self.device,
                    "reading a frame",
                    std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        "no frame from the camera in 2 s",
                    ),
                ));
            }
            let e = std::io::Error::last_os_error();
            if e.kind() != std::io::ErrorKind::Interrupted {
                return Err(SourceError::io(&self.device, "waiting for a frame", e));
            }
        }
        let mut b: sys::Buffer = sys::zeroed();
        b.type_ = sys::BUF_TYPE_VIDEO_CAPTURE;
        b.memory = sys::MEMORY_MMAP;
        ioctl(&self.fd, sys::VIDIOC_DQBUF, &mut b)
            .map_err(|e| SourceError::io(&self.device, "dequeueing a frame", e))?;
        Ok(b)
    }

    /// The frame's mid-exposure on the real-time clock (the module's header).
    fn timestamp_ns(&mut self, b: &sys::Buffer) -> u64 {
        let monotonic = clock_ns(libc::CLOCK_MONOTONIC);
        let realtime = monotonic + self.realtime_minus_monotonic_ns;
        let stamp = *self.stamp.get_or_insert(
            if b.flags & sys::BUF_FLAG_TIMESTAMP_MASK == sys::BUF_FLAG_TIMESTAMP_MONOTONIC {
                Stamp::Driver {
                    start_of_exposure: b.flags & sys::BUF_FLAG_TSTAMP_SRC_MASK
                        == sys::BUF_FLAG_TSTAMP_SRC_SOE,
                }
            } else {
                Stamp::Dequeue
            },
        );
        let driver_ns =
            b.timestamp.tv_sec as i128 * 1_000_000_000 + b.timestamp.tv_usec as i128 * 1_000;
        mid_exposure_ns(
            stamp,
            driver_ns,
            self.exposure_ns,
            self.readout_ns,
            realtime,
            monotonic,
        )
    }

    /// How frames are stamped, in words.
    fn stamp_words(&self) -> String {
        match self.stamp {
            None => "stamps: not yet known".into(),
            Some(Stamp::Dequeue) => {
                "stamped at dequeue (the driver's clock is not monotonic)".into()
            }
            Some(Stamp::Driver { start_of_exposure }) => {
                let edge = if start_of_exposure {
                    "start of exposure"
                } else {
                    "end of frame"
                };
                let readout = match (start_of_exposure, self.readout_ns) {
                    (false, Some(r)) => format!(" less {:.2} ms readout", r as f64 / 1e6),
                    (false, None) => " (readout not given: not subtracted)".into(),
                    (true, _) => String::new(),
                };
                match self.exposure_ns {
                    Some(e) => format!(
                        "the driver's {edge} stamp moved to mid-exposure ({:.1} ms){readout}",
                        e as f64 / 1e6
                    ),
                    None => format!("the driver's {edge} stamp (exposure unknown){readout}"),
                }
            }
        }
    }
}

impl Drop for Stream {
    fn drop(&mut self) {
        if self.streaming {
            let mut kind = sys::BUF_TYPE_VIDEO_CAPTURE as i32;
            let _ = ioctl(&self.fd, sys::VIDIOC_STREAMOFF, &mut kind);
        }
    }
}

impl Stream {
    fn describe(&self) -> String {
        format!(
            "v4l2 {} ({}) {:?} {}×{}{}, {}",
            self.device,
            self.card,
            self.wire,
            self.width,
            self.height,
            self.fps.map(|f| format!(" {f:.1} fps")).unwrap_or_default(),
            self.stamp_words()
        )
    }

    fn format(&self) -> PixelFormat {
        if self.wire == Wire::Y16 {
            PixelFormat::Gray16
        } else {
            PixelFormat::Gray8
        }
    }

    fn read(&mut self, out: &mut [u8]) -> Result<Read, SourceError> {
        let mut b = self.dequeue()?;
        let timestamp_ns = self.timestamp_ns(&b);
        let sequence = self.sequence.extend(b.sequence);
        let converted = match self.buffers.get(b.index as usize) {
            Some(m) if b.flags & sys::BUF_FLAG_ERROR == 0 => {
                // SAFETY: the driver handed this mapped buffer back and does not write it
                // until it is queued again below.
                let all = unsafe { std::slice::from_raw_parts(m.ptr as *const u8, m.len) };
                let data = &all[..(b.bytesused as usize).min(all.len())];
                convert(
                    self.wire,
                    data,
                    self.width as usize,
                    self.height as usize,
                    self.stride,
                    out,
                )
            }
            Some(_) => Err(ConvertError::DriverError),
            None => Err(ConvertError::NoSuchBuffer { index: b.index }),
        };
        if (b.index as usize) < self.buffers.len() {
            ioctl(&self.fd, sys::VIDIOC_QBUF, &mut b)
                .map_err(|e| SourceError::io(&self.device, "queueing a buffer again", e))?;
        }
        converted.map_err(|e| BadFrame::Camera {
            device: self.device.clone(),
            source: Box::new(e),
        })?;
        Ok(Read::Frame {
            timestamp_ns: Some(timestamp_ns),
            sequence: Some(sequence),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_device_is_named() {
        let e = V4lSource::open("/dev/video-none", &V4lRequest::default()).unwrap_err();
        assert!(e.to_string().contains("/dev/video-none"), "{e}");
        assert!(
            matches!(&e, SourceError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound),
            "{e:?}"
        );
    }

    #[test]
    fn a_file_that_is_no_camera_is_named() {
        let e = V4lSource::open("/dev/null", &V4lRequest::default()).unwrap_err();
        assert!(e.to_string().contains("/dev/null"), "{e}");
        assert!(e.to_string().contains("VIDIOC_QUERYCAP"), "{e}");
    }
}
