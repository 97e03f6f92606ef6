//! YUV4MPEG2 files and pipes: the luma plane of each frame, read straight into the frame
//! buffer; chroma is skipped. Headers: `YUV4MPEG2 W… H… F…:… [C…]`, then per frame
//! `FRAME[ params]\n` and the planes; a frame's `Xts=<ns>` parameter (the recorder writes it) is
//! its exposure time, so recorded frames replay with their recorded times. Colour spaces: 420 (all variants), 422, 444, mono
//! (8-bit) and mono16 (16-bit little-endian luma). Any other input can be converted by
//! `ffmpeg -i IN -f yuv4mpegpipe -pix_fmt gray PIPE`.

use crate::source::{BadFrame, FrameSource, Read, SourceError};
use std::fs::File;
use std::io::{BufRead, BufReader, Read as _, Seek, SeekFrom};
use stereoscope_proto::frame::PixelFormat;
use stereoscope_rig::schema::ReplayClock;

#[derive(Debug)]
pub struct Y4mSource {
    path: String,
    reader: BufReader<File>,
    width: u32,
    height: u32,
    fps: Option<f64>,
    format: PixelFormat,
    chroma_bytes: usize,
    data_start: u64,
    realtime: bool,
    repeat: bool,
    frames_read: u64,
    replay_clock: Option<ReplayClock>,
}

/// What is wrong with a YUV4MPEG2 stream header.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Y4mHeaderError {
    #[error("not a YUV4MPEG2 stream (the first word must be YUV4MPEG2)")]
    NotY4m,
    #[error("{field} {value:?} is not a number")]
    NotANumber { field: &'static str, value: String },
    #[error("frame rate {0:?} is not N:D")]
    Rate(String),
    #[error("frame size {width}×{height} is outside 1–16384")]
    Size { width: u32, height: u32 },
    #[error("the header has no W or H")]
    NoSize,
    #[error("colour space C{0} is not supported (420, 422, 444, mono, mono16)")]
    Colour(String),
}

/// Header fields: (width, height, fps, format, chroma bytes per frame).
pub fn parse_header(
    line: &str,
) -> Result<(u32, u32, Option<f64>, PixelFormat, usize), Y4mHeaderError> {
    let mut words = line.split_ascii_whitespace();
    if words.next() != Some("YUV4MPEG2") {
        return Err(Y4mHeaderError::NotY4m);
    }
    let number = |field: &'static str, value: &str| {
        value
            .parse::<u32>()
            .map_err(|_| Y4mHeaderError::NotANumber {
                field,
                value: value.to_string(),
            })
    };
    let (mut w, mut h, mut fps, mut colour) = (None, None, None, "420jpeg".to_string());
    for word in words {
        // The tag is the first character, whatever it is (a multi-byte one must not split
        // the word inside it: the property test found that panic).
        let mut chars = word.chars();
        let tag = chars.next();
        let value = chars.as_str();
        match tag {
            Some('W') => w = Some(number("width", value)?),
            Some('H') => h = Some(number("height", value)?),
            Some('F') => {
                let rate = || Y4mHeaderError::Rate(value.to_string());
                let (n, d) = value.split_once(':').ok_or_else(rate)?;
                let (n, d): (f64, f64) = (
                    n.parse().map_err(|_| rate())?,
                    d.parse().map_err(|_| rate())?,
                );
                if n > 0.0 && d > 0.0 {
                    fps = Some(n / d);
                }
            }
            Some('C') => colour = value.to_string(),
            _ => {}
        }
    }
    let (w, h) = match (w, h) {
        (Some(w), Some(h)) if w > 0 && h > 0 && w <= 16384 && h <= 16384 => (w, h),
        (Some(width), Some(height)) => return Err(Y4mHeaderError::Size { width, height }),
        _ => return Err(Y4mHeaderError::NoSize),
    };
    let luma = w as usize * h as usize;
    let cw = (w as usize).div_ceil(2);
    let ch = (h as usize).div_ceil(2);
    let (format, chroma) = match colour.as_str() {
        c if c.starts_with("420") => (PixelFormat::Gray8, 2 * cw * ch),
        "422" => (PixelFormat::Gray8, 2 * cw * h as usize),
        "444" => (PixelFormat::Gray8, 2 * luma),
        "mono" => (PixelFormat::Gray8, 0),
        "mono16" => (PixelFormat::Gray16, 0),
        other => return Err(Y4mHeaderError::Colour(other.to_string())),
    };
    Ok((w, h, fps, format, chroma))
}

impl Y4mSource {
    pub fn open(path: &str, realtime: bool, repeat: bool) -> Result<Self, SourceError> {
        let file = File::open(path).map_err(|e| SourceError::io(path, "opening", e))?;
        let mut reader = BufReader::with_capacity(1 << 20, file);
        let mut line = String::new();
        reader
            .read_line(&mut line)
            .map_err(|e| SourceError::io(path, "reading the header", e))?;
        let (width, height, fps, format, chroma_bytes) =
            parse_header(line.trim_end()).map_err(|source| SourceError::Y4mHeader {
                path: path.to_string(),
                source,
            })?;
        // A pipe cannot seek; repeat is then refused when the end comes.
        let data_start = line.len() as u64;
        Ok(Y4mSource {
            path: path.to_string(),
            reader,
            width,
            height,
            fps,
            format,
            chroma_bytes,
            data_start,
            realtime,
            repeat,
            frames_read: 0,
            replay_clock: None,
        })
    }

    /// Publish recorded frames at their recorded pace on `clock` (frames without `Xts` go out
    /// as fast as they are read).
    pub fn with_replay_clock(mut self, clock: Option<ReplayClock>) -> Self {
        if clock.is_some() {
            self.realtime = false;
        }
        self.replay_clock = clock;
        self
    }
}

impl FrameSource for Y4mSource {
    fn describe(&self) -> String {
        format!(
            "y4m {} {}×{} {}",
            self.path,
            self.width,
            self.height,
            self.fps
                .map(|f| format!("{f:.3} fps"))
                .unwrap_or_else(|| "no rate".into())
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
        self.realtime
    }

    fn lockstep(&self) -> bool {
        self.replay_clock.is_some()
    }

    fn read(&mut self, _index: u64, _t: f64, out: &mut [u8]) -> Result<Read, SourceError> {
        let frame_no = self.frames_read;
        let path = self.path.as_str();
        let io = |e| SourceError::io(path, format!("frame {frame_no}"), e);
        let mut line = Vec::new();
        let n = self.reader.read_until(b'\n', &mut line).map_err(io)?;
        if n == 0 {
            if self.repeat && frame_no > 0 {
                self.reader
                    .seek(SeekFrom::Start(self.data_start))
                    .map_err(|e| SourceError::io(path, "starting again (a pipe?)", e))?;
                self.frames_read = 0;
                return self.read(_index, _t, out);
            }
            return Ok(Read::End);
        }
        if !line.starts_with(b"FRAME") || line.last() != Some(&b'\n') {
            return Err(SourceError::NoFrameLine {
                path: path.to_string(),
                frame: frame_no,
                found: String::from_utf8_lossy(&line[..line.len().min(16)]).into_owned(),
            });
        }
        let want = out.len();
        let mut got = 0;
        while got < want {
            match self.reader.read(&mut out[got..]) {
                Ok(0) => break,
                Ok(k) => got += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io(e)),
            }
        }
        if got < want {
            return Err(BadFrame::Truncated {
                path: path.to_string(),
                frame: frame_no,
                plane: "luma",
                got: got as u64,
                want: want as u64,
            }
            .into());
        }
        let skip = self.chroma_bytes as u64;
        let copied =
            std::io::copy(&mut (&mut self.reader).take(skip), &mut std::io::sink()).map_err(io)?;
        if copied < skip {
            return Err(BadFrame::Truncated {
                path: path.to_string(),
                frame: frame_no,
                plane: "chroma",
                got: copied,
                want: skip,
            }
            .into());
        }
        self.frames_read += 1;
        let mut timestamp_ns = frame_timestamp(&line);
        let sequence = frame_sequence(&line);
        // A file without recorded times, restamped on a replay clock: its frames are timed by
        // their index and the file's rate from the clock's start, so files of several cameras
        // stay in step frame by frame whatever the machine's load.
        if let (Some(clock), None, Some(fps)) = (self.replay_clock, timestamp_ns, self.fps)
            && clock.restamp
            && fps > 0.0
        {
            timestamp_ns = Some(clock.recorded_ns + (frame_no as f64 * 1e9 / fps) as u64);
        }
        if let (Some(clock), Some(ts)) = (self.replay_clock, timestamp_ns) {
            // Due at the replay's wall-clock time for this recorded time.
            let speed = if clock.speed.is_finite() && clock.speed > 0.0 {
                clock.speed
            } else {
                1.0
            };
            let due = clock.wall_ns + (ts.saturating_sub(clock.recorded_ns) as f64 / speed) as u64;
            let now = stereoscope_proto::messages::now_ns();
            if due > now {
                std::thread::sleep(std::time::Duration::from_nanos(due - now));
            }
            if clock.restamp {
                return Ok(Read::Frame {
                    timestamp_ns: Some(due),
                    sequence,
                });
            }
        }
        Ok(Read::Frame {
            timestamp_ns,
            sequence,
        })
    }
}

/// The exposure time a FRAME line carries as `Xts=<ns>` (what the recorder writes; other
/// writers' frames have none and are stamped when read).
pub fn frame_timestamp(frame_line: &[u8]) -> Option<u64> {
    frame_parameter(frame_line, "Xts=")
}

/// The recorded time (`Xts`) of a Y4M file's first frame, if it has one and can be read.
pub fn first_frame_timestamp(path: &std::path::Path) -> Option<u64> {
    let file = File::open(path).ok()?;
    let mut reader = BufReader::new(file);
    let mut header = Vec::new();
    // Bounded reads: a header or frame line is a few dozen bytes.
    (&mut reader)
        .take(4096)
        .read_until(b'\n', &mut header)
        .ok()?;
    let mut line = Vec::new();
    (&mut reader).take(4096).read_until(b'\n', &mut line).ok()?;
    frame_timestamp(&line)
}

/// The live camera's sequence number a FRAME line carries as `Xseq=<n>` (the recorder's);
/// a replay publishes the frame under it, so the moment workers schedule their thresholds and
/// searches on the frames the live ones did.
pub fn frame_sequence(frame_line: &[u8]) -> Option<u64> {
    frame_parameter(frame_line, "Xseq=")
}

fn frame_parameter(frame_line: &[u8], key: &str) -> Option<u64> {
    std::str::from_utf8(frame_line)
        .ok()?
        .split_ascii_whitespace()
        .skip(1)
        .find_map(|p| p.strip_prefix(key))
        .and_then(|v| v.parse().ok())
}

/// Encodes grey frames as a Y4M stream (`Cmono`), for tests and for recording.
pub fn encode_mono(width: u32, height: u32, fps: u32, frames: &[&[u8]]) -> Vec<u8> {
    let mut out = format!("YUV4MPEG2 W{width} H{height} F{fps}:1 Ip A1:1 Cmono\n").into_bytes();
    for f in frames {
        out.extend_from_slice(b"FRAME\n");
        out.extend_from_slice(f);
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn frame_lines_give_their_recorded_time() {
        use super::frame_timestamp;
        assert_eq!(
            frame_timestamp(b"FRAME Xts=1764601234533333333 Xseq=7\n"),
            Some(1764601234533333333)
        );
        assert_eq!(
            super::frame_sequence(b"FRAME Xts=1764601234533333333 Xseq=7\n"),
            Some(7)
        );
        assert_eq!(super::frame_sequence(b"FRAME Xts=5\n"), None);
        assert_eq!(frame_timestamp(b"FRAME\n"), None);
        assert_eq!(frame_timestamp(b"FRAME Ixts=5 Xts=x\n"), None);
        assert_eq!(frame_timestamp(b"FRAMEXts=5\n"), None);
    }

    use super::*;

    #[test]
    fn headers() {
        let (w, h, f, fmt, c) =
            parse_header("YUV4MPEG2 W320 H240 F30000:1001 Ip A1:1 C420jpeg").unwrap();
        assert_eq!(
            (w, h, fmt, c),
            (320, 240, PixelFormat::Gray8, 2 * 160 * 120)
        );
        assert!((f.unwrap() - 29.97).abs() < 0.01);
        assert_eq!(
            parse_header("YUV4MPEG2 W3 H3 Cmono16").unwrap().3,
            PixelFormat::Gray16
        );
        assert_eq!(
            parse_header("YUV4MPEG2 W3 H3 C411").unwrap_err(),
            Y4mHeaderError::Colour("411".into())
        );
        assert_eq!(
            parse_header("YUV4MPEG W3 H3").unwrap_err(),
            Y4mHeaderError::NotY4m
        );
        assert_eq!(
            parse_header("YUV4MPEG2 W0 H3").unwrap_err(),
            Y4mHeaderError::Size {
                width: 0,
                height: 3
            }
        );
        assert!(matches!(
            parse_header("YUV4MPEG2 Wx H3").unwrap_err(),
            Y4mHeaderError::NotANumber { field: "width", .. }
        ));
    }

    #[test]
    fn a_restamped_replay_times_frames_by_index_or_recorded_time() {
        let dir = std::env::temp_dir().join(format!("y4m-restamp-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frame = vec![10u8; 12];
        // The replay started 10 s ago: no frame waits.
        let wall_ns = stereoscope_proto::messages::now_ns() - 10_000_000_000;
        let clock = |restamp| stereoscope_rig::schema::ReplayClock {
            recorded_ns: 5_000_000_000,
            wall_ns,
            speed: 1.0,
            restamp,
        };
        let stamps = |bytes: &[u8], restamp: bool| {
            let p = dir.join("clip.y4m");
            std::fs::write(&p, bytes).unwrap();
            let mut s = Y4mSource::open(p.to_str().unwrap(), false, false)
                .unwrap()
                .with_replay_clock(Some(clock(restamp)));
            let mut out = vec![0u8; 12];
            (0..3)
                .map(|i| match s.read(i, 0.0, &mut out).unwrap() {
                    Read::Frame { timestamp_ns, .. } => timestamp_ns,
                    Read::End => None,
                })
                .collect::<Vec<_>>()
        };
        // No recorded times: by index at the file's 25 fps from the clock's start.
        let plain = encode_mono(4, 3, 25, &[&frame, &frame, &frame]);
        assert_eq!(
            stamps(&plain, true),
            vec![
                Some(wall_ns),
                Some(wall_ns + 40_000_000),
                Some(wall_ns + 80_000_000)
            ]
        );
        // Not restamped, a file without times stays without.
        assert_eq!(stamps(&plain, false), vec![None, None, None]);
        // Recorded times: moved onto the replay clock when restamped, kept otherwise.
        let mut timed = b"YUV4MPEG2 W4 H3 F25:1 Ip A1:1 Cmono\n".to_vec();
        for t in [5_000_000_000u64, 5_050_000_000, 5_070_000_000] {
            timed.extend_from_slice(format!("FRAME Xts={t}\n").as_bytes());
            timed.extend_from_slice(&frame);
        }
        assert_eq!(
            stamps(&timed, true),
            vec![
                Some(wall_ns),
                Some(wall_ns + 50_000_000),
                Some(wall_ns + 70_000_000)
            ]
        );
        assert_eq!(
            stamps(&timed, false),
            vec![
                Some(5_000_000_000),
                Some(5_050_000_000),
                Some(5_070_000_000)
            ]
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn reads_frames_and_names_truncation() {
        let dir = std::env::temp_dir().join(format!("y4m-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = vec![10u8; 12];
        let b = vec![20u8; 12];
        let bytes = encode_mono(4, 3, 25, &[&a, &b]);
        let p = dir.join("ok.y4m");
        std::fs::write(&p, &bytes).unwrap();
        let mut s = Y4mSource::open(p.to_str().unwrap(), false, false).unwrap();
        let mut out = vec![0u8; 12];
        assert_eq!(
            s.read(0, 0.0, &mut out).unwrap(),
            Read::Frame {
                timestamp_ns: None,
                sequence: None
            }
        );
        assert_eq!(out, a);
        s.read(1, 0.0, &mut out).unwrap();
        assert_eq!(out, b);
        assert_eq!(s.read(2, 0.0, &mut out).unwrap(), Read::End);
        let cut = dir.join("cut.y4m");
        std::fs::write(&cut, &bytes[..bytes.len() - 5]).unwrap();
        let mut s = Y4mSource::open(cut.to_str().unwrap(), false, false).unwrap();
        s.read(0, 0.0, &mut out).unwrap();
        let err = s.read(1, 0.0, &mut out).unwrap_err();
        assert!(
            matches!(
                err,
                SourceError::BadFrame(BadFrame::Truncated {
                    frame: 1,
                    plane: "luma",
                    got: 7,
                    want: 12,
                    ..
                })
            ),
            "{err:?}"
        );
        let e = err.to_string();
        assert!(
            e.contains("cut.y4m") && e.contains("frame 1") && e.contains("7 of its 12"),
            "{e}"
        );
        // The partial frame skipped, the source ends at its last whole frame: never again
        // from frame 0 (5 good frames once gave 19 downstream).
        assert_eq!(s.read(2, 0.0, &mut out).unwrap(), Read::End);
        // Repeating, it starts again after the partial frame.
        let mut s = Y4mSource::open(cut.to_str().unwrap(), false, true).unwrap();
        s.read(0, 0.0, &mut out).unwrap();
        assert!(s.read(1, 0.0, &mut out).is_err());
        s.read(2, 0.0, &mut out).unwrap();
        assert_eq!(out, a);
        // Repeat starts again.
        let mut s = Y4mSource::open(p.to_str().unwrap(), false, true).unwrap();
        for _ in 0..3 {
            s.read(0, 0.0, &mut out).unwrap();
        }
        assert_eq!(out, a);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Property test: hostile stream headers and frames (cut, bit-flipped, with bytes inserted,
    /// removed or repeated, random) give an error, a skipped frame or the end — never a panic
    /// or an allocation the header claims (docs/reliability.md).
    #[test]
    fn hostile_y4m_bytes_never_panic_the_reader() {
        use stereoscope_numeric::random::mutations;
        let header = "YUV4MPEG2 W8 H6 F30:1 Ip A1:1 C420jpeg";
        for seed in 0..10 {
            for m in mutations(header.as_bytes(), 2_000, seed) {
                let _ = parse_header(&String::from_utf8_lossy(&m));
            }
        }
        let frame = vec![7u8; 48];
        let bytes = encode_mono(8, 6, 30, &[&frame, &frame, &frame]);
        let dir = std::env::temp_dir().join(format!("y4m-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.y4m");
        let mut out = vec![0u8; 48];
        for (i, m) in mutations(&bytes, 3_000, 42).into_iter().enumerate() {
            std::fs::write(&path, &m).unwrap();
            let Ok(mut s) = Y4mSource::open(path.to_str().unwrap(), false, i % 2 == 0) else {
                continue;
            };
            if s.size() != (8, 6) {
                continue;
            }
            // Bounded: a repeating source of garbage must not read for ever either.
            for k in 0..10 {
                match s.read(k, 0.0, &mut out) {
                    Ok(Read::End)
                    | Err(SourceError::Io { .. } | SourceError::NoFrameLine { .. }) => break,
                    _ => {}
                }
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
