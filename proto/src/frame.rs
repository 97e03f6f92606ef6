//! The shared-memory frame: a small `#[repr(C)]` header carried as iceoryx2's user header, the
//! pixels as the `[u8]` slice payload of the same sample. Capture writes each frame once into
//! shared memory; every reader borrows it in place. Frames never cross the network.
//!
//! Pixel layout: row-major, `stride_bytes` per row (at least `width × bytes per pixel`), rows
//! top to bottom; `Gray16` is little-endian and the payload is 8-byte aligned so it can be read
//! as `u16` in place. Image coordinates: `docs/conventions.md`.

use iceoryx2::prelude::ZeroCopySend;
use std::fmt;

/// Layout version of [`FrameHeader`]; a reader rejects any other.
pub const FRAME_HEADER_VERSION: u32 = 1;

/// Longest camera id carried in a header, bytes (UTF-8).
pub const CAMERA_ID_LEN: usize = 32;

/// Pixel formats a frame may carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum PixelFormat {
    /// 8-bit grey.
    Gray8 = 1,
    /// 16-bit grey, little-endian.
    Gray16 = 2,
}

impl PixelFormat {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Gray8 => 1,
            PixelFormat::Gray16 => 2,
        }
    }

    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            1 => Some(PixelFormat::Gray8),
            2 => Some(PixelFormat::Gray16),
            _ => None,
        }
    }
}

/// The header of one frame in shared memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("stereoscope::FrameHeader/v1")]
#[repr(C)]
pub struct FrameHeader {
    /// [`FRAME_HEADER_VERSION`].
    pub version: u32,
    /// [`PixelFormat`] code.
    pub pixel_format: u32,
    /// Frame number from the capture's start, counting every frame read (a gap means frames
    /// were lost before publication).
    pub sequence: u64,
    /// When the frame was exposed (the scene time of a synthetic frame), ns since the Unix
    /// epoch (CLOCK_REALTIME; PCs of one rig keep their clocks in step, `docs/deploy.md`).
    pub timestamp_ns: u64,
    /// When capture published it, ns since the Unix epoch.
    pub published_ns: u64,
    pub width: u32,
    pub height: u32,
    pub stride_bytes: u32,
    /// The camera's id, UTF-8, zero-padded.
    pub camera_id: [u8; CAMERA_ID_LEN],
}

impl Default for FrameHeader {
    fn default() -> Self {
        FrameHeader {
            version: FRAME_HEADER_VERSION,
            pixel_format: PixelFormat::Gray8 as u32,
            sequence: 0,
            timestamp_ns: 0,
            published_ns: 0,
            width: 0,
            height: 0,
            stride_bytes: 0,
            camera_id: [0; CAMERA_ID_LEN],
        }
    }
}

/// Why a frame cannot be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FrameError {
    Version(u32),
    PixelFormat(u32),
    EmptyImage { width: u32, height: u32 },
    Stride { stride_bytes: u32, needed: u64 },
    PayloadSize { header_says: u64, payload: u64 },
    CameraId(String),
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Version(v) => write!(
                f,
                "frame header version {v} is not {FRAME_HEADER_VERSION}: capture and worker are different builds"
            ),
            FrameError::PixelFormat(c) => write!(
                f,
                "pixel_format {c} is not a known format (1 = Gray8, 2 = Gray16)"
            ),
            FrameError::EmptyImage { width, height } => {
                write!(f, "frame size {width}×{height} is empty")
            }
            FrameError::Stride {
                stride_bytes,
                needed,
            } => write!(
                f,
                "stride_bytes {stride_bytes} is less than a row's {needed} bytes"
            ),
            FrameError::PayloadSize {
                header_says,
                payload,
            } => write!(
                f,
                "header says stride × height = {header_says} bytes but the payload has {payload}"
            ),
            FrameError::CameraId(id) => {
                write!(f, "camera id {id:?} is longer than {CAMERA_ID_LEN} bytes")
            }
        }
    }
}

impl std::error::Error for FrameError {}

impl FrameHeader {
    /// A header for a frame of this camera and size (stride = tight rows).
    pub fn new(
        camera_id: &str,
        format: PixelFormat,
        width: u32,
        height: u32,
    ) -> Result<Self, FrameError> {
        let mut h = FrameHeader {
            pixel_format: format as u32,
            width,
            height,
            stride_bytes: width.saturating_mul(format.bytes_per_pixel() as u32),
            ..FrameHeader::default()
        };
        h.camera_id = encode_camera_id(camera_id)?;
        Ok(h)
    }

    /// Bytes of payload this header describes.
    pub fn payload_len(&self) -> u64 {
        self.stride_bytes as u64 * self.height as u64
    }

    pub fn camera_id(&self) -> String {
        decode_camera_id(&self.camera_id)
    }

    /// Checks the header against the payload it came with.
    pub fn validate(&self, payload_len: usize) -> Result<PixelFormat, FrameError> {
        if self.version != FRAME_HEADER_VERSION {
            return Err(FrameError::Version(self.version));
        }
        let format = PixelFormat::from_code(self.pixel_format)
            .ok_or(FrameError::PixelFormat(self.pixel_format))?;
        if self.width == 0 || self.height == 0 {
            return Err(FrameError::EmptyImage {
                width: self.width,
                height: self.height,
            });
        }
        let needed = self.width as u64 * format.bytes_per_pixel() as u64;
        if (self.stride_bytes as u64) < needed {
            return Err(FrameError::Stride {
                stride_bytes: self.stride_bytes,
                needed,
            });
        }
        if self.payload_len() != payload_len as u64 {
            return Err(FrameError::PayloadSize {
                header_says: self.payload_len(),
                payload: payload_len as u64,
            });
        }
        Ok(format)
    }
}

/// A camera id as the header's fixed, zero-padded field.
pub fn encode_camera_id(id: &str) -> Result<[u8; CAMERA_ID_LEN], FrameError> {
    let bytes = id.as_bytes();
    if bytes.len() > CAMERA_ID_LEN {
        return Err(FrameError::CameraId(id.to_string()));
    }
    let mut out = [0u8; CAMERA_ID_LEN];
    out[..bytes.len()].copy_from_slice(bytes);
    Ok(out)
}

pub fn decode_camera_id(field: &[u8; CAMERA_ID_LEN]) -> String {
    let end = field.iter().position(|&b| b == 0).unwrap_or(CAMERA_ID_LEN);
    String::from_utf8_lossy(&field[..end]).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_is_the_documented_one() {
        use std::mem::{offset_of, size_of};
        assert_eq!(size_of::<FrameHeader>(), 80);
        assert_eq!(offset_of!(FrameHeader, pixel_format), 4);
        assert_eq!(offset_of!(FrameHeader, sequence), 8);
        assert_eq!(offset_of!(FrameHeader, timestamp_ns), 16);
        assert_eq!(offset_of!(FrameHeader, published_ns), 24);
        assert_eq!(offset_of!(FrameHeader, width), 32);
        assert_eq!(offset_of!(FrameHeader, stride_bytes), 40);
        assert_eq!(offset_of!(FrameHeader, camera_id), 44);
    }

    #[test]
    fn header_validates_against_payload() {
        let h = FrameHeader::new("cam0", PixelFormat::Gray8, 320, 240).unwrap();
        assert_eq!(h.validate(320 * 240), Ok(PixelFormat::Gray8));
        assert_eq!(h.camera_id(), "cam0");
        let err = h.validate(320 * 239).unwrap_err();
        assert!(
            err.to_string().contains("76800") && err.to_string().contains("76480"),
            "{err}"
        );
        let mut bad = h;
        bad.stride_bytes = 100;
        assert!(matches!(
            bad.validate(24000),
            Err(FrameError::Stride { .. })
        ));
        bad = h;
        bad.pixel_format = 9;
        assert!(
            bad.validate(320 * 240)
                .unwrap_err()
                .to_string()
                .contains("pixel_format 9")
        );
        bad = h;
        bad.version = 7;
        assert!(matches!(
            bad.validate(320 * 240),
            Err(FrameError::Version(7))
        ));
        bad = h;
        bad.height = 0;
        bad.stride_bytes = 320;
        assert!(matches!(
            bad.validate(0),
            Err(FrameError::EmptyImage { .. })
        ));
        let h16 = FrameHeader::new("c", PixelFormat::Gray16, 10, 2).unwrap();
        assert_eq!(h16.stride_bytes, 20);
        assert!(FrameHeader::new(&"x".repeat(33), PixelFormat::Gray8, 1, 1).is_err());
    }
}
