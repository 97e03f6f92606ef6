//! Gap filling for offline processing and exports (not in the thesis, which had no recordings):
//! a marker missing for a few frames between two sightings is put where its rigid neighbours
//! say it was, or on a cubic through its own path where it has none.
//!
//! - **Rigid** (a marker of a rigid set, e.g. a body's markers): the three or more other
//!   markers of its set seen in every frame from the sighting before the gap to the one after
//!   carry it. In each missing frame `f`, the rigid motion taking those neighbours from the
//!   frame before the gap to `f` ([`crate::kabsch`]) moves the marker's last sighting, the one
//!   from the frame after the gap moves its next sighting, and the two are blended by where
//!   `f` lies between them (so a slow drift of the set's shape does not jump at the gap's end).
//! - **Spline** (no such neighbours): the cubic Hermite curve from the last sighting to the
//!   next, its end tangents the marker's velocity there (the step to the sighting before the
//!   last, and after the next, where they exist; else the chord).
//!
//! Only gaps with a sighting on both sides and at most `max_gap_frames` long are filled, and
//! every filled sample is reported ([`Filled`]), never mixed silently with measured ones.

use crate::kabsch;
use nalgebra::Point3;

/// Per frame: where one marker was, `None` where it was not seen.
pub type Track = Vec<Option<Point3<f64>>>;

/// How a sample was filled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FillMethod {
    Rigid,
    Spline,
}

/// One filled sample: marker (index into the tracks), frame, how.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Filled {
    pub marker: usize,
    pub frame: usize,
    pub method: FillMethod,
}

/// Fills every gap of at most `max_gap_frames` frames with a sighting on each side, in place;
/// `sets` lists the rigid sets (marker indices; a marker in none is filled by spline). Tracks
/// are taken as they were measured: a sample filled here never carries another. Returns the
/// filled samples in marker, then frame order.
pub fn fill_gaps(tracks: &mut [Track], sets: &[Vec<usize>], max_gap_frames: usize) -> Vec<Filled> {
    let measured: Vec<Track> = tracks.to_vec();
    let mut out = Vec::new();
    for m in 0..measured.len() {
        let track = &measured[m];
        let mut f = 0;
        while f < track.len() {
            if track[f].is_some() {
                f += 1;
                continue;
            }
            let start = f;
            while f < track.len() && track[f].is_none() {
                f += 1;
            }
            // Frames start..f are missing; fill only between two sightings.
            let (before, after) = (start.checked_sub(1), (f < track.len()).then_some(f));
            let (Some(before), Some(after)) = (before, after) else {
                continue;
            };
            if f - start > max_gap_frames {
                continue;
            }
            let neighbours: Vec<usize> = sets
                .iter()
                .filter(|s| s.contains(&m))
                .flat_map(|s| s.iter().copied())
                .filter(|&n| n != m && (before..=after).all(|k| measured[n][k].is_some()))
                .collect();
            for k in start..f {
                let (p, method) = match rigid(&measured, m, &neighbours, before, after, k) {
                    Some(p) => (p, FillMethod::Rigid),
                    None => (spline(track, before, after, k), FillMethod::Spline),
                };
                tracks[m][k] = Some(p);
                out.push(Filled {
                    marker: m,
                    frame: k,
                    method,
                });
            }
        }
    }
    out
}

/// Marker `m` in frame `k` from its `neighbours` (seen in every frame `before..=after`), or
/// `None` when fewer than three of them fix a rigid motion.
fn rigid(
    tracks: &[Track],
    m: usize,
    neighbours: &[usize],
    before: usize,
    after: usize,
    k: usize,
) -> Option<Point3<f64>> {
    if neighbours.len() < 3 {
        return None;
    }
    let at = |f: usize| -> Option<Vec<Point3<f64>>> {
        neighbours.iter().map(|&n| tracks[n][f]).collect()
    };
    let now = at(k)?;
    let ones = vec![1.0; neighbours.len()];
    let (from_before, _) = kabsch(&at(before)?, &now, &ones)?;
    let (from_after, _) = kabsch(&at(after)?, &now, &ones)?;
    let p_before = from_before * tracks[m][before]?;
    let p_after = from_after * tracks[m][after]?;
    let w = (k - before) as f64 / (after - before) as f64;
    Some(Point3::from(
        p_before.coords * (1.0 - w) + p_after.coords * w,
    ))
}

/// The cubic Hermite curve between the sightings at `before` and `after`, at frame `k`.
fn spline(track: &Track, before: usize, after: usize, k: usize) -> Point3<f64> {
    let (Some(p0), Some(p1)) = (track[before], track[after]) else {
        // Only called between two sightings.
        return Point3::origin();
    };
    let span = (after - before) as f64;
    let chord = (p1 - p0) / span;
    // Velocities in metres a frame at each end.
    let v0 = before
        .checked_sub(1)
        .and_then(|b| track[b])
        .map_or(chord, |q| p0 - q);
    let v1 = track
        .get(after + 1)
        .copied()
        .flatten()
        .map_or(chord, |q| q - p1);
    let t = (k - before) as f64 / span;
    let (t2, t3) = (t * t, t * t * t);
    let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
    let h10 = t3 - 2.0 * t2 + t;
    let h01 = -2.0 * t3 + 3.0 * t2;
    let h11 = t3 - t2;
    Point3::from(p0.coords * h00 + v0 * (h10 * span) + p1.coords * h01 + v1 * (h11 * span))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    use stereoscope_numeric::SplitMix64;

    const HZ: f64 = 120.0;

    /// A cluster of four markers (a body 10–14 cm across) moving 1 m/s on a circle and turning
    /// 90° a second, `frames` frames at 120 Hz, each sample with `noise_m` of noise.
    fn cluster(frames: usize, noise_m: f64) -> (Vec<Track>, Vec<Track>) {
        let layout = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(0.10, 0.0, 0.0),
            Vector3::new(0.0, 0.12, 0.0),
            Vector3::new(0.03, 0.04, 0.14),
        ];
        let mut rng = SplitMix64::new(7);
        let mut truth = vec![Vec::new(); 4];
        let mut noisy = vec![Vec::new(); 4];
        for f in 0..frames {
            let t = f as f64 / HZ;
            let a = t / 0.5; // 1 m/s on a 0.5 m circle
            let pose = Isometry3::from_parts(
                Translation3::new(0.5 * a.cos(), 0.5 * a.sin(), 1.0 + 0.1 * (2.0 * t).sin()),
                UnitQuaternion::from_euler_angles(0.3 * t, 0.2, std::f64::consts::FRAC_PI_2 * t),
            );
            for (m, l) in layout.iter().enumerate() {
                let p = pose * Point3::from(*l);
                truth[m].push(Some(p));
                let n = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise_m;
                noisy[m].push(Some(p + n));
            }
        }
        (truth, noisy)
    }

    fn worst_mm(tracks: &[Track], truth: &[Track], filled: &[Filled]) -> f64 {
        filled
            .iter()
            .map(|f| {
                let (a, b) = (
                    tracks[f.marker][f.frame].unwrap(),
                    truth[f.marker][f.frame].unwrap(),
                );
                (a - b).norm() * 1e3
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_rigid_cluster_fills_a_ten_frame_gap_within_two_millimetres() {
        let (truth, mut tracks) = cluster(240, 0.0002);
        for f in 100..110 {
            tracks[0][f] = None;
        }
        for f in 150..152 {
            tracks[2][f] = None;
        }
        let filled = fill_gaps(&mut tracks, &[vec![0, 1, 2, 3]], 10);
        assert_eq!(filled.len(), 12, "{filled:?}");
        assert!(filled.iter().all(|f| f.method == FillMethod::Rigid));
        let worst = worst_mm(&tracks, &truth, &filled);
        println!("rigid fill, 0.2 mm noise: worst {worst:.3} mm");
        assert!(
            worst < 2.0,
            "worst filled sample {worst:.3} mm from the truth"
        );
        // Measured samples are untouched.
        assert_eq!(tracks[1], cluster(240, 0.0002).1[1]);
    }

    #[test]
    fn a_loose_marker_is_filled_on_a_spline_and_long_or_open_gaps_are_left() {
        let (truth, mut tracks) = cluster(240, 0.0);
        let mut one = vec![tracks.swap_remove(0)];
        let truth = vec![truth[0].clone()];
        for f in (50..60).chain(0..5).chain(120..140).chain(235..240) {
            one[0][f] = None;
        }
        let filled = fill_gaps(&mut one, &[], 10);
        // The 10-frame gap only: the 20-frame one is too long, the ends are open.
        assert_eq!(
            filled.iter().map(|f| f.frame).collect::<Vec<_>>(),
            (50..60).collect::<Vec<_>>()
        );
        assert!(filled.iter().all(|f| f.method == FillMethod::Spline));
        let worst = worst_mm(&one, &truth, &filled);
        println!("spline fill, 10 frames at 1 m/s on a 0.5 m circle: worst {worst:.3} mm");
        assert!(worst < 2.0, "worst {worst:.3} mm");
        assert!(one[0][130].is_none() && one[0][2].is_none() && one[0][237].is_none());
    }

    #[test]
    fn a_set_with_too_few_neighbours_seen_falls_back_to_the_spline() {
        let (_, mut tracks) = cluster(60, 0.0);
        for f in 20..25 {
            tracks[0][f] = None;
            tracks[1][f] = None;
        }
        let filled = fill_gaps(&mut tracks, &[vec![0, 1, 2, 3]], 10);
        assert_eq!(filled.len(), 10);
        assert!(filled.iter().all(|f| f.method == FillMethod::Spline));
    }
}
