//! The serial-link packets, encoder and decoder both (`docs/protocol.md`, "Serial link").
//!
//! **Legacy** — the thesis's packet (`send_serial_3Dx`, 9600 baud 8N1), 10 bytes:
//! `0x1B, X hi, X lo, Y hi, Y lo, Z hi, Z lo, θ hi, θ lo, 0x00`; X, Y, Z signed 16-bit
//! centimetres (two's complement, big-endian), θ unsigned hundredths of a degree, 0–35999.
//! It has no object id and no checksum, and a data byte may equal 0x1B or 0x00, so a receiver
//! that joins mid-stream can lock onto a false frame: kept for old receivers only.
//!
//! **Framed** — for new receivers: a 22-byte payload (version, object id, sequence number,
//! millimetre positions, heading, flags) followed by its CRC-16/CCITT-FALSE, COBS-encoded so
//! that 0x00 never occurs inside, and ended by a 0x00 delimiter. A receiver resynchronises at
//! the next 0x00 whatever it missed.
//!
//! Values that do not fit (a position beyond ±327.67 m in the legacy packet's centimetres, or
//! beyond ±2147 km in millimetres) are clamped to the nearest representable value and reported,
//! never wrapped.

use std::fmt;

/// Which packet a serial link carries: the rig file's `mode`, the serial service's `--mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SerialMode {
    /// The thesis's 10-byte packet, one object.
    Legacy,
    /// Object id, sequence number, CRC, COBS framing (the default).
    #[default]
    Framed,
}

impl SerialMode {
    pub fn as_str(self) -> &'static str {
        match self {
            SerialMode::Legacy => "legacy",
            SerialMode::Framed => "framed",
        }
    }
}

impl std::fmt::Display for SerialMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A word that is not a [`SerialMode`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownSerialMode(pub String);

impl std::fmt::Display for UnknownSerialMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?} is not legacy or framed", self.0)
    }
}

impl std::error::Error for UnknownSerialMode {}

impl std::str::FromStr for SerialMode {
    type Err = UnknownSerialMode;
    fn from_str(s: &str) -> Result<Self, UnknownSerialMode> {
        match s {
            "legacy" => Ok(SerialMode::Legacy),
            "framed" => Ok(SerialMode::Framed),
            o => Err(UnknownSerialMode(o.to_string())),
        }
    }
}

/// A pose as the serial link carries it: position in metres, heading in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SerialPose {
    pub object_id: u16,
    pub position_m: [f64; 3],
    pub heading_deg: f64,
}

/// Which fields had to be clamped (bit 0: x, bit 1: y, bit 2: z), and non-finite inputs
/// (bit 3), which are sent as 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Clamped(pub u8);

impl Clamped {
    pub fn any(self) -> bool {
        self.0 != 0
    }

    pub fn count(self) -> u32 {
        (self.0 & 0b111).count_ones()
    }
}

fn to_fixed(v: f64, scale: f64, min: f64, max: f64, bit: u8, clamped: &mut Clamped) -> f64 {
    if !v.is_finite() {
        clamped.0 |= 8;
        return 0.0;
    }
    let s = (v * scale).round();
    if s < min || s > max {
        clamped.0 |= bit;
    }
    s.clamp(min, max)
}

/// The heading in hundredths of a degree, 0–35999 (wrapped: a heading is an angle).
pub fn heading_centideg(heading_deg: f64) -> u16 {
    if !heading_deg.is_finite() {
        return 0;
    }
    let c = (heading_deg.rem_euclid(360.0) * 100.0).round() as u32;
    (c % 36000) as u16
}

/// The thesis's packet, decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LegacyPacket {
    pub x_cm: i16,
    pub y_cm: i16,
    pub z_cm: i16,
    pub heading_centideg: u16,
}

pub const LEGACY_START: u8 = 0x1B;
pub const LEGACY_END: u8 = 0x00;
pub const LEGACY_LEN: usize = 10;

/// Encodes the thesis's 10-byte packet.
pub fn encode_legacy(pose: &SerialPose) -> ([u8; LEGACY_LEN], Clamped) {
    let mut c = Clamped::default();
    let (lo, hi) = (i16::MIN as f64, i16::MAX as f64);
    let x = to_fixed(pose.position_m[0], 100.0, lo, hi, 1, &mut c) as i16;
    let y = to_fixed(pose.position_m[1], 100.0, lo, hi, 2, &mut c) as i16;
    let z = to_fixed(pose.position_m[2], 100.0, lo, hi, 4, &mut c) as i16;
    let t = heading_centideg(pose.heading_deg);
    let mut p = [0u8; LEGACY_LEN];
    p[0] = LEGACY_START;
    p[1..3].copy_from_slice(&x.to_be_bytes());
    p[3..5].copy_from_slice(&y.to_be_bytes());
    p[5..7].copy_from_slice(&z.to_be_bytes());
    p[7..9].copy_from_slice(&t.to_be_bytes());
    p[9] = LEGACY_END;
    (p, c)
}

/// Why bytes are not a packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SerialError {
    /// Legacy: not `0x1B … 0x00`, or the heading is 36000 or more.
    BadLegacyFrame,
    /// Framed: the COBS encoding is broken.
    BadCobs,
    /// Framed: the decoded payload has the wrong length.
    BadLength { got: usize, expected: usize },
    /// Framed: the checksum does not match.
    BadCrc { got: u16, computed: u16 },
    /// Framed: a version this decoder does not know.
    UnknownVersion(u8),
}

impl fmt::Display for SerialError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SerialError::BadLegacyFrame => {
                write!(f, "not a legacy packet (0x1B … 0x00, heading < 36000)")
            }
            SerialError::BadCobs => write!(f, "broken COBS encoding"),
            SerialError::BadLength { got, expected } => {
                write!(f, "payload of {got} bytes, expected {expected}")
            }
            SerialError::BadCrc { got, computed } => {
                write!(f, "CRC {got:#06x} does not match {computed:#06x}")
            }
            SerialError::UnknownVersion(v) => write!(f, "unknown packet version {v}"),
        }
    }
}

impl std::error::Error for SerialError {}

/// Decodes one legacy packet.
pub fn decode_legacy(b: &[u8; LEGACY_LEN]) -> Result<LegacyPacket, SerialError> {
    let t = u16::from_be_bytes([b[7], b[8]]);
    if b[0] != LEGACY_START || b[9] != LEGACY_END || t >= 36000 {
        return Err(SerialError::BadLegacyFrame);
    }
    Ok(LegacyPacket {
        x_cm: i16::from_be_bytes([b[1], b[2]]),
        y_cm: i16::from_be_bytes([b[3], b[4]]),
        z_cm: i16::from_be_bytes([b[5], b[6]]),
        heading_centideg: t,
    })
}

/// Finds legacy packets in a byte stream: a window starting with 0x1B and ending with 0x00
/// 9 bytes later (heading valid); otherwise it slides by one byte. Can lock onto a false frame
/// when data bytes look like the markers — the legacy format's flaw.
#[derive(Debug, Default, Clone)]
pub struct LegacyDecoder {
    buf: Vec<u8>,
}

impl LegacyDecoder {
    pub fn push(&mut self, bytes: &[u8]) -> Vec<LegacyPacket> {
        self.buf.extend_from_slice(bytes);
        let mut out = Vec::new();
        let mut i = 0;
        while i + LEGACY_LEN <= self.buf.len() {
            let mut frame = [0u8; LEGACY_LEN];
            frame.copy_from_slice(&self.buf[i..i + LEGACY_LEN]);
            match decode_legacy(&frame) {
                Ok(p) => {
                    out.push(p);
                    i += LEGACY_LEN;
                }
                Err(_) => i += 1,
            }
        }
        self.buf.drain(..i);
        out
    }
}

/// The framed packet's fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FramedPacket {
    pub object_id: u16,
    /// Counts packets per link, wrapping at 65536: a gap means lost packets.
    pub sequence: u16,
    pub x_mm: i32,
    pub y_mm: i32,
    pub z_mm: i32,
    pub heading_centideg: u16,
    /// Bit 0–2: x, y, z clamped; bit 3: a non-finite value was sent as 0.
    pub flags: u8,
}

pub const FRAMED_VERSION: u8 = 1;
/// Payload bytes before the CRC: version 1 + id 2 + seq 2 + x, y, z 4 each + heading 2 + flags 1.
pub const FRAMED_PAYLOAD_LEN: usize = 20;

/// CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final xor).
pub fn crc16_ccitt_false(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// COBS encoding (no zero bytes in the output).
pub fn cobs_encode(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + data.len() / 254 + 2);
    let mut code_at = out.len();
    out.push(0);
    let mut code = 1u8;
    for &b in data {
        if b == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(b);
            code += 1;
            if code == 0xFF {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out
}

/// COBS decoding; `None` if the input is not a valid encoding.
pub fn cobs_decode(data: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(data.len());
    let mut i = 0;
    while i < data.len() {
        let code = data[i] as usize;
        if code == 0 || i + code > data.len() {
            return None;
        }
        let block = &data[i + 1..i + code];
        if block.contains(&0) {
            return None;
        }
        out.extend_from_slice(block);
        i += code;
        if code < 0xFF && i < data.len() {
            out.push(0);
        }
    }
    Some(out)
}

/// Encodes a framed packet: COBS(payload ‖ CRC) followed by the 0x00 delimiter.
pub fn encode_framed(pose: &SerialPose, sequence: u16) -> (Vec<u8>, Clamped) {
    let mut c = Clamped::default();
    let (lo, hi) = (i32::MIN as f64, i32::MAX as f64);
    let x = to_fixed(pose.position_m[0], 1000.0, lo, hi, 1, &mut c) as i32;
    let y = to_fixed(pose.position_m[1], 1000.0, lo, hi, 2, &mut c) as i32;
    let z = to_fixed(pose.position_m[2], 1000.0, lo, hi, 4, &mut c) as i32;
    let mut payload = Vec::with_capacity(FRAMED_PAYLOAD_LEN + 2);
    payload.push(FRAMED_VERSION);
    payload.extend_from_slice(&pose.object_id.to_be_bytes());
    payload.extend_from_slice(&sequence.to_be_bytes());
    payload.extend_from_slice(&x.to_be_bytes());
    payload.extend_from_slice(&y.to_be_bytes());
    payload.extend_from_slice(&z.to_be_bytes());
    payload.extend_from_slice(&heading_centideg(pose.heading_deg).to_be_bytes());
    payload.push(c.0);
    let crc = crc16_ccitt_false(&payload);
    payload.extend_from_slice(&crc.to_be_bytes());
    let mut out = cobs_encode(&payload);
    out.push(0);
    (out, c)
}

/// Decodes one frame's bytes (between delimiters, without the 0x00).
pub fn decode_framed(frame: &[u8]) -> Result<FramedPacket, SerialError> {
    let p = cobs_decode(frame).ok_or(SerialError::BadCobs)?;
    if p.len() != FRAMED_PAYLOAD_LEN + 2 {
        return Err(SerialError::BadLength {
            got: p.len(),
            expected: FRAMED_PAYLOAD_LEN + 2,
        });
    }
    let got = u16::from_be_bytes([p[FRAMED_PAYLOAD_LEN], p[FRAMED_PAYLOAD_LEN + 1]]);
    let computed = crc16_ccitt_false(&p[..FRAMED_PAYLOAD_LEN]);
    if got != computed {
        return Err(SerialError::BadCrc { got, computed });
    }
    if p[0] != FRAMED_VERSION {
        return Err(SerialError::UnknownVersion(p[0]));
    }
    let i32_at = |k: usize| i32::from_be_bytes([p[k], p[k + 1], p[k + 2], p[k + 3]]);
    Ok(FramedPacket {
        object_id: u16::from_be_bytes([p[1], p[2]]),
        sequence: u16::from_be_bytes([p[3], p[4]]),
        x_mm: i32_at(5),
        y_mm: i32_at(9),
        z_mm: i32_at(13),
        heading_centideg: u16::from_be_bytes([p[17], p[18]]),
        flags: p[19],
    })
}

/// Splits a byte stream into framed packets at 0x00 delimiters. Bad frames are returned as
/// errors and skipped; the stream resynchronises at the next delimiter.
#[derive(Debug, Default, Clone)]
pub struct FramedDecoder {
    buf: Vec<u8>,
}

impl FramedDecoder {
    /// Longest frame kept while waiting for a delimiter (a garbage stream cannot grow the
    /// buffer without bound).
    pub const MAX_FRAME: usize = 64;

    pub fn push(&mut self, bytes: &[u8]) -> Vec<Result<FramedPacket, SerialError>> {
        let mut out = Vec::new();
        for &b in bytes {
            if b == 0 {
                if !self.buf.is_empty() {
                    out.push(decode_framed(&self.buf));
                    self.buf.clear();
                }
            } else if self.buf.len() < Self::MAX_FRAME {
                self.buf.push(b);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(x: f64, y: f64, z: f64, h: f64) -> SerialPose {
        SerialPose {
            object_id: 7,
            position_m: [x, y, z],
            heading_deg: h,
        }
    }

    #[test]
    fn legacy_packet_is_the_thesis_layout() {
        let (p, c) = encode_legacy(&pose(0.2, -1.5, 2.775, 123.456));
        assert_eq!(
            p,
            [0x1B, 0x00, 20, 0xFF, 0x6A, 0x01, 0x16, 0x30, 0x3A, 0x00]
        );
        assert!(!c.any());
        assert_eq!(
            decode_legacy(&p).unwrap(),
            LegacyPacket {
                x_cm: 20,
                y_cm: -150,
                z_cm: 278,
                heading_centideg: 12346
            }
        );
    }

    #[test]
    fn out_of_range_values_are_clamped_and_counted_not_wrapped() {
        let (p, c) = encode_legacy(&pose(400.0, -400.0, 1.0, -90.0));
        let d = decode_legacy(&p).unwrap();
        assert_eq!((d.x_cm, d.y_cm, d.z_cm), (i16::MAX, i16::MIN, 100));
        assert_eq!(c.count(), 2);
        assert_eq!(d.heading_centideg, 27000);
        assert_eq!(heading_centideg(359.999), 0);
        let (_, c) = encode_legacy(&pose(f64::NAN, 0.0, 0.0, 0.0));
        assert!(c.0 & 8 != 0);
    }

    #[test]
    fn crc_matches_the_standard_check_value() {
        assert_eq!(crc16_ccitt_false(b"123456789"), 0x29B1);
    }

    #[test]
    fn cobs_round_trips_and_has_no_zeros() {
        let mut rng = 12345u64;
        for len in [0usize, 1, 2, 253, 254, 255, 256, 600] {
            for zeros in [0u64, 1, 3] {
                let data: Vec<u8> = (0..len)
                    .map(|_| {
                        rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1);
                        if (rng >> 60) < zeros {
                            0
                        } else {
                            (rng >> 33) as u8
                        }
                    })
                    .collect();
                let enc = cobs_encode(&data);
                assert!(!enc.contains(&0), "len {len}");
                assert_eq!(cobs_decode(&enc).unwrap(), data, "len {len}");
            }
        }
        assert_eq!(cobs_decode(&[5, 1, 2]), None);
        assert_eq!(cobs_decode(&[0]), None);
    }

    #[test]
    fn framed_packets_survive_data_equal_to_delimiters_and_resync() {
        // Values whose bytes contain 0x00 and 0x1B.
        let poses = [
            pose(0.0, 0.0, 0.0, 0.0),
            pose(0.027, -0.000001, 6.912, 0.27),
            pose(-1.0, 2.0, -3.0, 359.0),
        ];
        let mut stream = vec![0x1B, 0x42, 0x00]; // junk before, with a delimiter
        for (s, p) in poses.iter().enumerate() {
            stream.extend(encode_framed(p, s as u16).0);
        }
        let mut dec = FramedDecoder::default();
        let got: Vec<_> = stream.chunks(3).flat_map(|c| dec.push(c)).collect();
        // The junk frame is an error; the three packets decode.
        let ok: Vec<FramedPacket> = got.iter().filter_map(|r| r.clone().ok()).collect();
        assert_eq!(got.len(), 4);
        assert_eq!(ok.len(), 3);
        assert_eq!(
            ok[1],
            FramedPacket {
                object_id: 7,
                sequence: 1,
                x_mm: 27,
                y_mm: 0,
                z_mm: 6912,
                heading_centideg: 27,
                flags: 0
            }
        );
        // A corrupted byte is caught by the CRC, and the next packet still decodes.
        let mut bad = encode_framed(&poses[2], 9).0;
        bad[5] ^= 0x10;
        if bad[5] == 0 {
            bad[5] = 1;
        }
        bad.extend(encode_framed(&poses[0], 10).0);
        let r = FramedDecoder::default().push(&bad);
        assert!(r[0].is_err());
        assert_eq!(r[1].as_ref().unwrap().sequence, 10);
    }

    #[test]
    fn decoders_never_panic_on_garbage() {
        let mut rng = 99u64;
        let mut legacy = LegacyDecoder::default();
        let mut framed = FramedDecoder::default();
        for _ in 0..2000 {
            let chunk: Vec<u8> = (0..(rng % 40) as usize)
                .map(|_| {
                    rng = rng
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (rng >> 56) as u8
                })
                .collect();
            rng = rng.wrapping_add(7);
            let _ = legacy.push(&chunk);
            let _ = framed.push(&chunk);
            assert!(framed.buf.len() <= FramedDecoder::MAX_FRAME);
        }
    }

    #[test]
    fn legacy_stream_decoder_finds_packets() {
        let mut s = vec![1, 2, 3];
        s.extend(encode_legacy(&pose(1.0, 2.0, 3.0, 45.0)).0);
        s.extend(encode_legacy(&pose(-1.0, 0.5, 0.1, 90.0)).0);
        let mut dec = LegacyDecoder::default();
        let mut got = dec.push(&s[..7]);
        got.extend(dec.push(&s[7..]));
        assert_eq!(got.len(), 2);
        assert_eq!(got[1].x_cm, -100);
    }

    /// Property test: the serial decoders take any bytes — random streams and hostile variants
    /// of valid packets — without a panic (docs/reliability.md).
    #[test]
    fn hostile_serial_bytes_never_panic_a_decoder() {
        use stereoscope_numeric::random::mutations;
        let pose = SerialPose {
            object_id: 3,
            position_m: [0.1, -0.2, 1.5],
            heading_deg: 45.0,
        };
        let (legacy, _) = encode_legacy(&pose);
        let (framed, _) = encode_framed(&pose, 7);
        let mut legacy_dec = LegacyDecoder::default();
        let mut framed_dec = FramedDecoder::default();
        for seed in 0..10 {
            for bytes in mutations(&legacy, 2_000, seed) {
                let _ = legacy_dec.push(&bytes);
                if let Ok(b) = <[u8; LEGACY_LEN]>::try_from(bytes.as_slice()) {
                    let _ = decode_legacy(&b);
                }
            }
            for bytes in mutations(&framed, 2_000, seed) {
                let _ = framed_dec.push(&bytes);
                let _ = decode_framed(&bytes);
                let _ = cobs_decode(&bytes);
            }
        }
        // Still in step: a valid packet after all that garbage decodes.
        let _ = framed_dec.push(&[0]);
        let got = framed_dec.push(&framed);
        assert!(got.iter().any(|p| p.is_ok()), "{got:?}");
    }
}
