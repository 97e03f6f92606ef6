//! `stereoscope blobs --json`: one [`BlobsReport`] per image, one JSON object per line.
//!
//! Coordinates follow `docs/conventions.md` (x right, y down, pixel centres at integers).

use serde::{Deserialize, Serialize};

/// The blobs of one image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlobsReport {
    /// The image path as given on the command line.
    pub image: String,
    pub width: u32,
    pub height: u32,
    /// The threshold used: foreground is `pixel >= threshold`.
    pub threshold: u32,
    /// Blobs in raster order of their first pixel.
    pub blobs: Vec<BlobRecord>,
}

/// One blob: exact binary moments and what follows from them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlobRecord {
    /// Area in pixels (M00).
    pub area_px: u64,
    /// Centroid (M10/M00, M01/M00), pixels.
    pub x_px: f64,
    pub y_px: f64,
    /// Central second moments, sums over pixels (OpenCV's `mu20`, `mu02`, `mu11`).
    pub mu20: f64,
    pub mu02: f64,
    pub mu11: f64,
    /// Major-axis angle, degrees counter-clockwise on screen from the x axis, (−90, 90],
    /// corrected for the pixel aspect ratio given with `--par`.
    pub orientation_deg: f64,
    /// Bounding box `[x0, y0, x1, y1]`, inclusive.
    pub bbox: [u32; 4],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_has_the_documented_keys_and_rejects_unknown_ones() {
        let r = BlobsReport {
            image: "a.pgm".into(),
            width: 4,
            height: 3,
            threshold: 128,
            blobs: vec![BlobRecord {
                area_px: 2,
                x_px: 1.5,
                y_px: 0.0,
                mu20: 0.5,
                mu02: 0.0,
                mu11: 0.0,
                orientation_deg: 0.0,
                bbox: [1, 0, 2, 0],
            }],
        };
        let text = serde_json::to_string(&r).unwrap();
        assert_eq!(
            text,
            r#"{"image":"a.pgm","width":4,"height":3,"threshold":128,"blobs":[{"area_px":2,"x_px":1.5,"y_px":0.0,"mu20":0.5,"mu02":0.0,"mu11":0.0,"orientation_deg":0.0,"bbox":[1,0,2,0]}]}"#
        );
        assert_eq!(serde_json::from_str::<BlobsReport>(&text).unwrap(), r);
        assert!(
            serde_json::from_str::<BlobsReport>(&text.replace("\"width\"", "\"wide\"")).is_err()
        );
    }
}
