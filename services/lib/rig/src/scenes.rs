//! Synthetic scenes made by code rather than written by hand: rigs for the benchmarks and
//! the system tests that need more targets than a rig file is worth writing out.

/// A ring of `cameras` 640 × 480 cameras (600 px focal length, 56° across) 3.6 m across and
/// 2.4 m up, each looking at the middle of a volume 2 m across and 0.2–1.8 m high, where
/// `markers` spheres of 12 mm radius move: every other one round the vertical axis (radii,
/// heights and periods that differ), the rest wandering within 0.5 m of a place of their own
/// (deterministic: marker k's motion is fixed by k). Each camera runs at `fps`, rendering live
/// or (`loop_frames`) that many frames once, played in a loop.
pub fn dense_ring(cameras: usize, markers: usize, fps: f64, loop_frames: Option<u32>) -> String {
    let mut out = String::from("name = \"dense\"\nunits = \"mm\"\n\n");
    let looped = loop_frames.map_or(String::new(), |n| format!(", loop_frames = {n}"));
    for i in 0..cameras {
        let a = std::f64::consts::TAU * i as f64 / cameras as f64;
        let (x, y) = (1800.0 * a.cos(), 1800.0 * a.sin());
        out += &format!(
            "[[camera]]\nid = \"cam{i}\"\nimage_size = [640, 480]\nfocal_length_mm = 3.6\n\
             pixel_pitch_um = [6.0, 6.0]\n\
             pose = {{ position = [{x:.1}, {y:.1}, 2400.0], look_at = [0.0, 0.0, 900.0], up = [0.0, 0.0, 1.0] }}\n\
             source = {{ kind = \"synthetic\", fps = {fps}{looped} }}\n\
             moments = {{ threshold = \"auto\", max_objects = {} }}\n\n",
            (markers + 8).min(512)
        );
    }
    out += "[fusion]\nmax_skew_ms = 2.0\nmax_wait_ms = 20.0\n\n";
    out += "[synthetic]\nseed = 3\nnoise_sigma = 2.0\nbackground = 20.0\n\n";
    for k in 0..markers {
        // Golden-ratio steps spread the radii and heights evenly whatever the count.
        let u = (k as f64 * 0.618_033_988_75).fract();
        let v = (k as f64 * 0.754_877_666_25).fract();
        let r = 100.0 + 850.0 * u.sqrt();
        let z = 200.0 + 1600.0 * v;
        let motion = if k % 2 == 0 {
            let period = 4.0 + 0.37 * (k % 23) as f64;
            format!(
                "kind = \"circle\", centre = [0.0, 0.0, {z:.1}], radius = {r:.1}, period_s = {period:.2}"
            )
        } else {
            let a = std::f64::consts::TAU * (k as f64 * 0.381_966).fract();
            format!(
                "kind = \"wander\", centre = [{:.1}, {:.1}, {z:.1}], extent = [250.0, 250.0, 150.0], seed = {k}",
                r * a.cos(),
                r * a.sin()
            )
        };
        out += &format!(
            "[[synthetic.target]]\nshape = \"sphere\"\nradius = 12.0\nmotion = {{ {motion} }}\n\n"
        );
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_dense_ring_is_a_rig_that_loads() {
        let rig = crate::Rig::from_toml(&super::dense_ring(16, 512, 120.0, Some(240))).unwrap();
        assert_eq!(rig.cameras.len(), 16);
        assert_eq!(rig.spec.synthetic.as_ref().unwrap().targets.len(), 512);
        let text = super::dense_ring(3, 1, 30.0, None);
        assert!(!text.contains("loop_frames"), "{text}");
    }

    #[test]
    fn min_views_to_start_is_refused_below_two_and_above_the_cameras() {
        let with = |n: u32| {
            super::dense_ring(3, 1, 30.0, None).replace(
                "[fusion]\n",
                &format!("[fusion]\nmin_views_to_start = {n}\n"),
            )
        };
        for n in [2, 3] {
            crate::Rig::from_toml(&with(n)).unwrap();
        }
        for (n, says) in [(1, "under 2"), (4, "more than the rig's 3 cameras")] {
            let e = crate::Rig::from_toml(&with(n)).unwrap_err();
            let text = e.to_string();
            assert!(
                text.contains("fusion.min_views_to_start") && text.contains(says),
                "{text}"
            );
        }
    }
}
