//! `stereoscope blobs IMAGE...`: every bright blob of each image with its moments.
//!
//! Uses the moment engine (`stereoscope-vision`: Eq. 3.33–3.44 of the thesis); pixel
//! conventions in `docs/conventions.md`; the JSON schema is `stereoscope_proto::blobs`.

use std::io::Write;
use std::path::PathBuf;
use stereoscope_imageio::{AnyGray, read_gray};
use stereoscope_proto::blobs::{BlobRecord, BlobsReport};
use stereoscope_vision::{
    Connectivity, ExtractConfig, Extractor, GrayView, Histogram, Pixel, ThresholdMethod,
    VisionError,
};

/// Options of `stereoscope blobs`.
#[derive(Debug, Clone)]
pub struct BlobsOptions {
    pub images: Vec<PathBuf>,
    pub threshold: ThresholdMethod,
    /// Pixel aspect ratio, pixel width / pixel height.
    pub par: f64,
    pub connectivity: Connectivity,
    pub min_area_px: u64,
    pub json: bool,
}

/// The blobs of one decoded image, or why not.
pub fn analyse(
    name: &str,
    image: &AnyGray,
    opts: &BlobsOptions,
) -> Result<(BlobsReport, Vec<Vec<&'static str>>), VisionError> {
    match image {
        AnyGray::U8(img) => analyse_view(name, img.view(), opts),
        AnyGray::U16 { image, .. } => analyse_view(name, image.view(), opts),
    }
}

fn analyse_view<P: Pixel>(
    name: &str,
    view: GrayView<'_, P>,
    opts: &BlobsOptions,
) -> Result<(BlobsReport, Vec<Vec<&'static str>>), VisionError> {
    let par = stereoscope_vision::moments::validate_par(opts.par)?;
    let threshold = Histogram::of(&view).threshold::<P>(opts.threshold)?;
    let mut ex = Extractor::new(ExtractConfig {
        connectivity: opts.connectivity,
        min_area_px: opts.min_area_px,
        max_blobs: usize::MAX,
        ..Default::default()
    });
    let blobs = ex.extract(view, threshold, &[])?;
    let mut flags = Vec::with_capacity(blobs.len());
    let records = blobs
        .iter()
        .map(|b| {
            let (x, y) = b.centroid_px();
            let c = b.central();
            flags.push(b.flags.names());
            BlobRecord {
                area_px: b.area_px(),
                x_px: x,
                y_px: y,
                mu20: c.mu20,
                mu02: c.mu02,
                mu11: c.mu11,
                // A single pixel or a row has no second moments to speak of: 0, not −0.
                orientation_deg: c.orientation_deg(par) + 0.0,
                bbox: [b.bbox.x0, b.bbox.y0, b.bbox.x1, b.bbox.y1],
            }
        })
        .collect();
    let report = BlobsReport {
        image: name.to_string(),
        width: view.width(),
        height: view.height(),
        threshold,
        blobs: records,
    };
    Ok((report, flags))
}

fn method_name(m: ThresholdMethod) -> &'static str {
    match m {
        ThresholdMethod::Fixed(_) => "fixed",
        ThresholdMethod::Otsu => "otsu",
        ThresholdMethod::Triangle => "triangle",
        ThresholdMethod::Auto => "auto",
    }
}

fn write_table(
    out: &mut impl Write,
    r: &BlobsReport,
    bits: u32,
    opts: &BlobsOptions,
    flags: &[Vec<&str>],
) -> std::io::Result<()> {
    writeln!(
        out,
        "{}: {}×{}, {bits}-bit, threshold {} ({}), PAR {}, {} blob{}",
        r.image,
        r.width,
        r.height,
        r.threshold,
        method_name(opts.threshold),
        opts.par,
        r.blobs.len(),
        if r.blobs.len() == 1 { "" } else { "s" }
    )?;
    if r.blobs.is_empty() {
        return Ok(());
    }
    writeln!(
        out,
        "{:>4} {:>9} {:>10} {:>10} {:>12} {:>12} {:>12} {:>9}  {:<22} flags",
        "#", "area_px", "x_px", "y_px", "mu20", "mu02", "mu11", "angle_deg", "bbox"
    )?;
    for (i, (b, f)) in r.blobs.iter().zip(flags).enumerate() {
        let bbox = format!(
            "[{}, {}, {}, {}]",
            b.bbox[0], b.bbox[1], b.bbox[2], b.bbox[3]
        );
        writeln!(
            out,
            "{:>4} {:>9} {:>10.3} {:>10.3} {:>12.1} {:>12.1} {:>12.1} {:>9.2}  {:<22} {}",
            i + 1,
            b.area_px,
            b.x_px,
            b.y_px,
            b.mu20,
            b.mu02,
            b.mu11,
            b.orientation_deg,
            bbox,
            f.join(",")
        )?;
    }
    Ok(())
}

/// Runs the command: every image is processed even when others fail. Returns how many images
/// failed (each named on `err` with the reason).
pub fn run(
    opts: &BlobsOptions,
    out: &mut impl Write,
    err: &mut impl Write,
) -> std::io::Result<usize> {
    let mut failed = 0;
    for path in &opts.images {
        let name = path.display().to_string();
        let result = read_gray(path).map_err(|e| e.to_string()).and_then(|img| {
            analyse(&name, &img, opts)
                .map(|r| (r, img.bits()))
                .map_err(|e| e.to_string())
        });
        match result {
            Ok(((report, flags), bits)) => {
                if opts.json {
                    let line = serde_json::to_string(&report).map_err(std::io::Error::other)?;
                    writeln!(out, "{line}")?;
                } else {
                    write_table(out, &report, bits, opts, &flags)?;
                }
            }
            Err(reason) => {
                failed += 1;
                writeln!(err, "error: {name}: {reason}")?;
            }
        }
    }
    Ok(failed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_vision::GrayImage;

    fn opts(images: Vec<PathBuf>, json: bool) -> BlobsOptions {
        BlobsOptions {
            images,
            threshold: ThresholdMethod::Fixed(128),
            par: 1.0,
            connectivity: Connectivity::Eight,
            min_area_px: 1,
            json,
        }
    }

    #[test]
    fn table_and_json_for_a_rectangle() {
        let mut img = GrayImage::filled(20, 10, 0u8).unwrap();
        for y in 2..5 {
            for x in 3..10 {
                img.set(x, y, 200);
            }
        }
        let (r, _) = analyse("r.pgm", &AnyGray::U8(img), &opts(vec![], true)).unwrap();
        assert_eq!(r.blobs.len(), 1);
        let b = &r.blobs[0];
        assert_eq!(
            (b.area_px, b.x_px, b.y_px, b.bbox),
            (21, 6.0, 3.0, [3, 2, 9, 4])
        );
        assert_eq!(b.orientation_deg, 0.0);
    }

    #[test]
    fn bad_threshold_and_par_are_errors_naming_the_value() {
        let img = AnyGray::U8(GrayImage::filled(4, 4, 0u8).unwrap());
        let mut o = opts(vec![], false);
        o.threshold = ThresholdMethod::Fixed(300);
        assert!(
            analyse("x", &img, &o)
                .unwrap_err()
                .to_string()
                .contains("300")
        );
        let mut o = opts(vec![], false);
        o.par = -1.0;
        assert!(
            analyse("x", &img, &o)
                .unwrap_err()
                .to_string()
                .contains("-1")
        );
    }

    #[test]
    fn missing_file_is_reported_and_the_rest_processed() {
        let dir = std::env::temp_dir().join(format!("stereoscope-blobs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.pgm");
        std::fs::write(&good, b"P2\n3 1\n255\n0 200 0\n").unwrap();
        let o = opts(vec![dir.join("missing.pgm"), good.clone()], true);
        let (mut out, mut err) = (Vec::new(), Vec::new());
        assert_eq!(run(&o, &mut out, &mut err).unwrap(), 1);
        let err = String::from_utf8(err).unwrap();
        assert!(
            err.contains("missing.pgm") && err.contains("cannot read"),
            "{err}"
        );
        let out = String::from_utf8(out).unwrap();
        assert_eq!(out.lines().count(), 1);
        assert!(out.contains("good.pgm"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
