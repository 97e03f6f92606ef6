//! The image the README's quick start runs on: `docs/examples/thesis-targets-320x240.pgm`.
//!
//! A view like the thesis's lab camera (§4.1.2): 320×240 pixels with PAR 0.86, a dark board
//! lit unevenly, the double ping-pong-ball target (two 40 mm balls glued together, seen from
//! above at about 2.5 m), a single ball, and a flat oblong marker, with Gaussian noise σ = 2.
//! Regenerate it with `STEREOSCOPE_REGENERATE_EXAMPLE=1 cargo test -p stereoscope example`.

use stereoscope_numeric::SplitMix64;
use stereoscope_vision::raster::{Ellipse, add_gaussian_noise, draw_ellipse, fill_background};
use stereoscope_vision::{GrayImage, VisionError};

/// Where the shipped example lives, relative to the repository root.
pub const EXAMPLE_PATH: &str = "docs/examples/thesis-targets-320x240.pgm";

/// The example's pixel aspect ratio.
pub const EXAMPLE_PAR: f64 = 0.86;

/// Renders the example scene (deterministic).
pub fn example_scene() -> Result<GrayImage<u8>, VisionError> {
    let par = EXAMPLE_PAR;
    let mut img = GrayImage::filled(320, 240, 0u8)?;
    let (base, gradient) = (18.0, 0.08);
    fill_background(&mut img, base, gradient);
    let bg_at = |x: f64| base + gradient * x;
    // The double ball: two discs of radius 5.5 (in pixel heights) touching, axis at 30°.
    let (cx, cy, r, angle) = (110.4, 95.3, 5.5f64, 30.0f64);
    let (dx, dy) = (
        r * angle.to_radians().cos() / par,
        -r * angle.to_radians().sin(),
    );
    for s in [-1.0, 1.0] {
        let e = Ellipse::disc(cx + s * dx, cy + s * dy, r);
        draw_ellipse(&mut img, &e, par, bg_at(cx), bg_at(cx) + 190.0, 8);
    }
    // A single ball.
    draw_ellipse(
        &mut img,
        &Ellipse::disc(230.7, 160.2, 5.5),
        par,
        bg_at(230.0),
        bg_at(230.0) + 185.0,
        8,
    );
    // A flat oblong marker at −50°.
    let marker = Ellipse {
        cx_px: 70.25,
        cy_px: 184.6,
        semi_major: 12.0,
        semi_minor: 4.0,
        angle_deg: -50.0,
    };
    draw_ellipse(&mut img, &marker, par, bg_at(70.0), bg_at(70.0) + 170.0, 8);
    add_gaussian_noise(&mut img, 2.0, &mut SplitMix64::new(1994));
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn shipped_example_is_what_the_generator_makes() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let path = root.join(EXAMPLE_PATH);
        let bytes = stereoscope_imageio::encode_pgm_u8(&example_scene().unwrap());
        if std::env::var_os("STEREOSCOPE_REGENERATE_EXAMPLE").is_some() {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
        let shipped = std::fs::read(&path).unwrap();
        assert!(
            shipped == bytes,
            "{} differs from example_scene(): regenerate it",
            path.display()
        );
    }
}
