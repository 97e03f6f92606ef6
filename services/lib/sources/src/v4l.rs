//! V4L2 cameras through the `v4l` crate (cargo feature `v4l`): GREY and Y16 frames are copied
//! row by row into shared memory, YUYV gives its luma bytes, MJPEG is decoded to grey.
//! Exposure and gain are set through the standard controls when given; the frame rate through
//! the capture parameters. Timestamps are taken when a buffer is dequeued (the driver's are on
//! the monotonic clock, not the rig's).

use crate::source::{BadFrame, FormatProblem, FrameSource, Read, SourceError};
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
        let io = |doing: &str, e| SourceError::io(device, doing, e);
        let format_problem = |problem| SourceError::Format {
            device: device.to_string(),
            problem,
        };
        let dev = Device::with_path(device).map_err(|e| io("opening", e))?;
        let mut fmt = dev.format().map_err(|e| io("reading the format", e))?;
        let offered: Vec<String> = dev
            .enum_formats()
            .map_err(|e| io("listing formats", e))?
            .iter()
            .filter_map(|d| d.fourcc.str().ok().map(|s| s.to_string()))
            .collect();
        let wanted = match format {
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
        fmt.fourcc = FourCC::new(&code);
        let fmt = dev
            .set_format(&fmt)
            .map_err(|e| io(&format!("setting format {wanted}"), e))?;
        let got = fmt.fourcc.str().unwrap_or("????").to_string();
        let wire = wire_of(&got).ok_or_else(|| {
            format_problem(FormatProblem::DriverChose {
                chosen: got.clone(),
            })
        })?;
        if let Some(f) = fps {
            let params = v4l::video::capture::Parameters::with_fps(f.round().max(1.0) as u32);
            dev.set_params(&params)
                .map_err(|e| io(&format!("setting {f} fps"), e))?;
        }
        if let Some(x) = exposure {
            dev.set_control(Control {
                id: CID_EXPOSURE_AUTO,
                value: Value::Integer(EXPOSURE_MANUAL),
            })
            .map_err(|e| io("setting manual exposure", e))?;
            dev.set_control(Control {
                id: CID_EXPOSURE_ABSOLUTE,
                value: Value::Integer(x),
            })
            .map_err(|e| io(&format!("setting exposure {x}"), e))?;
        }
        if let Some(g) = gain {
            dev.set_control(Control {
                id: CID_GAIN,
                value: Value::Integer(g),
            })
            .map_err(|e| io(&format!("setting gain {g}"), e))?;
        }
        let params = dev.params().ok();
        let fps = params
            .filter(|p| p.interval.numerator > 0)
            .map(|p| p.interval.denominator as f64 / p.interval.numerator as f64)
            .or(fps);
        let mut stream = Stream::with_buffers(&dev, Type::VideoCapture, 4)
            .map_err(|e| io("starting the stream", e))?;
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
        let (buf, meta) = self
            .stream
            .next()
            .map_err(|e| SourceError::io(&self.device, "reading a frame", e))?;
        let timestamp_ns = stereoscope_proto::messages::now_ns();
        let data = &buf[..(meta.bytesused as usize).min(buf.len())];
        convert(
            self.wire,
            data,
            self.width as usize,
            self.height as usize,
            self.stride,
            out,
        )
        .map_err(|e| BadFrame::Camera {
            device: self.device.clone(),
            source: Box::new(e),
        })?;
        Ok(Read::Frame {
            timestamp_ns: Some(timestamp_ns),
            sequence: None,
        })
    }
}

/// Why a camera buffer is not a frame.
#[derive(Debug, thiserror::Error)]
enum ConvertError {
    #[error("frame of {got} bytes, {need} expected")]
    Short { got: usize, need: usize },
    #[error("MJPEG frame")]
    Jpeg(#[source] jpeg_decoder::Error),
    #[error("MJPEG frame is {got_w}×{got_h}, the stream {w}×{h}")]
    JpegSize {
        got_w: u16,
        got_h: u16,
        w: usize,
        h: usize,
    },
}

/// One camera buffer (`stride` bytes per row as the driver gives them) into tight grey rows.
fn convert(
    wire: Wire,
    data: &[u8],
    w: usize,
    h: usize,
    stride: usize,
    out: &mut [u8],
) -> Result<(), ConvertError> {
    let short = |need: usize| ConvertError::Short {
        got: data.len(),
        need,
    };
    match wire {
        Wire::Grey | Wire::Y16 => {
            let bpp = if wire == Wire::Y16 { 2 } else { 1 };
            let stride = stride.max(w * bpp);
            if h == 0 || data.len() < stride * (h - 1) + w * bpp {
                return Err(short(stride * h));
            }
            crate::source::copy_rows(data, stride, w * bpp, h, out);
        }
        Wire::Yuyv => {
            let stride = stride.max(w * 2);
            if h == 0 || data.len() < stride * (h - 1) + w * 2 {
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
            let pixels = dec.decode().map_err(ConvertError::Jpeg)?;
            let info = dec.info().ok_or_else(|| short(w * h))?;
            if info.width as usize != w || info.height as usize != h {
                return Err(ConvertError::JpegSize {
                    got_w: info.width,
                    got_h: info.height,
                    w,
                    h,
                });
            }
            match pixels.len() / (w * h).max(1) {
                1 => out.copy_from_slice(&pixels[..w * h]),
                3 => {
                    for (d, p) in out.iter_mut().zip(pixels.chunks_exact(3)) {
                        // BT.601 luma.
                        *d = ((77 * p[0] as u32 + 150 * p[1] as u32 + 29 * p[2] as u32) >> 8) as u8;
                    }
                }
                _ => return Err(short(w * h * 3)),
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_formats_become_grey_rows() {
        // GREY with padded rows.
        let data = [1, 2, 3, 0, 4, 5, 6, 0];
        let mut out = [0u8; 6];
        convert(Wire::Grey, &data, 3, 2, 4, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3, 4, 5, 6]);
        // Y16: two bytes a pixel, little-endian, kept as bytes.
        let data = [1, 0, 2, 0, 3, 1, 4, 1];
        let mut out = [0u8; 8];
        convert(Wire::Y16, &data, 2, 2, 4, &mut out).unwrap();
        assert_eq!(out, data);
        // YUYV: the Y bytes.
        let data = [10, 128, 11, 129, 12, 128, 13, 129];
        let mut out = [0u8; 4];
        convert(Wire::Yuyv, &data, 2, 2, 4, &mut out).unwrap();
        assert_eq!(out, [10, 11, 12, 13]);
        // Short buffers and broken JPEG are bad frames, not panics.
        assert!(matches!(
            convert(Wire::Grey, &[1, 2], 3, 2, 3, &mut [0; 6]),
            Err(ConvertError::Short { got: 2, .. })
        ));
        assert!(convert(Wire::Yuyv, &[1; 7], 2, 2, 4, &mut [0; 4]).is_err());
        assert!(matches!(
            convert(Wire::Mjpg, &[0xff, 0xd8, 0, 1], 2, 2, 2, &mut [0; 4]),
            Err(ConvertError::Jpeg(_))
        ));
        assert_eq!(wire_of("Y16 "), Some(Wire::Y16));
        assert_eq!(wire_of("NV12"), None);
    }

    #[test]
    fn a_missing_device_is_named() {
        let e = V4lSource::open("/dev/video-none", None, None, None, None).unwrap_err();
        assert!(e.to_string().contains("/dev/video-none"), "{e}");
        assert!(
            matches!(&e, SourceError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound),
            "{e:?}"
        );
    }
}
