//! A camera's `moments` table turned into the moment worker's settings (thesis ch. 3 moments,
//! Eq. 3.44 orientation with the camera's pixel aspect ratio, ch. 5 tracking windows), with
//! every default filled in and every value checked against the camera it belongs to.

use crate::error::{RigError, err};
use crate::schema::{MomentsSpec, ThresholdMethodSpec, ThresholdSpec, WeightingSpec};
use stereoscope_vision::extract::{Connectivity, ExtractConfig, Weighting};
use stereoscope_vision::{PixelRect, ThresholdMethod, TrackerConfig};

/// Most objects one worker tracks (and one observation carries).
pub const MAX_OBJECTS: usize = stereoscope_proto::messages::limits::MAX_BLOBS;

/// The worker's settings, checked, from the camera's `moments` table.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerSettings {
    /// Dark targets: the worker tracks the frame with its levels inverted (`max_level − v`), so
    /// `threshold` (a fixed level already inverted) applies to that.
    pub dark: bool,
    /// The camera's largest grey level (255 or 65535).
    pub max_level: u32,
    pub threshold: ThresholdMethod,
    pub threshold_every_frames: u32,
    pub weighting: WeightingSpec,
    pub full_level: Option<u32>,
    pub tracker: TrackerConfig,
    pub extract: ExtractConfig,
    /// Where blobs are ignored (the `mask` rectangles).
    pub mask: Vec<PixelRect>,
}

/// Most mask rectangles one camera has.
pub const MAX_MASK_RECTS: usize = 256;

fn method(m: ThresholdMethodSpec) -> ThresholdMethod {
    match m {
        ThresholdMethodSpec::Auto => ThresholdMethod::Auto,
        ThresholdMethodSpec::Otsu => ThresholdMethod::Otsu,
        ThresholdMethodSpec::Triangle => ThresholdMethod::Triangle,
    }
}

/// Reads a `moments` table for a camera of `image_size` whose pixels reach `max_level`
/// (255 or 65535) with pixel aspect ratio `par`; errors name `KEY.FIELD` and the value.
pub fn worker_settings(
    spec: Option<&MomentsSpec>,
    par: f64,
    image_size: [u32; 2],
    max_level: u32,
    key: &str,
) -> Result<WorkerSettings, RigError> {
    let d = MomentsSpec::default();
    let s = spec.unwrap_or(&d);
    let level = |name: &str, l: u32| {
        if l == 0 || l > max_level {
            Err(err(
                format!("{key}.{name}"),
                format!("{l} is not a grey level of this camera's pixels (1 to {max_level})"),
            ))
        } else {
            Ok(l)
        }
    };
    let dark = s.polarity == Some(crate::schema::Polarity::Dark);
    let threshold = match s.threshold {
        None => ThresholdMethod::Auto,
        // A dark target is `pixel <= l`: on the inverted frame, `max − pixel >= max − l`.
        Some(ThresholdSpec::Level(l)) if dark => {
            if l >= max_level {
                return Err(err(
                    format!("{key}.threshold"),
                    format!(
                        "{l}: with polarity \"dark\" a level below {max_level} (foreground is pixel <= threshold)"
                    ),
                ));
            }
            ThresholdMethod::Fixed(max_level - l)
        }
        Some(ThresholdSpec::Level(l)) => ThresholdMethod::Fixed(level("threshold", l)?),
        Some(ThresholdSpec::Method(m)) => method(m),
    };
    if let Some(f) = s.full_level {
        level("full_level", f)?;
    }
    let connectivity = match s.connectivity {
        None | Some(8) => Connectivity::Eight,
        Some(4) => Connectivity::Four,
        Some(o) => {
            return Err(err(
                format!("{key}.connectivity"),
                format!("{o} is not 4 or 8"),
            ));
        }
    };
    let max_objects = s.max_objects.unwrap_or(8);
    if !(1..=MAX_OBJECTS).contains(&max_objects) {
        return Err(err(
            format!("{key}.max_objects"),
            format!("{max_objects} is not between 1 and {MAX_OBJECTS}"),
        ));
    }
    let pixels = image_size[0] as u64 * image_size[1] as u64;
    let min_area_px = s.min_area_px.unwrap_or(4);
    if min_area_px == 0 || min_area_px > pixels {
        return Err(err(
            format!("{key}.min_area_px"),
            format!("{min_area_px} is not between 1 and the image's {pixels} pixels"),
        ));
    }
    let longest = image_size[0].max(image_size[1]);
    let min_half_width_px = s.min_half_width_px.unwrap_or(30);
    if min_half_width_px == 0 || min_half_width_px > longest {
        return Err(err(
            format!("{key}.min_half_width_px"),
            format!("{min_half_width_px} is not between 1 and the image's {longest} pixels"),
        ));
    }
    for (name, v) in [
        ("search_every_frames", s.search_every_frames),
        ("threshold_every_frames", s.threshold_every_frames),
    ] {
        if let Some(v) = v
            && !(1..=1_000_000).contains(&v)
        {
            return Err(err(
                format!("{key}.{name}"),
                format!("{v} is not between 1 and 1000000"),
            ));
        }
    }
    if let Some(step) = s.search_row_step
        && !(1..=image_size[1]).contains(&step)
    {
        return Err(err(
            format!("{key}.search_row_step"),
            format!(
                "{step} is not between 1 and the image's {} rows",
                image_size[1]
            ),
        ));
    }
    if s.mask.len() > MAX_MASK_RECTS {
        return Err(err(
            format!("{key}.mask"),
            format!("has {} rectangles, over {MAX_MASK_RECTS}", s.mask.len()),
        ));
    }
    let mut mask = Vec::with_capacity(s.mask.len());
    for (i, &[x0, y0, x1, y1]) in s.mask.iter().enumerate() {
        if x0 > x1 || y0 > y1 || x1 >= image_size[0] || y1 >= image_size[1] {
            return Err(err(
                format!("{key}.mask[{i}]"),
                format!(
                    "[{x0}, {y0}, {x1}, {y1}] is not a rectangle [x0, y0, x1, y1] inside the {}×{} image (x0 <= x1, y0 <= y1)",
                    image_size[0], image_size[1]
                ),
            ));
        }
        mask.push(PixelRect { x0, y0, x1, y1 });
    }
    let tracker = TrackerConfig {
        max_objects,
        min_new_area_px: min_area_px,
        search_every_frames: s.search_every_frames.unwrap_or(10),
        search_row_step: s.search_row_step,
        min_half_width_px,
        par,
        window_threshold: s.window_threshold.map(method),
        core_scan: s.core_scan.unwrap_or(true),
        ..TrackerConfig::default()
    };
    tracker
        .validate()
        .map_err(|e| err(key.to_string(), e.to_string()))?;
    Ok(WorkerSettings {
        dark,
        max_level,
        threshold,
        threshold_every_frames: s.threshold_every_frames.unwrap_or(30),
        weighting: s.weighting.unwrap_or_default(),
        full_level: s.full_level,
        tracker,
        extract: ExtractConfig {
            connectivity,
            min_area_px,
            max_blobs: 256,
            weighting: Weighting::Binary,
            threads: 1,
        },
        mask,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mask_rectangle_must_be_inside_the_image() {
        let m = |r: [u32; 4]| MomentsSpec {
            mask: vec![[0, 0, 9, 9], r],
            ..Default::default()
        };
        let ok =
            worker_settings(Some(&m([300, 200, 319, 239])), 1.0, [320, 240], 255, "c").unwrap();
        assert_eq!(
            ok.mask[1],
            PixelRect {
                x0: 300,
                y0: 200,
                x1: 319,
                y1: 239
            }
        );
        for bad in [[0, 0, 320, 10], [5, 5, 4, 9], [0, 240, 1, 240]] {
            let e = worker_settings(Some(&m(bad)), 1.0, [320, 240], 255, "c").unwrap_err();
            assert_eq!(e.key, "c.mask[1]", "{bad:?}");
            assert!(e.message.contains(&format!("{}", bad[2])), "{e}");
        }
    }

    #[test]
    fn settings_name_the_bad_key() {
        let at =
            |s: Option<&MomentsSpec>| worker_settings(s, 1.0, [320, 240], 255, "camera[2].moments");
        let ok = worker_settings(None, 0.86, [320, 240], 255, "camera[0].moments").unwrap();
        assert_eq!(ok.threshold, ThresholdMethod::Auto);
        assert_eq!(ok.weighting, WeightingSpec::Coverage);
        let bad = |s: MomentsSpec| at(Some(&s)).unwrap_err();
        let e = bad(MomentsSpec {
            threshold: Some(ThresholdSpec::Level(300)),
            ..Default::default()
        });
        assert_eq!(e.key, "camera[2].moments.threshold");
        assert!(e.message.contains("300"), "{e}");
        let e = bad(MomentsSpec {
            connectivity: Some(6),
            ..Default::default()
        });
        assert_eq!(e.key, "camera[2].moments.connectivity");
        assert!(e.message.contains('6'), "{e}");
        let e = bad(MomentsSpec {
            max_objects: Some(0),
            ..Default::default()
        });
        assert_eq!(e.key, "camera[2].moments.max_objects");
        let e = bad(MomentsSpec {
            threshold_every_frames: Some(0),
            ..Default::default()
        });
        assert_eq!(e.key, "camera[2].moments.threshold_every_frames");
        let e = bad(MomentsSpec {
            min_area_px: Some(320 * 240 + 1),
            ..Default::default()
        });
        assert_eq!(e.key, "camera[2].moments.min_area_px");
        for step in [0, 241] {
            let e = bad(MomentsSpec {
                search_row_step: Some(step),
                ..Default::default()
            });
            assert_eq!(e.key, "camera[2].moments.search_row_step");
            assert!(e.message.contains(&format!("{step} is not")), "{e}");
        }
        let sampled = MomentsSpec {
            search_row_step: Some(240),
            ..Default::default()
        };
        assert_eq!(
            at(Some(&sampled)).unwrap().tracker.search_row_step,
            Some(240)
        );
        // Cores are on unless the rig turns them off.
        assert!(at(None).unwrap().tracker.core_scan);
        let whole = MomentsSpec {
            core_scan: Some(false),
            ..Default::default()
        };
        assert!(!at(Some(&whole)).unwrap().tracker.core_scan);
        // A 16-bit camera takes levels above 255.
        let deep = MomentsSpec {
            threshold: Some(ThresholdSpec::Level(300)),
            ..Default::default()
        };
        let ok = worker_settings(Some(&deep), 1.0, [320, 240], 65535, "m").unwrap();
        assert_eq!(ok.threshold, ThresholdMethod::Fixed(300));
    }
}
