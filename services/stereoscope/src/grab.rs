//! `stereoscope grab`: frames from one camera of a rig, as its capture service would read them
//! (V4L2, Y4M, image files or the synthetic scene), saved as PGM or PNG for calibration
//! (`stereoscope calibrate --dot-grid` reads them), and a preview of the last one showing what
//! the moment worker makes of it — the pixels over its threshold in red, each blob's box and
//! orientation cross — with a word on the exposure, so a user can aim the camera and set its
//! exposure before calibrating (`docs/calibration.md`).

use anyhow::Context as _;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::Observation;
use stereoscope_sources::Read;
use stereoscope_vision::GrayImage;

/// How long `grab` goes on skipping spoilt frames before it gives up.
const GIVE_UP_AFTER: Duration = Duration::from_secs(5);

/// How to save the frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GrabFormat {
    Pgm,
    Png,
}

#[derive(Debug, Clone)]
pub struct GrabOptions {
    pub rig: PathBuf,
    pub camera: String,
    pub count: u32,
    /// Seconds between saved frames (of the source's time for files and the synthetic scene,
    /// of the clock for a camera).
    pub every_s: f64,
    pub format: GrabFormat,
    pub out: PathBuf,
}

/// The most frames one grab saves.
pub const MAX_COUNT: u32 = 100_000;

fn write_file(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// The frame's levels as 8 bits (16-bit frames shifted by what the camera's levels need).
fn level8(payload: &[u8], format: PixelFormat, max_level: u32) -> Vec<u8> {
    match format {
        PixelFormat::Gray8 => payload.to_vec(),
        PixelFormat::Gray16 => {
            let bits = 32 - max_level.max(255).leading_zeros();
            let shift = bits.saturating_sub(8);
            payload
                .chunks_exact(2)
                .map(|b| (u16::from_le_bytes([b[0], b[1]]) >> shift).min(255) as u8)
                .collect()
        }
    }
}

/// The preview: the frame in grey, what is over the threshold (under it, for dark targets)
/// in red, each blob's bounding box in green and its orientation cross in magenta.
fn preview_rgb(grey: &[u8], w: u32, h: u32, obs: &Observation, shift: u32) -> Vec<u8> {
    let t = (obs.threshold >> shift).min(255) as u8;
    let mut rgb = Vec::with_capacity(grey.len() * 3);
    for &v in grey {
        let fg = if obs.dark { v <= t } else { v >= t };
        if fg {
            rgb.extend_from_slice(&[255, v / 3, v / 3]);
        } else {
            rgb.extend_from_slice(&[v, v, v]);
        }
    }
    let mut put = |x: i64, y: i64, c: [u8; 3]| {
        if (0..w as i64).contains(&x) && (0..h as i64).contains(&y) {
            let i = 3 * (y as usize * w as usize + x as usize);
            rgb[i..i + 3].copy_from_slice(&c);
        }
    };
    for b in obs
        .blobs
        .iter()
        .filter(|b| b.status != stereoscope_proto::messages::TrackState::Lost)
    {
        let [x0, y0, x1, y1] = b.bbox_px.map(|v| v as i64);
        for x in x0 - 1..=x1 + 1 {
            put(x, y0 - 1, [0, 230, 0]);
            put(x, y1 + 1, [0, 230, 0]);
        }
        for y in y0 - 1..=y1 + 1 {
            put(x0 - 1, y, [0, 230, 0]);
            put(x1 + 1, y, [0, 230, 0]);
        }
        // Orientation on screen: counter-clockwise from +x with y down (Eq. 3.44's angle).
        let a = -b.orientation_deg.to_radians();
        let r = (b.area_px.sqrt()).max(4.0);
        let q = r * b.roundness.max(0.3);
        for k in -100..=100 {
            let s = k as f64 / 100.0;
            put(
                (b.x_px + s * r * a.cos()).round() as i64,
                (b.y_px + s * r * a.sin()).round() as i64,
                [255, 0, 255],
            );
            put(
                (b.x_px - s * q * a.sin()).round() as i64,
                (b.y_px + s * q * a.cos()).round() as i64,
                [255, 0, 255],
            );
        }
    }
    rgb
}

/// What the last frame says about the exposure, in words.
fn exposure_advice(
    grey_full: &[u8],
    format: PixelFormat,
    max_level: u32,
    obs: &Observation,
) -> String {
    let top = match format {
        PixelFormat::Gray8 => 255,
        PixelFormat::Gray16 => max_level.min(65535),
    };
    let level = |i: usize| match format {
        PixelFormat::Gray8 => grey_full[i] as u32,
        PixelFormat::Gray16 => u16::from_le_bytes([grey_full[2 * i], grey_full[2 * i + 1]]) as u32,
    };
    let n = match format {
        PixelFormat::Gray8 => grey_full.len(),
        PixelFormat::Gray16 => grey_full.len() / 2,
    };
    let saturated = (0..n).filter(|&i| level(i) >= top).count();
    let found = obs
        .blobs
        .iter()
        .filter(|b| b.status != stereoscope_proto::messages::TrackState::Lost)
        .count();
    if found == 0 {
        return "no blob over the threshold: aim the camera at the markers or the target, or \
                raise the exposure or the lights"
            .into();
    }
    if saturated > 0 {
        return format!(
            "{saturated} pixels at the top level ({top}): lower the exposure or the gain until \
             none is (a saturated marker's centroid is biased)"
        );
    }
    format!("{found} blobs, none saturated: the exposure is usable")
}

/// Saves `count` frames of the camera into `out`, and its preview; prints a line per frame
/// and the advice. Returns 0.
pub fn run(opts: &GrabOptions, out: &mut impl Write) -> anyhow::Result<usize> {
    if !(1..=MAX_COUNT).contains(&opts.count) {
        anyhow::bail!("--count {} is not between 1 and {MAX_COUNT}", opts.count);
    }
    if !(opts.every_s.is_finite() && opts.every_s >= 0.0) {
        anyhow::bail!(
            "--every {} must be a number of seconds, 0 or more",
            opts.every_s
        );
    }
    let rig = stereoscope_rig::Rig::load(&opts.rig)?;
    let index = rig.camera_index(&opts.camera).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no camera {:?} (cameras: {:?})",
            opts.rig.display(),
            opts.camera,
            rig.cameras.iter().map(|c| &c.id).collect::<Vec<_>>()
        )
    })?;
    // The camera's own host: its source is that PC's.
    let host = if rig.spec.hosts.is_empty() {
        None
    } else {
        rig.spec.cameras[index].host.clone()
    };
    let ctx = stereoscope_service::CommonArgs {
        rig: opts.rig.clone(),
        place: stereoscope_service::HostArgs {
            host,
            iox_prefix: None,
        },
        zenoh_mode: None,
        zenoh_connect: Vec::new(),
        zenoh_listen: Vec::new(),
        tls: Default::default(),
    }
    .resolve()?;
    let settings = ctx.rig.worker_settings(index)?;
    let max_level = settings.max_level;
    let mut worker =
        stereoscope_pipeline::worker::Worker::new(settings, &ctx.rig.name, &opts.camera)?;
    let mut source = stereoscope_sources::open(&ctx.rig, &opts.camera)?;
    let (w, h) = source.size();
    let format = source.format();
    let bytes_pp = match format {
        PixelFormat::Gray8 => 1,
        PixelFormat::Gray16 => 2,
    };
    let mut buf = vec![0u8; w as usize * h as usize * bytes_pp];
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("making the folder {}", opts.out.display()))?;
    writeln!(out, "{}: {}", opts.camera, source.describe())?;
    // Files and the synthetic scene are read at the frames wanted; a camera is read on, and
    // a frame kept when its time has come.
    let fps = source.fps().unwrap_or(30.0).max(1e-3);
    let step = ((opts.every_s * fps).round() as u64).max(1);
    let paced_by_clock = !source.realtime();
    let start = Instant::now();
    let mut next_keep = start;
    let mut index_in_source = 0u64;
    let mut kept = 0u32;
    let mut last: Option<(Vec<u8>, Observation)> = None;
    let mut first_stamp_ns: Option<Option<u64>> = None;
    let mut last_good = Instant::now();
    while kept < opts.count {
        let t_s = index_in_source as f64 / fps;
        // A frame the camera spoilt (lost packets, the camera gone and being opened again) is
        // skipped and said, as the capture service does; five seconds without a good one end
        // the grab with the last reason.
        let read = match source.read(index_in_source, t_s, &mut buf) {
            Err(stereoscope_sources::SourceError::BadFrame(bad))
                if last_good.elapsed() < GIVE_UP_AFTER =>
            {
                writeln!(
                    out,
                    "skipped a frame: {}",
                    stereoscope_transport::error_chain(&bad)
                )?;
                continue;
            }
            r => {
                r.with_context(|| format!("reading frame {index_in_source} of {}", opts.camera))?
            }
        };
        last_good = Instant::now();
        let (stamp_ns, camera_sequence) = match read {
            Read::Frame {
                timestamp_ns,
                sequence,
            } => (timestamp_ns, sequence),
            Read::End => (None, None),
        };
        if read == Read::End {
            writeln!(
                out,
                "the source ended after {kept} of {} frames",
                opts.count
            )?;
            break;
        }
        let this = index_in_source;
        index_in_source += if paced_by_clock { 1 } else { step };
        if paced_by_clock {
            if Instant::now() < next_keep {
                continue;
            }
            next_keep += Duration::from_secs_f64(opts.every_s);
        }
        let mut header = FrameHeader::new(&opts.camera, format, w, h)?;
        header.sequence = this;
        let obs = worker.process_frame(&header, &buf)?;
        kept += 1;
        let name = format!(
            "{}-{kept:04}.{}",
            opts.camera,
            match opts.format {
                GrabFormat::Pgm => "pgm",
                GrabFormat::Png => "png",
            }
        );
        let path = opts.out.join(&name);
        let encoded = match (format, opts.format) {
            (PixelFormat::Gray8, f) => {
                let img = GrayImage::from_vec(buf.clone(), w, h)?;
                match f {
                    GrabFormat::Pgm => stereoscope_imageio::encode_pgm_u8(&img),
                    GrabFormat::Png => stereoscope_imageio::encode_png_u8(&img)?,
                }
            }
            (PixelFormat::Gray16, f) => {
                let px: Vec<u16> = buf
                    .chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]))
                    .collect();
                let img = GrayImage::from_vec(px, w, h)?;
                match f {
                    GrabFormat::Pgm => {
                        stereoscope_imageio::encode_pgm_u16(&img, max_level.min(65535) as u16)
                    }
                    GrabFormat::Png => stereoscope_imageio::encode_png_u16(&img)?,
                }
            }
        };
        write_file(&path, &encoded)?;
        let first = *first_stamp_ns.get_or_insert(stamp_ns);
        let when = match (stamp_ns, first, camera_sequence) {
            (Some(t), Some(t0), Some(seq)) => format!(
                "camera's frame {seq}, exposed {:.1} ms after the first saved, ",
                (t as i128 - t0 as i128) as f64 / 1e6
            ),
            _ => String::new(),
        };
        writeln!(
            out,
            "{} (frame {this}, {when}threshold {}, {} blobs)",
            path.display(),
            obs.threshold,
            obs.blobs.len()
        )?;
        last = Some((buf.clone(), obs));
    }
    if let Some((frame, obs)) = last {
        let shift = match format {
            PixelFormat::Gray8 => 0,
            PixelFormat::Gray16 => (32 - max_level.max(255).leading_zeros()).saturating_sub(8),
        };
        let grey = level8(&frame, format, max_level);
        let rgb = preview_rgb(&grey, w, h, &obs, shift);
        let path = opts.out.join(format!("{}-preview.png", opts.camera));
        write_file(&path, &stereoscope_imageio::encode_png_rgb8(&rgb, w, h)?)?;
        writeln!(
            out,
            "{}: over the threshold in red, blobs boxed in green, their axes in magenta",
            path.display()
        )?;
        for b in obs
            .blobs
            .iter()
            .filter(|b| b.status != stereoscope_proto::messages::TrackState::Lost)
        {
            writeln!(
                out,
                "blob {}: centroid ({:.2}, {:.2}) px, area {:.0} px², orientation {:.1}°",
                b.track_id, b.x_px, b.y_px, b.area_px, b.orientation_deg
            )?;
        }
        writeln!(out, "{}", exposure_advice(&frame, format, max_level, &obs))?;
        writeln!(out, "{}", source.describe())?;
    }
    Ok(0)
}
