//! A sequence of PGM/PNG files (8- or 16-bit grey), in name order; every file must have the
//! first file's size and depth. A file that cannot be read, or differs, is skipped and named.

use crate::source::{FrameSource, Read, SourceError};
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
    let fatal = |m: String| SourceError::Fatal(format!("{}: {m}", path.display()));
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| fatal(e.to_string()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("pgm") || e.eq_ignore_ascii_case("png"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(fatal("no .pgm or .png files".into()));
    }
    Ok(files)
}

impl ImageSource {
    pub fn open(path: &str, fps: f64, realtime: bool, repeat: bool) -> Result<Self, SourceError> {
        let files = list(Path::new(path))?;
        let first = read_gray(&files[0])
            .map_err(|e| SourceError::Fatal(format!("{}: {e}", files[0].display())))?;
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
        let img = read_gray(path)
            .map_err(|e| SourceError::BadFrame(format!("{}: {e}", path.display())))?;
        if img.width() != self.width || img.height() != self.height {
            return Err(SourceError::BadFrame(format!(
                "{}: {}×{} differs from the sequence's {}×{}",
                path.display(),
                img.width(),
                img.height(),
                self.width,
                self.height
            )));
        }
        match (img, self.format) {
            (AnyGray::U8(i), PixelFormat::Gray8) => out.copy_from_slice(i.as_slice()),
            (AnyGray::U16 { image, .. }, PixelFormat::Gray16) => {
                for (d, s) in out.chunks_exact_mut(2).zip(image.as_slice()) {
                    d.copy_from_slice(&s.to_le_bytes());
                }
            }
            _ => {
                return Err(SourceError::BadFrame(format!(
                    "{}: bit depth differs from the sequence's first file",
                    path.display()
                )));
            }
        }
        Ok(Read::Frame {
            timestamp_ns: None,
            sequence: None,
        })
    }
}
