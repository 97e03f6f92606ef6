//! V4L2 cameras through the `v4l` crate (cargo feature `v4l`): GREY and Y16 frames are copied
//! row by row into shared memory, YUYV gives its luma bytes, MJPEG is decoded to grey.
//! Exposure and gain are set through the standard controls when given; the frame rate through
//! the capture parameters. Timestamps are taken when a buffer is dequeued (the driver's are on
//! the monotonic clock, not the rig's).

use crate::source::{FrameSource, Read, SourceError};
use stereoscope_proto::frame::PixelFormat;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const CID_GAIN: u32 = 0x0098_0913;
const EXPOSURE_MANUAL: i64 = 1;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wire {
    Grey,
    Y16,
    Yuyv,
    Mjpg,
}

pub struct V4lSource {
    device: String,
    stream: Stream<'static>,
    _dev: Device,
    wire: Wire,
    width: u32,
    height: u32,
    stride: usize,
    fps: Option<f64>,
}

impl std::fmt::Debug for V4lSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "V4lSource({})", self.device)
    }
}

fn wire_of(code: &str) -> Option<Wire> {
    match code {
        "GREY" => Some(Wire::Grey),
        "Y16 " | "Y16" => Some(Wire::Y16),
        "YUYV" => Some(Wire::Yuyv),
        "MJPG" => Some(Wire::Mjpg),
        _ => None,
    }
}

impl V4lSource {
    pub fn open(
        device: &str,
        format: Option<&str>,
        fps: Option<f64>,
        exposure: Option<i64>,
        gain: Option<i64>,
    ) -> Result<Self, SourceError> {
        let fatal = |m: String| SourceError::Fatal(format!("{device}: {m}"));
        let dev = Device::with_path(device).map_err(|e| fatal(e.to_string()))?;
        let mut fmt = dev
            .format()
            .map_err(|e| fatal(format!("reading the format: {e}")))?;
        let offered: Vec<String> = dev
            .enum_formats()
            .map_err(|e| fatal(format!("listing formats: {e}")))?
            .iter()
            .filter_map(|d| d.fourcc.str().ok().map(|s| s.to_string()))
            .collect();
        let wanted = match format {
            Some(f) => {
                if wire_of(f).is_none() {
                    return Err(fatal(format!(
                        "format {f:?} is not GREY, Y16, YUYV or MJPG"
                    )));
                }
                if !offered.iter().any(|o| o.trim_end() == f.trim_end()) {
                    return Err(fatal(format!(
                        "the camera does not offer {f}; it offers {offered:?}"
                    )));
                }
                f.to_string()
            }
            None => offered
                .iter()
                .find(|o| wire_of(o).is_some())
                .cloned()
                .ok_or_else(|| {
                    fatal(format!(
                        "offers none of GREY, Y16, YUYV, MJPG (it offers {offered:?})"
                    ))
                })?,
        };
        let mut code = [b' '; 4];
        for (c, b) in code.iter_mut().zip(wanted.bytes()) {
            *c = b;
        }
        fmt.fourcc = FourCC::new(&code);
        let fmt = dev
            .set_format(&fmt)
            .map_err(|e| fatal(format!("setting format {wanted}: {e}")))?;
        let got = fmt.fourcc.str().unwrap_or("????").to_string();
        let wire = wire_of(&got).ok_or_else(|| fatal(format!("driver chose format {got}")))?;
        if let Some(f) = fps {
            let params = v4l::video::capture::Parameters::with_fps(f.round().max(1.0) as u32);
            dev.set_params(&params)
                .map_err(|e| fatal(format!("setting {f} fps: {e}")))?;
        }
        if let Some(x) = exposure {
            dev.set_control(Control {
                id: CID_EXPOSURE_AUTO,
                value: Value::Integer(EXPOSURE_MANUAL),
            })
            .map_err(|e| fatal(format!("manual exposure: {e}")))?;
            dev.set_control(Control {
                id: CID_EXPOSURE_ABSOLUTE,
                value: Value::Integer(x),
            })
            .map_err(|e| fatal(format!("exposure {x}: {e}")))?;
        }
        if let Some(g) = gain {
            dev.set_control(Control {
                id: CID_GAIN,
                value: Value::Integer(g),
            })
            .map_err(|e| fatal(format!("gain {g}: {e}")))?;
        }
        let params = dev.params().ok();
        let fps = params
            .filter(|p| p.interval.numerator > 0)
            .map(|p| p.interval.denominator as f64 / p.interval.numerator as f64)
            .or(fps);
        let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
            .map_err(|e| fatal(format!("starting the stream: {e}")))?;
        stream.set_timeout(std::time::Duration::from_secs(2));
        Ok(V4lSource {
            device: device.to_string(),
            stream,
            _dev: dev,
            wire,
            width: fmt.width,
            height: fmt.height,
            stride: fmt.stride as usize,
            fps,
        })
    }
}

impl FrameSource for V4lSource {
    fn describe(&self) -> String {
        format!(
            "v4l2 {} {:?} {}×{}",
            self.device, self.wire, self.width, self.height
        )
    }

    fn format(&self) -> PixelFormat {
        if self.wire == Wire::Y16 {
            PixelFormat::Gray16
        } else {
            PixelFormat::Gray8
        }
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
        let (w, h) = (self.width as usize, self.height as usize);
        let (buf, meta) = self
            .stream
            .next()
            .map_err(|e| SourceError::Fatal(format!("{}: {e}", self.device)))?;
        let timestamp_ns = stereoscope_proto::messages::now_ns();
        let data = &buf[..(meta.bytesused as usize).min(buf.len())];
        let short = |need: usize| {
            SourceError::BadFrame(format!(
                "{}: frame of {} bytes, {need} expected",
                self.device,
                data.len()
            ))
        };
        match self.wire {
            Wire::Grey | Wire::Y16 => {
                let bpp = if self.wire == Wire::Y16 { 2 } else { 1 };
                let stride = self.stride.max(w * bpp);
                if data.len() < stride * (h - 1) + w * bpp {
                    return Err(short(stride * h));
                }
                crate::source::copy_rows(data, stride, w * bpp, h, out);
            }
            Wire::Yuyv => {
                let stride = self.stride.max(w * 2);
                if data.len() < stride * (h - 1) + w * 2 {
                    return Err(short(stride * h));
                }
                for (y, row) in out.chunks_exact_mut(w).enumerate() {
                    let src = &data[y * stride..y * stride + 2 * w];
                    for (d, s) in row.iter_mut().zip(src.iter().step_by(2)) {
                        *d = *s;
                    }
                }
            }
            Wire::Mjpg => {
                let mut dec = jpeg_decoder::Decoder::new(data);
                let pixels = dec.decode().map_err(|e| {
                    SourceError::BadFrame(format!("{}: MJPEG frame: {e}", self.device))
                })?;
                let info = dec.info().ok_or_else(|| short(w * h))?;
                if info.width as usize != w || info.height as usize != h {
                    return Err(SourceError::BadFrame(format!(
                        "{}: MJPEG frame is {}×{}, the stream {w}×{h}",
                        self.device, info.width, info.height
                    )));
                }
                let channels = pixels.len() / (w * h).max(1);
                match channels {
                    1 => out.copy_from_slice(&pixels[..w * h]),
                    3 => {
                        for (d, p) in out.iter_mut().zip(pixels.chunks_exact(3)) {
                            // BT.601 luma.
                            *d = ((77 * p[0] as u32 + 150 * p[1] as u32 + 29 * p[2] as u32) >> 8)
                                as u8;
                        }
                    }
                    _ => return Err(short(w * h * 3)),
                }
            }
        }
        Ok(Read::Frame {
            timestamp_ns: Some(timestamp_ns),
        })
    }
}
