//! A sequence of PGM/PNG files (8- or 16-bit grey), in name order; every file must have the
//! first file's size and depth. A file that cannot be read, or differs, is skipped and named.

use crate::source::{BadFrame, FrameSource, Read, SourceError};
use std::path::{Path, PathBuf};
use stereoscope_imageio::{AnyGray, read_gray};
use stereoscope_proto::frame::PixelFormat;

#[derive(Debug)]
pub struct ImageSource {
    files: Vec<PathBuf>,
    next: usize,
    width: u32,
    height: u32,
    format: PixelFormat,
    fps: f64,
    realtime: bool,
    repeat: bool,
}

fn list(path: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let shown = path.display().to_string();
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| SourceError::io(&shown, "listing the folder", e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("pgm") || e.eq_ignore_ascii_case("png"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(SourceError::NoImages { path: shown });
    }
    Ok(files)
}

impl ImageSource {
    pub fn open(path: &str, fps: f64, realtime: bool, repeat: bool) -> Result<Self, SourceError> {
        let files = list(Path::new(path))?;
        let first = read_gray(&files[0]).map_err(|source| SourceError::FirstImage {
            path: files[0].display().to_string(),
            source,
        })?;
        let format = match first {
            AnyGray::U8(_) => PixelFormat::Gray8,
            AnyGray::U16 { .. } => PixelFormat::Gray16,
        };
        Ok(ImageSource {
            width: first.width(),
            height: first.height(),
            files,
            next: 0,
            format,
            fps,
            realtime,
            repeat,
        })
    }
}

impl FrameSource for ImageSource {
    fn describe(&self) -> String {
        format!(
            "{} images {}×{} at {} fps",
            self.files.len(),
            self.width,
            self.height,
            self.fps
        )
    }

    fn format(&self) -> PixelFormat {
        self.format
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn fps(&self) -> Option<f64> {
        Some(self.fps)
    }

    fn realtime(&self) -> bool {
        self.realtime
    }

    fn read(&mut self, _i: u64, _t: f64, out: &mut [u8]) -> Result<Read, SourceError> {
        if self.next >= self.files.len() {
            if !self.repeat {
                return Ok(Read::End);
            }
            self.next = 0;
        }
        let path = &self.files[self.next];
        self.next += 1;
        let shown = || path.display().to_string();
        let img = read_gray(path).map_err(|source| BadFrame::Image {
            path: shown(),
            source,
        })?;
        if img.width() != self.width || img.height() != self.height {
            return Err(BadFrame::SizeChanged {
                path: shown(),
                got_px: (img.width(), img.height()),
                want_px: (self.width, self.height),
            }
            .into());
        }
        match (img, self.format) {
            (AnyGray::U8(i), PixelFormat::Gray8) => out.copy_from_slice(i.as_slice()),
            (AnyGray::U16 { image, .. }, PixelFormat::Gray16) => {
                for (d, s) in out.chunks_exact_mut(2).zip(image.as_slice()) {
                    d.copy_from_slice(&s.to_le_bytes());
                }
            }
            _ => {
                return Err(BadFrame::DepthChanged { path: shown() }.into());
            }
        }
        Ok(Read::Frame {
            timestamp_ns: None,
            sequence: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_imageio::{encode_pgm_u8, encode_pgm_u16};
    use stereoscope_vision::GrayImage;

    /// A sequence whose later files differ from the first is read on, each bad file skipped
    /// with its reason; an empty folder and an unreadable first file stop the source.
    #[test]
    fn bad_files_are_skipped_by_reason_and_a_bad_start_is_fatal() {
        let dir = std::env::temp_dir().join(format!("images-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.to_str().unwrap();
        let err = ImageSource::open(path, 10.0, false, false).unwrap_err();
        assert!(matches!(err, SourceError::NoImages { .. }), "{err:?}");

        let img = |w: u32, h: u32| GrayImage::<u8>::filled(w, h, 7).unwrap();
        std::fs::write(dir.join("a.pgm"), encode_pgm_u8(&img(4, 3))).unwrap();
        std::fs::write(dir.join("b.pgm"), encode_pgm_u8(&img(5, 3))).unwrap();
        let wide = GrayImage::<u16>::filled(4, 3, 7).unwrap();
        std::fs::write(dir.join("c.pgm"), encode_pgm_u16(&wide, 1023)).unwrap();
        std::fs::write(dir.join("d.pgm"), b"P5 4 3 255\n").unwrap();
        std::fs::write(dir.join("e.pgm"), encode_pgm_u8(&img(4, 3))).unwrap();
        let mut s = ImageSource::open(path, 10.0, false, false).unwrap();
        let mut out = vec![0u8; 12];
        assert!(matches!(s.read(0, 0.0, &mut out), Ok(Read::Frame { .. })));
        let err = s.read(1, 0.0, &mut out).unwrap_err();
        assert!(
            matches!(
                &err,
                SourceError::BadFrame(BadFrame::SizeChanged {
                    got_px: (5, 3),
                    want_px: (4, 3),
                    ..
                })
            ),
            "{err:?}"
        );
        assert!(err.to_string().contains("b.pgm"), "{err}");
        let err = s.read(2, 0.0, &mut out).unwrap_err();
        assert!(
            matches!(&err, SourceError::BadFrame(BadFrame::DepthChanged { .. })),
            "{err:?}"
        );
        let err = s.read(3, 0.0, &mut out).unwrap_err();
        assert!(
            matches!(&err, SourceError::BadFrame(BadFrame::Image { .. })),
            "{err:?}"
        );
        assert!(matches!(s.read(4, 0.0, &mut out), Ok(Read::Frame { .. })));
        assert!(matches!(s.read(5, 0.0, &mut out), Ok(Read::End)));

        std::fs::remove_file(dir.join("a.pgm")).unwrap();
        std::fs::rename(dir.join("d.pgm"), dir.join("a.pgm")).unwrap();
        let err = ImageSource::open(path, 10.0, false, false).unwrap_err();
        assert!(matches!(err, SourceError::FirstImage { .. }), "{err:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
