//! The files the commands read and write: grey images — PGM (P2 ASCII and P5 binary, 8- and
//! 16-bit) and PNG (grey, grey+alpha, RGB, RGBA, palette; 8- and 16-bit; colour is converted to
//! luma with the Rec. 601 weights) — and, in [`csv`], the commands' CSV inputs.
//!
//! Not a thesis algorithm: the thesis grabbed frames from a board. Errors say what is wrong
//! with the file (the caller adds the path).

pub mod csv;

use std::io::Read;
use std::path::Path;
use stereoscope_vision::{GrayImage, VisionError};
use thiserror::Error;

/// A decoded image: 8- or 16-bit.
#[derive(Debug, Clone, PartialEq)]
pub enum AnyGray {
    U8(GrayImage<u8>),
    /// 16-bit samples; `max_value` is the file's declared maximum (PGM maxval, or 65535).
    U16 {
        image: GrayImage<u16>,
        max_value: u32,
    },
}

impl AnyGray {
    pub fn width(&self) -> u32 {
        match self {
            AnyGray::U8(i) => i.width(),
            AnyGray::U16 { image, .. } => image.width(),
        }
    }

    pub fn height(&self) -> u32 {
        match self {
            AnyGray::U8(i) => i.height(),
            AnyGray::U16 { image, .. } => image.height(),
        }
    }

    pub fn bits(&self) -> u32 {
        match self {
            AnyGray::U8(_) => 8,
            AnyGray::U16 { .. } => 16,
        }
    }
}

#[derive(Debug, Error)]
pub enum ImageIoError {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    #[error("not a PGM or PNG file (starts with {0:?})")]
    UnknownFormat(String),
    #[error("PGM header: {0}")]
    PgmHeader(String),
    #[error("PGM data: {0}")]
    PgmData(String),
    #[error("PNG: {0}")]
    Png(String),
    /// The header claims a size over the supported one: nothing was allocated for it.
    #[error("the header claims {width}×{height} pixels, larger than the supported {max}×{max}")]
    TooLarge { width: u32, height: u32, max: u32 },
    #[error("{0}")]
    Image(#[from] VisionError),
}

/// Reads a PGM or PNG file, telling them apart by content, not by name.
pub fn read_gray(path: &Path) -> Result<AnyGray, ImageIoError> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)?.read_to_end(&mut bytes)?;
    decode_gray(&bytes)
}

/// Decodes PGM or PNG bytes.
pub fn decode_gray(bytes: &[u8]) -> Result<AnyGray, ImageIoError> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(bytes)
    } else if bytes.starts_with(b"P5") || bytes.starts_with(b"P2") {
        decode_pgm(bytes)
    } else {
        let head: String = bytes
            .iter()
            .take(4)
            .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
            .collect();
        Err(ImageIoError::UnknownFormat(head))
    }
}

/// Header tokens: magic, width, height, maxval; returns them and the offset after the single
/// whitespace byte that ends the header.
fn pgm_header(bytes: &[u8]) -> Result<([u32; 3], usize), ImageIoError> {
    let mut pos = 2usize;
    let mut values = [0u32; 3];
    let names = ["width", "height", "maxval"];
    for (i, name) in names.iter().enumerate() {
        // Skip white space and comments.
        loop {
            match bytes.get(pos) {
                Some(b) if b.is_ascii_whitespace() => pos += 1,
                Some(b'#') => {
                    while bytes.get(pos).is_some_and(|&b| b != b'\n') {
                        pos += 1;
                    }
                }
                _ => break,
            }
        }
        let start = pos;
        while bytes.get(pos).is_some_and(|b| b.is_ascii_digit()) {
            pos += 1;
        }
        if start == pos {
            return Err(ImageIoError::PgmHeader(format!(
                "{name} is missing or not a number"
            )));
        }
        let text = std::str::from_utf8(&bytes[start..pos]).unwrap_or("?");
        values[i] = text
            .parse()
            .map_err(|_| ImageIoError::PgmHeader(format!("{name} {text} is out of range")))?;
    }
    match bytes.get(pos) {
        Some(b) if b.is_ascii_whitespace() => pos += 1,
        _ => {
            return Err(ImageIoError::PgmHeader(
                "no white space after maxval".into(),
            ));
        }
    }
    let [w, h, maxval] = values;
    if w == 0 || h == 0 {
        return Err(ImageIoError::PgmHeader(format!("size {w}×{h} is empty")));
    }
    let max = stereoscope_vision::image::MAX_SIDE_PX;
    if w > max || h > max {
        return Err(ImageIoError::TooLarge {
            width: w,
            height: h,
            max,
        });
    }
    if maxval == 0 || maxval > 65535 {
        return Err(ImageIoError::PgmHeader(format!(
            "maxval {maxval} is not in 1..=65535"
        )));
    }
    Ok((values, pos))
}

fn decode_pgm(bytes: &[u8]) -> Result<AnyGray, ImageIoError> {
    let binary = bytes.starts_with(b"P5");
    let ([w, h, maxval], start) = pgm_header(bytes)?;
    let count = w as usize * h as usize;
    let samples: Vec<u32> = if binary {
        let bpp = if maxval > 255 { 2 } else { 1 };
        let need = count * bpp;
        let data = &bytes[start..];
        if data.len() < need {
            return Err(ImageIoError::PgmData(format!(
                "truncated: {w}×{h} at {} bit needs {need} bytes of pixels, the file has {}",
                8 * bpp,
                data.len()
            )));
        }
        if bpp == 1 {
            data[..need].iter().map(|&b| b as u32).collect()
        } else {
            data[..need]
                .chunks_exact(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]) as u32)
                .collect()
        }
    } else {
        let text = std::str::from_utf8(&bytes[start..])
            .map_err(|_| ImageIoError::PgmData("P2 pixels are not ASCII".into()))?;
        // Each pixel takes at least two characters: do not trust the header's size.
        let mut out = Vec::with_capacity(count.min(text.len() / 2 + 1));
        for (i, tok) in text.split_ascii_whitespace().take(count).enumerate() {
            let v: u32 = tok.parse().map_err(|_| {
                ImageIoError::PgmData(format!("pixel {i} is {tok:?}, not a number"))
            })?;
            out.push(v);
        }
        if out.len() < count {
            return Err(ImageIoError::PgmData(format!(
                "truncated: {} of {count} pixels",
                out.len()
            )));
        }
        out
    };
    if let Some((i, v)) = samples.iter().enumerate().find(|(_, v)| **v > maxval) {
        return Err(ImageIoError::PgmData(format!(
            "pixel {i} is {v}, above maxval {maxval}"
        )));
    }
    if maxval > 255 {
        let image = GrayImage::from_vec(samples.into_iter().map(|v| v as u16).collect(), w, h)?;
        Ok(AnyGray::U16 {
            image,
            max_value: maxval,
        })
    } else {
        Ok(AnyGray::U8(GrayImage::from_vec(
            samples.into_iter().map(|v| v as u8).collect(),
            w,
            h,
        )?))
    }
}

fn decode_png(bytes: &[u8]) -> Result<AnyGray, ImageIoError> {
    let mut decoder = png::Decoder::new(bytes);
    decoder.set_transformations(png::Transformations::EXPAND);
    let mut reader = decoder
        .read_info()
        .map_err(|e| ImageIoError::Png(e.to_string()))?;
    // The header's size is checked before the buffer it implies is allocated.
    let (width, height) = (reader.info().width, reader.info().height);
    let max = stereoscope_vision::image::MAX_SIDE_PX;
    if width > max || height > max {
        return Err(ImageIoError::TooLarge { width, height, max });
    }
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| ImageIoError::Png(e.to_string()))?;
    let (w, h) = (info.width, info.height);
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => {
            return Err(ImageIoError::Png("palette was not expanded".into()));
        }
    };
    let luma = |s: &[u32]| -> u32 {
        if channels >= 3 {
            ((299 * s[0] + 587 * s[1] + 114 * s[2] + 500) / 1000).min(65535)
        } else {
            s[0]
        }
    };
    match info.bit_depth {
        png::BitDepth::Sixteen => {
            let px: Vec<u16> = buf[..info.buffer_size()]
                .chunks_exact(2 * channels)
                .map(|c| {
                    let s: Vec<u32> = c
                        .chunks_exact(2)
                        .map(|b| u16::from_be_bytes([b[0], b[1]]) as u32)
                        .collect();
                    luma(&s) as u16
                })
                .collect();
            Ok(AnyGray::U16 {
                image: GrayImage::from_vec(px, w, h)?,
                max_value: 65535,
            })
        }
        png::BitDepth::Eight => {
            let px: Vec<u8> = buf[..info.buffer_size()]
                .chunks_exact(channels)
                .map(|c| {
                    let s: Vec<u32> = c.iter().map(|&b| b as u32).collect();
                    luma(&s) as u8
                })
                .collect();
            Ok(AnyGray::U8(GrayImage::from_vec(px, w, h)?))
        }
        other => Err(ImageIoError::Png(format!(
            "bit depth {other:?} after expansion is not supported"
        ))),
    }
}

/// Encodes an 8-bit image as binary PGM (P5).
pub fn encode_pgm_u8(img: &GrayImage<u8>) -> Vec<u8> {
    let mut out = format!("P5\n{} {}\n255\n", img.width(), img.height()).into_bytes();
    out.extend_from_slice(img.as_slice());
    out
}

/// Encodes a 16-bit image as binary PGM (P5, big-endian samples) with the given maxval.
pub fn encode_pgm_u16(img: &GrayImage<u16>, max_value: u16) -> Vec<u8> {
    let mut out = format!(
        "P5\n{} {}\n{}\n",
        img.width(),
        img.height(),
        max_value.max(256)
    )
    .into_bytes();
    for p in img.as_slice() {
        out.extend_from_slice(&p.to_be_bytes());
    }
    out
}

/// Encodes a 16-bit grey PNG (PNG's samples are big-endian).
pub fn encode_png_u16(img: &GrayImage<u16>) -> Result<Vec<u8>, ImageIoError> {
    let bytes: Vec<u8> = img
        .as_slice()
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    encode_png(
        &bytes,
        img.width(),
        img.height(),
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
    )
}

/// Encodes an 8-bit RGB PNG from `width × height` pixels of three bytes.
pub fn encode_png_rgb8(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, ImageIoError> {
    encode_png(
        rgb,
        width,
        height,
        png::ColorType::Rgb,
        png::BitDepth::Eight,
    )
}

fn encode_png(
    data: &[u8],
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
) -> Result<Vec<u8>, ImageIoError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(color);
        enc.set_depth(depth);
        let mut w = enc
            .write_header()
            .map_err(|e| ImageIoError::Png(e.to_string()))?;
        w.write_image_data(data)
            .map_err(|e| ImageIoError::Png(e.to_string()))?;
    }
    Ok(out)
}

/// Encodes an 8-bit grey PNG.
pub fn encode_png_u8(img: &GrayImage<u8>) -> Result<Vec<u8>, ImageIoError> {
    encode_png(
        img.as_slice(),
        img.width(),
        img.height(),
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> GrayImage<u8> {
        GrayImage::from_vec((0..12u8).map(|i| i * 20).collect(), 4, 3).unwrap()
    }

    #[test]
    fn pgm_round_trips_8_and_16_bit() {
        let img = sample();
        assert_eq!(
            decode_gray(&encode_pgm_u8(&img)).unwrap(),
            AnyGray::U8(img.clone())
        );
        let img16 = GrayImage::from_vec((0..12u16).map(|i| i * 4000).collect(), 4, 3).unwrap();
        match decode_gray(&encode_pgm_u16(&img16, 65535)).unwrap() {
            AnyGray::U16 { image, max_value } => {
                assert_eq!(image, img16);
                assert_eq!(max_value, 65535);
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn ascii_pgm_with_comments() {
        let text = b"P2\n# a comment\n3 2\n# another\n255\n0 10 20\n30 40 255\n";
        let AnyGray::U8(img) = decode_gray(text).unwrap() else {
            panic!()
        };
        assert_eq!(img.as_slice(), &[0, 10, 20, 30, 40, 255]);
        let text16 = b"P2 2 1 1000 999 1000";
        assert!(matches!(
            decode_gray(text16).unwrap(),
            AnyGray::U16 {
                max_value: 1000,
                ..
            }
        ));
    }

    #[test]
    fn png_round_trip_and_colour_to_luma() {
        let img = sample();
        assert_eq!(
            decode_gray(&encode_png_u8(&img).unwrap()).unwrap(),
            AnyGray::U8(img)
        );
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, 2, 1);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().unwrap();
            w.write_image_data(&[255, 0, 0, 255, 255, 255]).unwrap();
        }
        let AnyGray::U8(img) = decode_gray(&out).unwrap() else {
            panic!()
        };
        assert_eq!(img.as_slice(), &[76, 255]);
    }

    #[test]
    fn arbitrary_bytes_never_panic() {
        // Random and mutated inputs: every one decodes or gets an error, none panics.
        let mut rng = stereoscope_numeric::SplitMix64::new(11);
        let good = [
            encode_pgm_u8(&sample()),
            encode_png_u8(&sample()).unwrap(),
            b"P2\n3 2\n255\n0 1 2\n3 4 5\n".to_vec(),
        ];
        for trial in 0..3000 {
            let mut bytes = good[trial % good.len()].clone();
            match trial % 3 {
                0 => {
                    // Flip a few bytes.
                    for _ in 0..1 + rng.next_u64() % 4 {
                        let i = (rng.next_u64() % bytes.len() as u64) as usize;
                        bytes[i] = rng.next_u64() as u8;
                    }
                }
                1 => bytes.truncate((rng.next_u64() % bytes.len() as u64) as usize),
                _ => {
                    bytes = (0..rng.next_u64() % 64)
                        .map(|_| rng.next_u64() as u8)
                        .collect()
                }
            }
            let _ = decode_gray(&bytes);
        }
    }

    #[test]
    fn bad_files_say_what_is_wrong() {
        let msg = |b: &[u8]| decode_gray(b).unwrap_err().to_string();
        assert!(msg(b"GIF89a").contains("not a PGM or PNG"));
        assert!(msg(b"P5\n4 3\n255\n\x00\x01").contains("truncated"));
        assert!(msg(b"P5\n4\n").contains("height"));
        assert!(msg(b"P5\n0 3\n255\n").contains("empty"));
        assert!(msg(b"P5\n4 3\n70000\n").contains("maxval 70000"));
        assert!(msg(b"P2\n2 1\n100\n5 200\n").contains("above maxval"));
        assert!(msg(b"P2\n2 1\n100\n5 x\n").contains("not a number"));
        assert!(msg(b"\x89PNG\r\n\x1a\n\x00\x00").starts_with("PNG:"));
        assert!(msg(b"P5\n99999 99999\n255\n").contains("larger than the supported"));
        assert!(msg(b"P2\n8000 8000\n255\n1 2 3").contains("truncated"));
    }

    /// A 74-byte PNG whose header claims 100000 × 100000 pixels is refused before its
    /// 10-gigapixel buffer is allocated (it aborted the process before).
    #[test]
    fn a_png_header_claiming_a_huge_image_is_refused_before_allocating() {
        fn crc32(bytes: &[u8]) -> u32 {
            let mut c = !0u32;
            for &b in bytes {
                c ^= b as u32;
                for _ in 0..8 {
                    c = if c & 1 == 1 {
                        0xEDB8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        let small = GrayImage::<u8>::filled(2, 2, 7).unwrap();
        let mut png = encode_png_u8(&small).unwrap();
        // IHDR: 8-byte signature, length, "IHDR", width, height, ..., CRC over type + data.
        png[16..20].copy_from_slice(&100_000u32.to_be_bytes());
        png[20..24].copy_from_slice(&100_000u32.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        let err = decode_gray(&png).unwrap_err();
        assert!(
            matches!(
                err,
                ImageIoError::TooLarge {
                    width: 100_000,
                    height: 100_000,
                    ..
                }
            ),
            "{err:?}"
        );
    }
}
