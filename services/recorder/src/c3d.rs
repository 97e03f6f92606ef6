//! C3D files (not in the thesis): the motion-capture exchange format biomechanics and
//! animation tools read — `stereoscope export --format c3d` (docs/recording.md).
//!
//! A minimal, complete writer for 3D points and a reader for what it writes (Intel byte order,
//! floating-point points, no analog channels). The crates.io crate `c3dio` 0.8 was checked
//! first and not used: it panics on some paths (`unwrap` on a file name without extension),
//! keeps frame counts in 16 bits, and decodes `TRIAL:ACTUAL_END_FIELD` with a 65 535 instead of
//! a 65 536 multiplier.
//!
//! Layout (512-byte blocks, numbered from 1; every 16-bit word little-endian):
//! - block 1, the header: byte 0 = 2 (parameters start at block 2), byte 1 = 0x50; words 2–6 =
//!   points per frame, analog samples per frame (0), first frame (1), last frame (at most
//!   65 535; the true count is in the parameters), interpolation gap (0); bytes 12–15 = POINT
//!   scale as f32, negative = floating-point data; word 9 = first data block; word 10 = analog
//!   samples per point frame (1, none used); bytes 20–23 = frame rate as f32.
//! - blocks 2…: the parameter section: bytes `01 50 <blocks> 54` (0x54 = 84, Intel), then
//!   group and parameter records (`[name length, ±group id, name, i16 offset to the next
//!   record, …]`), the last record's offset 0, zeros after it. Groups POINT (USED, SCALE, RATE,
//!   DATA_START, FRAMES, LONG_FRAMES, LABELS, DESCRIPTIONS, UNITS), ANALOG (USED = 0, RATE),
//!   TRIAL (ACTUAL_START_FIELD, ACTUAL_END_FIELD: 32-bit frame numbers as two words).
//! - then the data, unpadded: per frame, per point, x, y, z (millimetres) and a fourth f32 whose integer
//!   value packs the cameras that saw the point (high byte, bit i = the rig's camera i) over a
//!   residual byte (millimetres, 1–255 for a measured point; 0 with no camera bits: computed
//!   or filled, not measured); −1 marks a point not seen in that frame (x = y = z = 0).

use std::collections::BTreeMap;

const BLOCK: usize = 512;
const PROCESSOR_INTEL: u8 = 84;
/// The POINT scale: negative = floating-point coordinates, 1 mm per residual unit.
const POINT_SCALE: f32 = -1.0;

/// One point of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct C3dPoint {
    pub xyz_mm: [f32; 3],
    /// Bit i: camera i of the rig saw it (cameras 0–6).
    pub cameras: u8,
    /// The point's residual in millimetres, 1–255 for a measured point; 0 for one that was
    /// computed (a body's origin, a heading marker) or filled in a gap (C3D's convention: a
    /// zero residual and no camera bits mark a point that was not measured).
    pub residual_mm: u8,
}

/// A trial: labelled points at a constant frame rate; `frames[f][p]` is point `p` in frame `f`,
/// `None` where it was not seen.
#[derive(Debug, Clone, PartialEq)]
pub struct C3dTrial {
    pub frame_rate_hz: f32,
    pub labels: Vec<String>,
    pub descriptions: Vec<String>,
    pub frames: Vec<Vec<Option<C3dPoint>>>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum C3dError {
    #[error("C3D: {0}")]
    Invalid(String),
    #[error("C3D file: {0}")]
    Corrupt(String),
}

fn invalid(s: impl Into<String>) -> C3dError {
    C3dError::Invalid(s.into())
}

/// A parameter's value.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    /// Fixed-width strings, padded with spaces (`dims = [width, count]`, or `[width]`).
    Chars(Vec<String>, bool),
    Ints(Vec<i16>, bool),
    Floats(Vec<f32>, bool),
}

impl Value {
    fn scalar_int(v: i16) -> Self {
        Value::Ints(vec![v], false)
    }
    fn scalar_float(v: f32) -> Self {
        Value::Floats(vec![v], false)
    }
}

/// A numeric parameter's type, dimensions and values.
fn numbers(
    body: &mut Vec<u8>,
    ty: u8,
    array: bool,
    values: impl ExactSizeIterator<Item = Vec<u8>>,
) {
    body.push(ty);
    if array {
        body.extend([1, values.len() as u8]);
    } else {
        body.push(0);
    }
    for v in values {
        body.extend(v);
    }
}

/// Encodes one parameter record (without its offset's final value for the last record).
fn param_record(name: &str, group: i8, value: &Value, description: &str) -> Vec<u8> {
    let mut body = Vec::new();
    match value {
        Value::Chars(strings, array) => {
            let width = strings.iter().map(|s| s.len()).max().unwrap_or(0).max(1);
            body.push((-1i8) as u8);
            if *array {
                body.extend([2, width as u8, strings.len() as u8]);
            } else {
                body.extend([1, width as u8]);
            }
            for s in strings {
                body.extend(s.as_bytes());
                body.extend(std::iter::repeat_n(b' ', width - s.len()));
            }
        }
        Value::Ints(v, array) => numbers(
            &mut body,
            2,
            *array,
            v.iter().map(|x| x.to_le_bytes().to_vec()),
        ),
        Value::Floats(v, array) => numbers(
            &mut body,
            4,
            *array,
            v.iter().map(|x| x.to_le_bytes().to_vec()),
        ),
    }
    body.push(description.len() as u8);
    body.extend(description.as_bytes());
    let mut rec = vec![name.len() as u8, group as u8];
    rec.extend(name.as_bytes());
    rec.extend(((body.len() + 2) as i16).to_le_bytes());
    rec.extend(body);
    rec
}

fn group_record(name: &str, id: i8, description: &str) -> Vec<u8> {
    let mut rec = vec![name.len() as u8, (-id) as u8];
    rec.extend(name.as_bytes());
    rec.extend(((description.len() + 3) as i16).to_le_bytes());
    rec.push(description.len() as u8);
    rec.extend(description.as_bytes());
    rec
}

fn check_text(what: &str, s: &str) -> Result<(), C3dError> {
    if !s.is_ascii() || s.len() > 255 {
        return Err(invalid(format!(
            "{what} {s:?} must be ASCII and at most 255 characters"
        )));
    }
    Ok(())
}

/// The file's bytes.
pub fn write(trial: &C3dTrial) -> Result<Vec<u8>, C3dError> {
    let n_points = trial.labels.len();
    if n_points > 255 {
        return Err(invalid(format!(
            "{n_points} points; this writer takes at most 255 (one POINT:LABELS parameter)"
        )));
    }
    if trial.descriptions.len() != n_points {
        return Err(invalid(format!(
            "{} descriptions for {n_points} labels",
            trial.descriptions.len()
        )));
    }
    for l in &trial.labels {
        check_text("label", l)?;
    }
    for d in &trial.descriptions {
        check_text("description", d)?;
    }
    if !(trial.frame_rate_hz.is_finite() && trial.frame_rate_hz > 0.0) {
        return Err(invalid(format!(
            "frame rate {} Hz must be a finite number above zero",
            trial.frame_rate_hz
        )));
    }
    if let Some((f, row)) = trial
        .frames
        .iter()
        .enumerate()
        .find(|(_, r)| r.len() != n_points)
    {
        return Err(invalid(format!(
            "frame {f} has {} points, the trial {n_points}",
            row.len()
        )));
    }
    let n_frames = trial.frames.len();
    if n_frames == 0 {
        return Err(invalid("no frames"));
    }
    if n_frames > i32::MAX as usize {
        return Err(invalid(format!("{n_frames} frames: too many")));
    }
    // The parameters; DATA_START is patched once the section's size is known.
    let labels_or_blank = |v: &[String]| {
        if v.is_empty() {
            vec![String::new()]
        } else {
            v.to_vec()
        }
    };
    let frames_word = n_frames.min(u16::MAX as usize) as u16 as i16;
    let (lo, hi) = (
        (n_frames & 0xFFFF) as u16 as i16,
        (n_frames >> 16) as u16 as i16,
    );
    let params: Vec<(&str, i8, Value, &str)> = vec![
        (
            "USED",
            1,
            Value::scalar_int(n_points as i16),
            "points per frame",
        ),
        (
            "SCALE",
            1,
            Value::scalar_float(POINT_SCALE),
            "negative: floating-point data",
        ),
        (
            "RATE",
            1,
            Value::scalar_float(trial.frame_rate_hz),
            "frames per second",
        ),
        (
            "DATA_START",
            1,
            Value::scalar_int(0),
            "first block of the data",
        ),
        (
            "FRAMES",
            1,
            Value::scalar_int(frames_word),
            "frames (unsigned; see TRIAL)",
        ),
        (
            "LONG_FRAMES",
            1,
            Value::scalar_float(n_frames as f32),
            "frames",
        ),
        (
            "LABELS",
            1,
            Value::Chars(labels_or_blank(&trial.labels), true),
            "",
        ),
        (
            "DESCRIPTIONS",
            1,
            Value::Chars(labels_or_blank(&trial.descriptions), true),
            "",
        ),
        ("UNITS", 1, Value::Chars(vec!["mm".into()], false), ""),
        ("USED", 2, Value::scalar_int(0), "analog channels"),
        ("RATE", 2, Value::scalar_float(trial.frame_rate_hz), ""),
        (
            "ACTUAL_START_FIELD",
            3,
            Value::Ints(vec![1, 0], true),
            "first frame, 32 bits",
        ),
        (
            "ACTUAL_END_FIELD",
            3,
            Value::Ints(vec![lo, hi], true),
            "last frame, 32 bits",
        ),
    ];
    let encode = |data_start: i16| -> Vec<u8> {
        let mut records: Vec<Vec<u8>> = vec![
            group_record("POINT", 1, "3D points"),
            group_record("ANALOG", 2, "analog channels (none)"),
            group_record("TRIAL", 3, "frame range"),
        ];
        for (name, group, value, desc) in &params {
            let value = if *name == "DATA_START" {
                Value::scalar_int(data_start)
            } else {
                value.clone()
            };
            records.push(param_record(name, *group, &value, desc));
        }
        // The last record's offset is 0: the end of the parameters.
        if let Some(last) = records.last_mut() {
            let at = 2 + last[0] as usize;
            last[at..at + 2].copy_from_slice(&0i16.to_le_bytes());
        }
        let mut section = vec![0x01, 0x50, 0, PROCESSOR_INTEL];
        for r in records {
            section.extend(r);
        }
        let blocks = section.len().div_ceil(BLOCK);
        section.resize(blocks * BLOCK, 0);
        section[2] = blocks as u8;
        section
    };
    let section_len = encode(0).len();
    let data_block = 2 + section_len / BLOCK;
    if data_block > i16::MAX as usize || section_len / BLOCK > 255 {
        return Err(invalid("the parameter section is too large"));
    }
    let section = encode(data_block as i16);

    let mut header = vec![0u8; BLOCK];
    header[0] = 2;
    header[1] = 0x50;
    let word = |h: &mut Vec<u8>, index: usize, v: u16| {
        h[2 * index..2 * index + 2].copy_from_slice(&v.to_le_bytes())
    };
    word(&mut header, 1, n_points as u16);
    word(&mut header, 2, 0);
    word(&mut header, 3, 1);
    word(&mut header, 4, frames_word as u16);
    word(&mut header, 5, 0);
    header[12..16].copy_from_slice(&POINT_SCALE.to_le_bytes());
    word(&mut header, 8, data_block as u16);
    word(&mut header, 9, 1);
    header[20..24].copy_from_slice(&trial.frame_rate_hz.to_le_bytes());

    let mut out = header;
    out.extend(section);
    out.reserve(n_frames * n_points * 16 + BLOCK);
    for row in &trial.frames {
        for p in row {
            match p {
                Some(p) => {
                    for v in p.xyz_mm {
                        out.extend(v.to_le_bytes());
                    }
                    let packed =
                        ((u16::from(p.cameras & 0x7F) << 8) | u16::from(p.residual_mm)) as f32;
                    out.extend(packed.to_le_bytes());
                }
                None => {
                    for v in [0.0f32, 0.0, 0.0, -1.0] {
                        out.extend(v.to_le_bytes());
                    }
                }
            }
        }
    }
    // No padding after the data: a reader that counts frames by the file's size (ezc3d, past
    // 65 535 frames) would read padding as frames.
    Ok(out)
}

/// A parameter record as read: group id, name, type, dimensions, data.
type RawParam = (i8, String, i8, Vec<usize>, Vec<u8>);

/// Reads what [`write()`] writes (Intel byte order, floating-point points); every problem is
/// named, none panics.
pub fn read(bytes: &[u8]) -> Result<C3dTrial, C3dError> {
    let corrupt = |s: String| C3dError::Corrupt(s);
    let at = |pos: usize, len: usize| -> Result<&[u8], C3dError> {
        bytes.get(pos..pos + len).ok_or_else(|| {
            corrupt(format!(
                "ends at byte {} (needed {})",
                bytes.len(),
                pos + len
            ))
        })
    };
    let u16_at = |pos: usize| -> Result<u16, C3dError> {
        let b = at(pos, 2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    };
    let f32_at = |pos: usize| -> Result<f32, C3dError> {
        let b = at(pos, 4)?;
        Ok(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let header = at(0, BLOCK)?;
    if header[1] != 0x50 {
        return Err(corrupt(format!(
            "byte 1 is {:#04x}, not the C3D key 0x50",
            header[1]
        )));
    }
    let param_start = (usize::from(header[0]).max(1) - 1) * BLOCK;
    let p = at(param_start, 4)?;
    if p[3] != PROCESSOR_INTEL {
        return Err(corrupt(format!(
            "processor type {} (only Intel, 84, is read)",
            p[3]
        )));
    }
    // Records.
    let mut groups: BTreeMap<i8, String> = BTreeMap::new();
    let mut raw: Vec<RawParam> = Vec::new();
    let mut pos = param_start + 4;
    let end = param_start + usize::from(p[2]) * BLOCK;
    while pos + 2 <= end {
        // A negative name length marks a locked record.
        let len = usize::from((at(pos, 1)?[0] as i8).unsigned_abs());
        if len == 0 {
            break;
        }
        let id = at(pos + 1, 1)?[0] as i8;
        let name = String::from_utf8_lossy(at(pos + 2, len)?).to_string();
        let off_pos = pos + 2 + len;
        let offset = u16_at(off_pos)? as i16;
        if id < 0 {
            // Group ids are 1–127; -128 has no positive twin (negating it overflowed).
            if let Some(group) = id.checked_neg() {
                groups.insert(group, name);
            }
        } else {
            let ty = at(off_pos + 2, 1)?[0] as i8;
            let nd = usize::from(at(off_pos + 3, 1)?[0]);
            let dims: Vec<usize> = at(off_pos + 4, nd)?.iter().map(|&d| d as usize).collect();
            let elem = usize::from(ty.unsigned_abs());
            // Checked: up to 255 dimensions of up to 255 overflow a usize (the property test
            // found that panic); the bytes must then be in the file anyway.
            let bytes = dims
                .iter()
                .try_fold(elem, |a, &d| a.checked_mul(d))
                .ok_or_else(|| {
                    corrupt(format!("parameter {name}: dimensions {dims:?} overflow"))
                })?;
            let data = at(off_pos + 4 + nd, bytes)?.to_vec();
            raw.push((id, name, ty, dims, data));
        }
        if offset <= 0 {
            break;
        }
        pos = off_pos + offset as usize;
    }
    let find = |group: &str, name: &str| {
        raw.iter().find(|(id, n, ..)| {
            n.eq_ignore_ascii_case(name)
                && groups
                    .get(id)
                    .is_some_and(|g| g.eq_ignore_ascii_case(group))
        })
    };
    let int = |group: &str, name: &str| -> Result<Vec<u16>, C3dError> {
        let (_, _, ty, _, data) =
            find(group, name).ok_or_else(|| corrupt(format!("no {group}:{name} parameter")))?;
        if *ty != 2 {
            return Err(corrupt(format!("{group}:{name} is not an integer")));
        }
        Ok(data
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect())
    };
    let strings = |group: &str, name: &str| -> Result<Vec<String>, C3dError> {
        let (_, _, ty, dims, data) =
            find(group, name).ok_or_else(|| corrupt(format!("no {group}:{name} parameter")))?;
        if *ty != -1 {
            return Err(corrupt(format!("{group}:{name} is not text")));
        }
        let width = dims.first().copied().unwrap_or(0).max(1);
        Ok(data
            .chunks(width)
            .map(|c| String::from_utf8_lossy(c).trim_end().to_string())
            .collect())
    };
    let n_points = usize::from(u16_at(2)?);
    let scale = f32_at(12)?;
    if scale >= 0.0 {
        return Err(corrupt(format!(
            "POINT scale {scale}: only floating-point data is read"
        )));
    }
    let data_block = usize::from(u16_at(16)?);
    let rate = f32_at(20)?;
    let end_field = int("TRIAL", "ACTUAL_END_FIELD")?;
    let start_field = int("TRIAL", "ACTUAL_START_FIELD")?;
    let frame_no = |w: &[u16]| -> usize {
        usize::from(w.first().copied().unwrap_or(0))
            | (usize::from(w.get(1).copied().unwrap_or(0)) << 16)
    };
    let n_frames = (frame_no(&end_field) + 1)
        .checked_sub(frame_no(&start_field))
        .ok_or_else(|| corrupt("TRIAL:ACTUAL_END_FIELD before its start".into()))?;
    let mut labels = strings("POINT", "LABELS")?;
    let mut descriptions = strings("POINT", "DESCRIPTIONS")?;
    labels.truncate(n_points);
    descriptions.truncate(n_points);
    let data_at = (data_block.max(1) - 1) * BLOCK;
    let needed = n_frames * n_points * 16;
    let data = at(data_at, needed)?;
    let mut frames = Vec::with_capacity(n_frames);
    for f in 0..n_frames {
        let mut row = Vec::with_capacity(n_points);
        for p in 0..n_points {
            let base = (f * n_points + p) * 16;
            let v = |k: usize| {
                let b = &data[base + 4 * k..base + 4 * k + 4];
                f32::from_le_bytes([b[0], b[1], b[2], b[3]])
            };
            row.push(if v(3) < 0.0 {
                None
            } else {
                Some(C3dPoint {
                    xyz_mm: [v(0), v(1), v(2)],
                    cameras: ((v(3) as u32 >> 8) & 0x7F) as u8,
                    residual_mm: (v(3) as u32 & 0xFF) as u8,
                })
            });
        }
        frames.push(row);
    }
    Ok(C3dTrial {
        frame_rate_hz: rate,
        labels,
        descriptions,
        frames,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(frames: usize) -> C3dTrial {
        C3dTrial {
            frame_rate_hz: 120.0,
            labels: vec!["obj1".into(), "obj1_heading".into(), "obj2".into()],
            descriptions: vec!["object 1".into(), "heading".into(), "object 2".into()],
            frames: (0..frames)
                .map(|f| {
                    vec![
                        Some(C3dPoint {
                            xyz_mm: [f as f32, -2.5, 1000.25],
                            cameras: 0b11,
                            residual_mm: 1,
                        }),
                        (f % 3 != 0).then_some(C3dPoint {
                            xyz_mm: [f as f32 + 100.0, -2.5, 1000.25],
                            cameras: 0b01,
                            residual_mm: 7,
                        }),
                        None,
                    ]
                })
                .collect(),
        }
    }

    #[test]
    fn what_is_written_reads_back_exactly() {
        let t = trial(10);
        let bytes = write(&t).unwrap();
        // Header and parameters in whole blocks, then 10 frames × 3 points × 16 bytes.
        assert_eq!(bytes.len() % BLOCK, 10 * 3 * 16 % BLOCK);
        assert_eq!(&bytes[..2], &[2, 0x50]);
        assert_eq!(read(&bytes).unwrap(), t);
    }

    #[test]
    fn more_frames_than_16_bits_keep_their_count() {
        let t = trial(70_000);
        let bytes = write(&t).unwrap();
        let back = read(&bytes).unwrap();
        assert_eq!(back.frames.len(), 70_000);
        assert_eq!(back.frames[69_999], t.frames[69_999]);
        // The header's 16-bit last frame saturates; the parameters hold the truth.
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), u16::MAX);
    }

    #[test]
    fn bad_trials_are_named_not_written() {
        let mut t = trial(2);
        t.frames[1].pop();
        assert!(
            write(&t)
                .unwrap_err()
                .to_string()
                .contains("frame 1 has 2 points")
        );
        let mut t = trial(2);
        t.frame_rate_hz = f32::NAN;
        assert!(write(&t).unwrap_err().to_string().contains("frame rate"));
        let mut t = trial(2);
        t.labels[0] = "ob\u{e9}".into();
        assert!(write(&t).unwrap_err().to_string().contains("ASCII"));
        let mut t = trial(0);
        t.frames.clear();
        assert!(write(&t).unwrap_err().to_string().contains("no frames"));
    }

    #[test]
    fn truncated_or_foreign_files_are_named_not_panicked_on() {
        let bytes = write(&trial(5)).unwrap();
        for cut in [0, 1, 100, 512, 600, 1024, bytes.len() - 1] {
            assert!(read(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut other = bytes.clone();
        other[1] = 0;
        assert!(read(&other).unwrap_err().to_string().contains("0x50"));
    }

    /// Property test: 30 000 hostile variants of a written file (cut, bit-flipped, with bytes
    /// inserted, removed or repeated, random) read to an error or a trial — never a panic, and
    /// never an allocation a header merely claims (docs/reliability.md).
    #[test]
    fn hostile_c3d_bytes_never_panic_the_reader() {
        use stereoscope_numeric::random::mutations;
        let trial = C3dTrial {
            frame_rate_hz: 30.0,
            labels: vec!["obj1".into(), "obj2".into()],
            descriptions: vec!["object 1".into(), "object 2".into()],
            frames: (0..20)
                .map(|f| {
                    vec![
                        Some(C3dPoint {
                            xyz_mm: [f as f32, 2.0, 3.0],
                            cameras: 3,
                            residual_mm: 1,
                        }),
                        None,
                    ]
                })
                .collect(),
        };
        let bytes = write(&trial).unwrap();
        let mut read_ok = 0;
        for seed in 0..10 {
            for m in mutations(&bytes, 3_000, seed) {
                if read(&m).is_ok() {
                    read_ok += 1;
                }
            }
        }
        assert!(read_ok > 0);
    }
}
