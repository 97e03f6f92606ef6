//! A V4L2 frame as the driver gives it into the tight grey rows the moment worker reads: GREY
//! and Y16 copied per row (rows may be padded), YUYV's luma, MJPEG decoded — one pass from the
//! driver's buffer into the shared-memory frame (`frame_copy` bench, docs/performance.md).

/// A frame's layout as the driver gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    Grey,
    Y16,
    Yuyv,
    Mjpg,
}

/// The layout of a V4L2 four-character code this source reads.
pub fn wire_of(code: &str) -> Option<Wire> {
    match code.trim_end() {
        "GREY" => Some(Wire::Grey),
        "Y16" => Some(Wire::Y16),
        "YUYV" => Some(Wire::Yuyv),
        "MJPG" => Some(Wire::Mjpg),
        _ => None,
    }
}

/// Why a camera buffer is not a frame.
#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
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
    #[error("the driver flagged the buffer as corrupted")]
    DriverError,
    #[error("the driver returned buffer {index}, which it never gave")]
    NoSuchBuffer { index: u32 },
}

/// Every other byte of `yuyv` (Y0 U Y1 V …) into `luma`, in blocks of 16 the compiler turns
/// into byte shuffles (a byte-by-byte `step_by(2)` loop took 93 µs at 640 × 480; the
/// frame_copy bench).
fn luma_of_yuyv(yuyv: &[u8], luma: &mut [u8]) {
    let mut blocks = luma.chunks_exact_mut(16);
    let mut pairs = yuyv.chunks_exact(32);
    for (d, s) in (&mut blocks).zip(&mut pairs) {
        for i in 0..16 {
            d[i] = s[2 * i];
        }
    }
    for (d, s) in blocks
        .into_remainder()
        .iter_mut()
        .zip(pairs.remainder().chunks_exact(2))
    {
        *d = s[0];
    }
}

/// One camera buffer (`stride` bytes per row as the driver gives them) into tight grey rows:
/// the one pass each frame takes from the driver's buffer into the shared-memory frame.
pub fn convert(
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
                luma_of_yuyv(src, row);
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
        assert_eq!(
            crate::v4l2::sys::fourcc_str(crate::v4l2::sys::fourcc(b"Y16 ")),
            "Y16 "
        );
    }

    /// The blocked luma copy gives every Y byte, at widths that leave remainders.
    #[test]
    fn yuyv_luma_is_every_other_byte() {
        for w in [1usize, 15, 16, 17, 37, 640] {
            let yuyv: Vec<u8> = (0..2 * w).map(|i| (i * 7 % 251) as u8).collect();
            let mut luma = vec![0u8; w];
            luma_of_yuyv(&yuyv, &mut luma);
            let want: Vec<u8> = yuyv.iter().step_by(2).copied().collect();
            assert_eq!(luma, want, "width {w}");
        }
    }
}
