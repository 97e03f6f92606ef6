//! The moment worker's per-frame step, independent of transport: the frame threshold from the
//! histogram (every `threshold_every_frames` frames, or fixed; tracking windows may take their
//! own, the thesis's `region.thres`), the moment engine's self-adaptive multi-object tracker
//! (thesis ch. 3 moments, Eq. 3.44 orientation, ch. 5 windows, §4.1.1 heading — all in
//! `stereoscope_vision`), and the frame's `Observation`; dark targets by inverting the frame;
//! the reduced preview for the viewer. The moment worker service, `grab`, the benches and the
//! in-process pipeline all run this. Pixel conventions: `docs/conventions.md`.

use stereoscope_numeric::heading::HeadingStatus;
use stereoscope_proto::frame::{FrameHeader, PixelFormat};
use stereoscope_proto::messages::{
    BlobObservation, Observation, Preview, SCHEMA_VERSION, TrackState,
};
use stereoscope_rig::moments::WorkerSettings;
use stereoscope_rig::schema::WeightingSpec;
use stereoscope_vision::extract::{BlobFlags, Weighting};
use stereoscope_vision::{CoreScan, GrayView, Histogram, Pixel, TrackStatus, Tracker, VisionError};

/// A camera's preview for the viewer (`docs/viewer.md`): at most one every this many
/// milliseconds, at most this wide, and only while someone subscribes to it.
pub const PREVIEW_EVERY_MS: u64 = 250;
pub const PREVIEW_MAX_WIDTH_PX: u32 = 320;

/// Most blobs one observation carries.
pub const MAX_REPORTED_BLOBS: usize = stereoscope_proto::messages::limits::MAX_BLOBS;

/// The periodic threshold's histogram reads every k-th row, at least this many rows: every
/// row of a frame up to 479 rows high, every 2nd at 640 × 480, every 4th at 1080p (the
/// threshold of a distribution does not need every pixel: on the live bench's 640 × 480
/// frames every 2nd row gives a threshold within the 2 levels it moves from frame to frame,
/// for half the reads; at 1080p the full histogram was most of the worker's time).
pub const THRESHOLD_ROWS: u32 = 240;

/// Why one frame was rejected (the worker goes on with the next).
#[derive(Debug, thiserror::Error)]
pub enum FrameRejected {
    #[error("header and payload disagree")]
    Header(#[from] stereoscope_proto::frame::FrameError),
    #[error("a Gray16 frame must be 2-byte aligned with an even stride")]
    Unaligned,
    #[error("tracking")]
    Vision(#[from] VisionError),
}

/// The per-frame processing, independent of transport: thresholds, tracking, the message.
#[derive(Debug)]
pub struct Worker {
    settings: WorkerSettings,
    tracker: Tracker,
    threshold: Option<u32>,
    /// The sequence number of the frame the threshold was last taken from.
    threshold_sequence: Option<u64>,
    rig: String,
    camera: String,
    /// Dark polarity: the frame with its levels inverted, reused from frame to frame.
    inverted8: Vec<u8>,
    inverted16: Vec<u16>,
    /// Blobs ignored in masked places (`moments.mask`), all frames.
    masked: u64,
    /// Frames whose windowed step the cores settled, and frames whose cores were read and
    /// did not settle it (`docs/vision.md`, "Cores"), all frames.
    cores_settled: u64,
    cores_widened: u64,
}

impl Worker {
    pub fn new(settings: WorkerSettings, rig: &str, camera: &str) -> Result<Self, VisionError> {
        let mut tracker = Tracker::new(settings.tracker, settings.extract)?;
        tracker.set_mask(settings.mask.clone());
        Ok(Worker {
            settings,
            tracker,
            threshold: None,
            threshold_sequence: None,
            rig: rig.into(),
            camera: camera.into(),
            inverted8: Vec::new(),
            inverted16: Vec::new(),
            masked: 0,
            cores_settled: 0,
            cores_widened: 0,
        })
    }

    /// Blobs ignored so far because they were in a masked place.
    pub fn masked(&self) -> u64 {
        self.masked
    }

    /// Frames so far whose windowed step the cores settled, and frames whose cores did not
    /// (their windows were read after them).
    pub fn core_scans(&self) -> (u64, u64) {
        (self.cores_settled, self.cores_widened)
    }

    pub fn threshold(&self) -> Option<u32> {
        self.threshold
    }

    pub fn tracked(&self) -> usize {
        self.tracker
            .tracks()
            .iter()
            .filter(|t| t.status != TrackStatus::Lost)
            .count()
    }

    /// The frame threshold, taken afresh from the histogram on the first frame of each period
    /// of `threshold_every_frames` sequence numbers: workers fed the same frames (live, and a
    /// replay of a recording that began mid-run) take it from the same frames.
    fn refresh_threshold<P: Pixel>(
        &mut self,
        img: &GrayView<'_, P>,
        sequence: u64,
    ) -> Result<u32, VisionError> {
        let every = self.settings.threshold_every_frames as u64;
        let due = self.threshold.is_none()
            || self
                .threshold_sequence
                .is_none_or(|l| sequence / every != l / every);
        if let (false, Some(t)) = (due, self.threshold) {
            return Ok(t);
        }
        // Every k-th row, at least THRESHOLD_ROWS of them: every row up to 479, every 2nd
        // at 640 × 480, every 4th at 1080p.
        let hist = Histogram::of_rows(img, (img.height() / THRESHOLD_ROWS).max(1));
        let t = hist.threshold::<P>(self.settings.threshold)?;
        let t = t.clamp(1, P::MAX_VALUE);
        let background = hist.mode()?.min(t.saturating_sub(1));
        let weighting = match self.settings.weighting {
            WeightingSpec::Binary => Weighting::Binary,
            WeightingSpec::Intensity => Weighting::Intensity { background },
            // The weights start a quarter of the way from the background to the threshold:
            // the dim pixels round a blob now count (`extract::add_edge_ring`), and a floor
            // keeps the read noise of the background among them out of the centroid (in the
            // demo's 10 minutes: the helmet 0.45 mm RMS with it, 0.61 mm with none).
            WeightingSpec::Coverage => Weighting::Coverage {
                background: background + (t - background) / 4,
                full: self
                    .settings
                    .full_level
                    .unwrap_or(background + 2 * (t - background))
                    .max(t + 1),
            },
        };
        if self.tracker_weighting() != weighting {
            let mut ex = self.settings.extract;
            ex.weighting = weighting;
            self.tracker.set_extract_config(ex);
        }
        self.threshold = Some(t);
        self.threshold_sequence = Some(sequence);
        Ok(t)
    }

    fn tracker_weighting(&self) -> Weighting {
        self.tracker.extract_config().weighting
    }

    /// Tracks one frame and builds its observation.
    pub fn process<P: Pixel>(
        &mut self,
        img: GrayView<'_, P>,
        header: &FrameHeader,
    ) -> Result<Observation, VisionError> {
        let threshold = self.refresh_threshold(&img, header.sequence)?;
        let step = self.tracker.step_frame(img, threshold, header.sequence)?;
        self.masked += step.masked as u64;
        match step.cores {
            CoreScan::Settled => self.cores_settled += 1,
            CoreScan::Widened => self.cores_widened += 1,
            CoreScan::Windows => {}
        }
        let mut blobs = Vec::new();
        for t in self.tracker.tracks().iter().take(MAX_REPORTED_BLOBS) {
            let w = t.window;
            let (status, area, bbox, flags) = match &t.blob {
                Some(b) => {
                    let st = if t.status == TrackStatus::New {
                        TrackState::New
                    } else {
                        TrackState::Tracked
                    };
                    (st, b.area_px() as f64, b.bbox, b.flags)
                }
                None => (TrackState::Lost, t.area_px as f64, w, BlobFlags::default()),
            };
            // The blob's moments and axes as the tracker took its heading from them (the
            // tracker's `par`, the same setting).
            let (mu20, mu02, mu11, orientation, roundness) = match &t.shape {
                Some(s) => (
                    s.central.mu20,
                    s.central.mu02,
                    s.central.mu11,
                    s.axis.angle_deg,
                    s.axis.roundness(),
                ),
                None => (0.0, 0.0, 0.0, 0.0, 1.0),
            };
            blobs.push(BlobObservation {
                track_id: t.id,
                status,
                area_px: area,
                x_px: t.x_px,
                y_px: t.y_px,
                mu20,
                mu02,
                mu11,
                orientation_deg: orientation,
                roundness,
                heading_deg: t.heading.heading_deg,
                directed: t.heading.status == HeadingStatus::Directed,
                heading_ambiguous: matches!(
                    t.heading.status,
                    HeadingStatus::Ambiguous | HeadingStatus::NearCircular
                ),
                clipped: flags.contains(BlobFlags::CLIPPED)
                    || flags.contains(BlobFlags::TOUCHES_BORDER),
                merged: t.merged && t.blob.is_some(),
                window_px: [w.x0, w.y0, w.x1, w.y1],
                bbox_px: [bbox.x0, bbox.y0, bbox.x1, bbox.y1],
            });
        }
        let dropped = self
            .tracker
            .tracks()
            .len()
            .saturating_sub(MAX_REPORTED_BLOBS)
            + step.extract.dropped_over_capacity;
        Ok(Observation {
            schema: SCHEMA_VERSION,
            rig: self.rig.clone(),
            camera: self.camera.clone(),
            sequence: header.sequence,
            timestamp_ns: header.timestamp_ns,
            frame_published_ns: header.published_ns,
            published_ns: 0,
            width_px: header.width,
            height_px: header.height,
            // A dark target's threshold in the frame's own levels (`pixel <= threshold`).
            threshold: if self.settings.dark {
                self.settings.max_level.saturating_sub(threshold)
            } else {
                threshold
            },
            dark: self.settings.dark,
            full_frame: step.full_frame,
            dropped_blobs: dropped as u32,
            blobs,
        })
    }

    /// Checks a shared-memory frame and tracks it.
    pub fn process_frame(
        &mut self,
        header: &FrameHeader,
        payload: &[u8],
    ) -> Result<Observation, FrameRejected> {
        let format = header.validate(payload.len())?;
        let (w, h) = (header.width, header.height);
        let stride = header.stride_bytes as usize;
        let result = match format {
            PixelFormat::Gray8 if self.settings.dark => {
                // Dark targets: the frame inverted (one pass), then tracked as bright ones.
                let mut buf = std::mem::take(&mut self.inverted8);
                buf.clear();
                buf.extend(payload.iter().map(|v| 255 - v));
                let r = GrayView::new(&buf, w, h, stride)
                    .map_err(FrameRejected::from)
                    .and_then(|view| Ok(self.process(view, header)?));
                self.inverted8 = buf;
                return r;
            }
            PixelFormat::Gray8 => {
                let view = GrayView::new(payload, w, h, stride)?;
                self.process(view, header)
            }
            PixelFormat::Gray16 => {
                // The payload is 8-byte aligned (names::iox frame service); check anyway.
                // SAFETY: every bit pattern is a valid u16, and align_to only returns an
                // aligned middle part.
                let (pre, mid, _) = unsafe { payload.align_to::<u16>() };
                if !pre.is_empty() || !header.stride_bytes.is_multiple_of(2) {
                    return Err(FrameRejected::Unaligned);
                }
                if self.settings.dark {
                    let max = self.settings.max_level.min(u16::MAX as u32) as u16;
                    let mut buf = std::mem::take(&mut self.inverted16);
                    buf.clear();
                    buf.extend(mid.iter().map(|v| max.saturating_sub(*v)));
                    let r = GrayView::new(&buf, w, h, stride / 2)
                        .map_err(FrameRejected::from)
                        .and_then(|view| Ok(self.process(view, header)?));
                    self.inverted16 = buf;
                    return r;
                }
                let view = GrayView::new(mid, w, h, stride / 2)?;
                self.process(view, header)
            }
        };
        Ok(result?)
    }

    /// The frame reduced for people to look at, with the blobs of its observation `obs` (made
    /// from the same frame): called after the observation is out, so it delays no pose.
    pub fn preview(
        &self,
        header: &FrameHeader,
        payload: &[u8],
        obs: &Observation,
    ) -> Result<Preview, FrameRejected> {
        use stereoscope_vision::preview::{reduce, scale_for};
        let format = header.validate(payload.len())?;
        let (w, h) = (header.width, header.height);
        let scale = scale_for(w, PREVIEW_MAX_WIDTH_PX);
        let dark = self.settings.dark;
        let (reduced, level_shift) = match format {
            PixelFormat::Gray8 => {
                let view = GrayView::new(payload, w, h, header.stride_bytes as usize)?;
                (reduce(&view, scale, 0, dark), 0)
            }
            PixelFormat::Gray16 => {
                // SAFETY: as in `process_frame`.
                let (pre, mid, _) = unsafe { payload.align_to::<u16>() };
                if !pre.is_empty() || !header.stride_bytes.is_multiple_of(2) {
                    return Err(FrameRejected::Unaligned);
                }
                let view = GrayView::new(mid, w, h, header.stride_bytes as usize / 2)?;
                let bits = 32 - self.settings.max_level.max(255).leading_zeros();
                let shift = bits.saturating_sub(8).min(8);
                (reduce(&view, scale, shift, dark), shift)
            }
        };
        Ok(Preview {
            schema: SCHEMA_VERSION,
            rig: self.rig.clone(),
            camera: self.camera.clone(),
            sequence: header.sequence,
            timestamp_ns: header.timestamp_ns,
            width_px: w,
            height_px: h,
            scale,
            preview_width_px: reduced.width,
            preview_height_px: reduced.height,
            level_shift,
            threshold: obs.threshold,
            dark,
            histogram: reduced.histogram,
            pixels: reduced.pixels,
            blobs: obs.blobs.clone(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::Message;

    fn defaults() -> WorkerSettings {
        stereoscope_rig::moments::worker_settings(None, 1.0, [640, 480], 65535, "m").unwrap()
    }

    /// Thresholds come from the frames of the same sequence numbers whenever a worker
    /// started: one fed from frame 13 on (a replay of a recording made mid-run) takes its own
    /// from frame 13, then both take frame 30's and agree from there.
    #[test]
    fn thresholds_are_taken_on_the_same_frames_by_sequence_number() {
        let frame = |seq: u64| {
            let bg = 10 + 2 * seq as u8;
            let mut img = vec![bg; 64 * 48];
            for y in 20..26 {
                for x in 30..40 {
                    img[y * 64 + x] = 230;
                }
            }
            let mut h = FrameHeader::new("c", PixelFormat::Gray8, 64, 48).unwrap();
            h.sequence = seq;
            (h, img)
        };
        let mut live = Worker::new(defaults(), "r", "c").unwrap();
        let mut late = Worker::new(defaults(), "r", "c").unwrap();
        for seq in 0..45 {
            let (h, img) = frame(seq);
            let a = live.process_frame(&h, &img).unwrap();
            if seq < 13 {
                continue;
            }
            let b = late.process_frame(&h, &img).unwrap();
            if seq < 30 {
                assert_ne!(live.threshold(), late.threshold(), "frame {seq}");
            } else {
                assert_eq!(live.threshold(), late.threshold(), "frame {seq}");
                assert_eq!(a.blobs, b.blobs, "frame {seq}");
            }
        }
    }

    #[test]
    fn a_frame_becomes_an_observation_with_its_blob() {
        let s = defaults();
        let mut w = Worker::new(s, "r", "c").unwrap();
        let mut img = vec![10u8; 64 * 48];
        for y in 20..26 {
            for x in 30..40 {
                img[y * 64 + x] = 210;
            }
        }
        let mut h = FrameHeader::new("c", PixelFormat::Gray8, 64, 48).unwrap();
        h.sequence = 7;
        h.timestamp_ns = 99;
        let o = w.process_frame(&h, &img).unwrap();
        assert_eq!((o.sequence, o.timestamp_ns, o.blobs.len()), (7, 99, 1));
        let b = &o.blobs[0];
        assert_eq!(b.area_px, 60.0);
        assert!(
            (b.x_px - 34.5).abs() < 1e-9 && (b.y_px - 22.5).abs() < 1e-9,
            "{b:?}"
        );
        assert_eq!(b.bbox_px, [30, 20, 39, 25]);
        assert!(b.orientation_deg.abs() < 1e-9);
        // 16-bit frames are read in place too.
        let img16: Vec<u8> = img
            .iter()
            .flat_map(|&v| (v as u16 * 256).to_le_bytes())
            .collect();
        let mut w16 = Worker::new(defaults(), "r", "c").unwrap();
        let h16 = FrameHeader::new("c", PixelFormat::Gray16, 64, 48).unwrap();
        let o = w16.process_frame(&h16, &img16).unwrap();
        assert_eq!(o.blobs.len(), 1);
        assert!(matches!(
            w.process_frame(&h, &img[..100]),
            Err(FrameRejected::Header(
                stereoscope_proto::frame::FrameError::PayloadSize { .. }
            ))
        ));
    }

    /// A 1920-pixel frame's preview is 320 wide, shows its marker, carries the frame's blobs
    /// and threshold, and decodes as the viewer will read it.
    #[test]
    fn a_preview_shows_the_frame_its_blobs_and_threshold() {
        let (w, h) = (1920u32, 1080u32);
        let mut img = vec![12u8; (w * h) as usize];
        for y in 500..504 {
            for x in 900..904 {
                img[(y * w + x) as usize] = 240;
            }
        }
        let s = stereoscope_rig::moments::worker_settings(None, 1.0, [w, h], 255, "m").unwrap();
        let mut worker = Worker::new(s, "r", "c").unwrap();
        let hd = FrameHeader::new("c", PixelFormat::Gray8, w, h).unwrap();
        let obs = worker.process_frame(&hd, &img).unwrap();
        let p = worker.preview(&hd, &img, &obs).unwrap();
        assert_eq!(
            (p.scale, p.preview_width_px, p.preview_height_px),
            (6, 320, 180)
        );
        assert_eq!(p.pixels[(501 / 6) * 320 + 901 / 6], 240);
        assert_eq!((p.blobs.len(), p.threshold), (1, obs.threshold));
        let back = Preview::from_binary(&p.to_binary()).unwrap();
        assert_eq!(back, p);
    }

    /// The thesis's helmet target: a dark rectangle on a bright background. With polarity
    /// "dark" the worker finds it, its centroid and its axis (30° here), and reports the
    /// threshold in the frame's own levels (`pixel <= threshold`); a fixed dark level is given
    /// as the frame's level too.
    #[test]
    fn dark_targets_on_a_bright_background() {
        let (w, h) = (96usize, 64usize);
        let (cx, cy, a) = (50.0f64, 30.0f64, 30f64.to_radians());
        let mut img = vec![200u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                // Image y points down: 30° counter-clockwise on screen.
                let (u, v) = (dx * a.cos() - dy * a.sin(), dx * a.sin() + dy * a.cos());
                if u.abs() <= 16.0 && v.abs() <= 8.0 {
                    img[y * w + x] = 20;
                }
            }
        }
        let spec = |t: &str| {
            let text = format!("polarity = \"dark\"\nthreshold = {t}\n");
            let m: stereoscope_rig::schema::MomentsSpec = toml::from_str(&text).unwrap();
            stereoscope_rig::moments::worker_settings(Some(&m), 1.0, [96, 64], 255, "m").unwrap()
        };
        for t in ["\"auto\"", "110"] {
            let mut worker = Worker::new(spec(t), "r", "c").unwrap();
            let hd = FrameHeader::new("c", PixelFormat::Gray8, 96, 64).unwrap();
            let o = worker.process_frame(&hd, &img).unwrap();
            assert!(o.dark);
            assert!((20..200).contains(&o.threshold), "{}", o.threshold);
            if t == "110" {
                assert_eq!(o.threshold, 110);
            }
            assert_eq!(o.blobs.len(), 1, "{o:?}");
            let b = &o.blobs[0];
            assert!(
                (b.x_px - cx).abs() < 0.1 && (b.y_px - cy).abs() < 0.1,
                "{b:?}"
            );
            assert!((b.orientation_deg - 30.0).abs() < 1.0, "{b:?}");
            assert!((b.area_px - 32.0 * 16.0).abs() < 40.0, "{b:?}");
        }
        // The same frame looked at for bright targets: the rectangle is not one.
        let mut bright = Worker::new(defaults(), "r", "c").unwrap();
        let hd = FrameHeader::new("c", PixelFormat::Gray8, 96, 64).unwrap();
        let o = bright.process_frame(&hd, &img).unwrap();
        assert!(!o.dark);
        assert!(
            o.blobs
                .iter()
                .all(|b| (b.x_px - cx).abs() > 1.0 || (b.area_px - 512.0).abs() > 100.0),
            "{o:?}"
        );
        // A dark level at the top of the range cannot be a threshold.
        let m: stereoscope_rig::schema::MomentsSpec =
            toml::from_str("polarity = \"dark\"\nthreshold = 255\n").unwrap();
        let e = stereoscope_rig::moments::worker_settings(
            Some(&m),
            1.0,
            [96, 64],
            255,
            "camera[0].moments",
        )
        .unwrap_err();
        assert_eq!(e.key, "camera[0].moments.threshold");
    }
}
