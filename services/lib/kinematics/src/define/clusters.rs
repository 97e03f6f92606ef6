//! Rigid clusters of markers from a take's tracks — pieces cut where an id may have passed,
//! grouped by constant distance while the model moves, found again by their shapes — the
//! grouping half of [`super`].

use super::Track;
use nalgebra::{Isometry3, Point3, Vector3};
use stereoscope_bodies::kabsch;

/// A rigid cluster: its markers (each one or more tracks never seen together), their shape
/// about its centroid, its pose in every frame where 3 of its markers were seen.
pub(super) struct Cluster {
    pub(super) markers: Vec<Vec<usize>>,
    pub(super) shape: Vec<Point3<f64>>,
    pub(super) poses: Vec<Option<Isometry3<f64>>>,
    /// RMS of the markers used about the shape, metres.
    pub(super) shape_rms_m: f64,
    /// Share of the markers' sightings left out as off their place.
    pub(super) outliers: f64,
    /// The same, per marker.
    pub(super) marker_outliers: Vec<f64>,
    /// Each marker's point in each frame (by its pieces' ids until [`by_shape`] finds them
    /// by the cluster's shape).
    pub(super) seen: Vec<Vec<Option<Point3<f64>>>>,
}

pub(super) fn observed(tracks: &[Track], marker: &[usize], f: usize) -> Option<Point3<f64>> {
    marker
        .iter()
        .find_map(|&t| tracks[t].points.get(f).copied().flatten())
}

/// A marker this far from where its cluster's other markers put it is not used in that frame
/// (an image merged with another's, an id passed to a neighbour), as a multiple of the
/// rigidity tolerance.
pub(super) const OUTLIER_TOLERANCES: f64 = 4.0;

/// The pose of `shape` in frame `f` from the markers seen there, the worst marker left out
/// while one is farther than `outlier_m` and 3 remain; with which markers were used.
pub(super) fn pose_in(
    tracks: &[Track],
    markers: &[Vec<usize>],
    shape: &[Point3<f64>],
    f: usize,
    outlier_m: f64,
) -> Option<(Isometry3<f64>, Vec<bool>)> {
    let mut used: Vec<bool> = markers
        .iter()
        .map(|m| observed(tracks, m, f).is_some())
        .collect();
    loop {
        let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = markers
            .iter()
            .zip(shape)
            .zip(&used)
            .filter(|(_, u)| **u)
            .filter_map(|((m, s), _)| observed(tracks, m, f).map(|o| (*s, o)))
            .unzip();
        if a.len() < 3 {
            return None;
        }
        let (pose, _) = kabsch(&a, &b, &vec![1.0; a.len()])?;
        let worst = (0..markers.len())
            .filter(|&k| used[k])
            .filter_map(|k| {
                Some((
                    k,
                    (pose * shape[k] - observed(tracks, &markers[k], f)?).norm(),
                ))
            })
            .max_by(|x, y| x.1.total_cmp(&y.1));
        match worst {
            Some((k, e)) if e > outlier_m && a.len() > 3 => used[k] = false,
            Some((_, e)) if e > outlier_m => return None,
            _ => return Some((pose, used)),
        }
    }
}

/// A track missing more frames than this is cut there: the id a marker had before the gap may
/// have been taken up by a neighbour after it.
pub(super) const MAX_GAP_FRAMES: usize = 2;

/// A track is cut where it lands this far from where its last two points carried on would
/// put it, metres: an id passed to a neighbouring marker jumps by the markers' spacing.
pub(super) const MAX_JUMP_M: f64 = 0.008;

/// Every track cut into its pieces seen without a gap longer than `max_gap` frames or a jump
/// off its course longer than `max_jump_m`.
pub fn split_at_gaps(
    tracks: &[Track],
    frames: usize,
    max_gap: usize,
    max_jump_m: f64,
) -> Vec<Track> {
    let mut out = Vec::new();
    for t in tracks {
        let flush = |from: usize, to: usize, out: &mut Vec<Track>| {
            let mut points = vec![None; frames];
            points[from..=to].copy_from_slice(&t.points[from..=to]);
            out.push(Track { id: t.id, points });
        };
        let mut piece: Option<(usize, usize)> = None;
        for f in 0..frames {
            let Some(p) = t.points[f] else {
                continue;
            };
            let jumped = f >= 2
                && match (t.points[f - 1], t.points[f - 2]) {
                    (Some(a), Some(b)) => (p - (a + (a - b))).norm() > max_jump_m,
                    _ => false,
                };
            piece = match piece {
                Some((from, last)) if f - last <= max_gap + 1 && !jumped => Some((from, f)),
                Some((from, last)) => {
                    flush(from, last, &mut out);
                    Some((f, f))
                }
                None => Some((f, f)),
            };
        }
        if let Some((from, last)) = piece {
            flush(from, last, &mut out);
        }
    }
    out
}

/// Frames over which nothing moved: no track (but one in twenty) went further than `4 · tol_m` over the 10
/// frames about it. At such a time every pair of markers keeps its distance, so rigidity is
/// judged from the other frames only.
pub(super) fn still_frames(tracks: &[Track], frames: usize, tol_m: f64) -> Vec<bool> {
    const SPAN: usize = 5;
    (0..frames)
        .map(|f| {
            let (a, b) = (f.saturating_sub(SPAN), (f + SPAN).min(frames - 1));
            let (mut seen, mut moved) = (0usize, 0usize);
            for t in tracks {
                if let (Some(p), Some(q)) = (t.points[a], t.points[b]) {
                    seen += 1;
                    if (p - q).norm() > 4.0 * tol_m {
                        moved += 1;
                    }
                }
            }
            // One track in twenty may jump (a ghost, an id passed on) in a still scene.
            seen > 0 && moved <= (seen / 20).max(1) - usize::from(seen < 20)
        })
        .collect()
}

/// Tracks grouped by constant distance, clusters of 3 or more: pairs joined most rigid first,
/// two groups only where nearly every pair across them seen together is rigid too (one pair
/// that keeps its distance across a joint — a marker near the axis — does not join two links).
pub(super) fn rigid_groups(
    tracks: &[Track],
    keep: &[usize],
    tol_m: f64,
    still: &[bool],
) -> Vec<Vec<usize>> {
    let n = keep.len();
    let mut spread: Vec<Option<f64>> = vec![None; n * n];
    let mut d = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            d.clear();
            // Only while the model moves: standing at its zero pose, every pair is rigid.
            for ((p, q), still) in tracks[keep[i]]
                .points
                .iter()
                .zip(&tracks[keep[j]].points)
                .zip(still)
            {
                if let (Some(p), Some(q), false) = (p, q, still) {
                    d.push((p - q).norm());
                }
            }
            // Seen together a second or more at 60 fps: over a shorter while a joint may
            // barely have moved.
            if d.len() < 60 {
                continue;
            }
            // Robust: the median absolute deviation as a standard deviation, so that a few
            // frames where a marker's image merged with another's do not part a link.
            d.sort_by(f64::total_cmp);
            let median = d[d.len() / 2];
            for x in d.iter_mut() {
                *x = (*x - median).abs();
            }
            d.sort_by(f64::total_cmp);
            let sd = 1.4826 * d[d.len() / 2];
            spread[i * n + j] = Some(sd);
            spread[j * n + i] = Some(sd);
        }
    }
    let mut edges: Vec<(f64, usize, usize)> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .filter_map(|(i, j)| spread[i * n + j].filter(|s| *s < tol_m).map(|s| (s, i, j)))
        .collect();
    edges.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut group: Vec<usize> = (0..n).collect();
    for (_, i, j) in edges {
        let (gi, gj) = (group[i], group[j]);
        if gi == gj {
            continue;
        }
        let (mut rigid, mut seen) = (0usize, 0usize);
        for a in (0..n).filter(|&a| group[a] == gi) {
            for b in (0..n).filter(|&b| group[b] == gj) {
                if let Some(s) = spread[a * n + b] {
                    seen += 1;
                    if s < 2.0 * tol_m {
                        rigid += 1;
                    }
                }
            }
        }
        if rigid * 4 >= seen * 3 {
            for g in group.iter_mut() {
                if *g == gj {
                    *g = gi;
                }
            }
        }
    }
    let mut groups: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for i in 0..n {
        groups.entry(group[i]).or_default().push(keep[i]);
    }
    groups.into_values().filter(|g| g.len() >= 3).collect()
}

/// A group's shape: placed from the frame that shows most of it, each other marker placed
/// from a frame that shows it with 3 placed ones; then twice refined as the mean of every
/// frame's markers brought into the shape's frame. Tracks at one place never seen together
/// are one marker whose track broke.
pub(super) fn build_cluster(
    tracks: &[Track],
    group: &[usize],
    frames: usize,
    merge_m: f64,
    outlier_m: f64,
    initial: Option<Vec<Option<Point3<f64>>>>,
) -> Cluster {
    let seen_at = |t: usize, f: usize| tracks[t].points[f].is_some();
    let best = (0..frames)
        .max_by_key(|&f| group.iter().filter(|&&t| seen_at(t, f)).count())
        .unwrap_or(0);
    let mut place: Vec<Option<Point3<f64>>> =
        initial.unwrap_or_else(|| group.iter().map(|&t| tracks[t].points[best]).collect());
    for _ in 0..group.len() {
        let missing: Vec<usize> = (0..group.len()).filter(|&k| place[k].is_none()).collect();
        if missing.is_empty() {
            break;
        }
        for k in missing {
            for f in 0..frames {
                let Some(p) = tracks[group[k]].points[f] else {
                    continue;
                };
                let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = (0..group.len())
                    .filter_map(|i| Some((place[i]?, tracks[group[i]].points[f]?)))
                    .unzip();
                if a.len() >= 3
                    && let Some((world_from_shape, _)) = kabsch(&a, &b, &vec![1.0; a.len()])
                {
                    place[k] = Some(world_from_shape.inverse() * p);
                    break;
                }
            }
        }
    }
    let placed: Vec<(usize, Point3<f64>)> = place
        .iter()
        .enumerate()
        .filter_map(|(k, p)| p.map(|p| (k, p)))
        .collect();
    // Tracks at one place (within merge_m) never seen together are one marker.
    let mut markers: Vec<Vec<usize>> = Vec::new();
    let mut shape: Vec<Point3<f64>> = Vec::new();
    for (k, p) in placed {
        let t = group[k];
        let same = (0..markers.len()).find(|&i| {
            (shape[i] - p).norm() < merge_m
                && markers[i]
                    .iter()
                    .all(|&u| (0..frames).all(|f| !(seen_at(u, f) && seen_at(t, f))))
        });
        match same {
            Some(i) => markers[i].push(t),
            None => {
                markers.push(vec![t]);
                shape.push(p);
            }
        }
    }
    let mut poses = vec![None; frames];
    let mut rms = 0.0;
    let mut outliers = 0.0;
    let mut marker_seen = vec![0usize; markers.len()];
    let mut count = vec![0usize; markers.len()];
    for _ in 0..3 {
        let mut sum = vec![Vector3::zeros(); shape.len()];
        count.iter_mut().for_each(|x| *x = 0);
        let (mut sq, mut n, mut seen) = (0.0, 0usize, 0usize);
        marker_seen.iter_mut().for_each(|x| *x = 0);
        for (f, pose) in poses.iter_mut().enumerate() {
            let found = pose_in(tracks, &markers, &shape, f, outlier_m);
            let visible = markers
                .iter()
                .filter(|m| observed(tracks, m, f).is_some())
                .count();
            if visible >= 3 {
                seen += visible;
                for (k, m) in markers.iter().enumerate() {
                    if observed(tracks, m, f).is_some() {
                        marker_seen[k] += 1;
                    }
                }
            }
            *pose = found.as_ref().map(|(p, _)| *p);
            let Some((world_from_shape, used)) = found else {
                continue;
            };
            let shape_from_world = world_from_shape.inverse();
            for (k, m) in markers.iter().enumerate() {
                if let (true, Some(o)) = (used[k], observed(tracks, m, f)) {
                    let local = shape_from_world * o;
                    sq += (local - shape[k]).norm_squared();
                    n += 1;
                    sum[k] += local.coords;
                    count[k] += 1;
                }
            }
        }
        rms = (sq / n.max(1) as f64).sqrt();
        outliers = 1.0 - n as f64 / seen.max(1) as f64;
        for k in 0..shape.len() {
            if count[k] > 0 {
                shape[k] = Point3::from(sum[k] / count[k] as f64);
            }
        }
        let c = shape.iter().map(|p| p.coords).sum::<Vector3<f64>>() / shape.len() as f64;
        for p in &mut shape {
            *p -= c;
        }
    }
    for (f, pose) in poses.iter_mut().enumerate() {
        *pose = pose_in(tracks, &markers, &shape, f, outlier_m).map(|(p, _)| p);
    }
    let marker_outliers = marker_seen
        .iter()
        .zip(&count)
        .map(|(&s, &c)| {
            if s == 0 {
                0.0
            } else {
                1.0 - c as f64 / s as f64
            }
        })
        .collect();
    let seen = markers
        .iter()
        .map(|m| (0..frames).map(|f| observed(tracks, m, f)).collect())
        .collect();
    Cluster {
        markers,
        shape,
        poses,
        shape_rms_m: rms,
        outliers,
        marker_outliers,
        seen,
    }
}

/// Pieces on no cluster taken up by the cluster they ride on: brought into its frame wherever
/// it is posed, they stay at one place (robust spread under `tol_m`, over 20 frames or more).
/// A piece fits the cluster it spreads least in; pieces at one of its markers' places that
/// are never seen with it are that marker (its id changed), the others new markers.
#[allow(clippy::too_many_arguments)]
pub(super) fn absorb(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    keep: &[usize],
    still: &[bool],
    frames: usize,
    tol_m: f64,
    merge_m: f64,
    outlier_m: f64,
) -> Vec<Cluster> {
    let used: std::collections::HashSet<usize> = clusters
        .iter()
        .flat_map(|c| c.markers.iter().flatten().copied())
        .collect();
    let mut taken: Vec<Vec<(usize, Point3<f64>)>> = vec![Vec::new(); clusters.len()];
    let mut local = Vec::new();
    for &t in keep.iter().filter(|t| !used.contains(t)) {
        let mut best: Option<(f64, usize, Point3<f64>)> = None;
        for (ci, c) in clusters.iter().enumerate() {
            local.clear();
            for f in (0..frames).filter(|&f| !still[f]) {
                if let (Some(pose), Some(p)) = (c.poses[f], tracks[t].points[f]) {
                    local.push(pose.inverse() * p);
                }
            }
            if local.len() < 20 {
                continue;
            }
            let median = |k: usize, v: &[Point3<f64>]| {
                let mut x: Vec<f64> = v.iter().map(|p| p[k]).collect();
                x.sort_by(f64::total_cmp);
                x[x.len() / 2]
            };
            let at = Point3::new(median(0, &local), median(1, &local), median(2, &local));
            let mut off: Vec<f64> = local.iter().map(|p| (p - at).norm()).collect();
            off.sort_by(f64::total_cmp);
            // The median distance from the median, as a per-axis deviation (χ with 3 degrees
            // of freedom has its median at 1.54 σ).
            let spread = off[off.len() / 2] / 1.54;
            if spread < tol_m && best.is_none_or(|b| spread < b.0) {
                best = Some((spread, ci, at));
            }
        }
        if let Some((_, ci, at)) = best {
            taken[ci].push((t, at));
        }
    }
    for (ci, new) in taken.into_iter().enumerate() {
        if new.is_empty() {
            continue;
        }
        let c = &clusters[ci];
        let (mut group, mut place) = (Vec::new(), Vec::new());
        for (m, s) in c.markers.iter().zip(&c.shape) {
            for &t in m {
                group.push(t);
                place.push(Some(*s));
            }
        }
        for (t, at) in new {
            group.push(t);
            place.push(Some(at));
        }
        clusters[ci] = build_cluster(tracks, &group, frames, merge_m, outlier_m, Some(place));
    }
    clusters
}

/// Every cluster found in every frame by its shape, whatever the ids (`stereoscope_bodies::
/// identify_near`, all clusters at once, no point used twice, continuity from the last
/// frame): a link whose markers' ids changed is found all the same. A first pass also looks,
/// in each cluster's frame, for points no cluster explains that stay at one place (a marker
/// whose pieces were all too short to group): new markers. Clusters of more than
/// `stereoscope_bodies::MAX_MARKERS` markers keep what their ids gave.
pub(super) fn by_shape(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    still: &[bool],
    frames: usize,
    tol_m: f64,
    merge_m: f64,
) -> (Vec<Cluster>, Vec<bool>) {
    let mut used_track = vec![false; tracks.len()];
    for round in 0..2 {
        let ok: Vec<usize> = (0..clusters.len())
            .filter(|&c| (3..=stereoscope_bodies::MAX_MARKERS).contains(&clusters[c].shape.len()))
            .collect();
        let defs: Vec<stereoscope_bodies::BodyDef> = ok
            .iter()
            .map(|&c| stereoscope_bodies::BodyDef {
                name: format!("cluster {c}"),
                markers_m: clusters[c].shape.clone(),
                tolerance_m: 2.0 * tol_m,
            })
            .collect();
        let mut near: Vec<Option<Isometry3<f64>>> = vec![None; ok.len()];
        let mut loose: Vec<Vec<Point3<f64>>> = vec![Vec::new(); clusters.len()];
        let mut points = Vec::new();
        let mut owner = Vec::new();
        for f in 0..frames {
            points.clear();
            owner.clear();
            for (t, tr) in tracks.iter().enumerate() {
                if let Some(p) = tr.points[f] {
                    points.push(p);
                    owner.push(t);
                }
            }
            let found = stereoscope_bodies::identify_near(&defs, &points, &near);
            let mut explained = vec![false; points.len()];
            // A cluster not found by its shape (a symmetric one seen from nothing) keeps what
            // its ids gave.
            for m in &found {
                let c = ok[m.body];
                clusters[c].poses[f] = Some(m.world_from_body);
                for (k, i) in m.markers.iter().enumerate() {
                    clusters[c].seen[k][f] = i.map(|i| points[i]);
                }
            }
            for (b, &c) in ok.iter().enumerate() {
                near[b] = clusters[c].poses[f];
                for s in &clusters[c].seen {
                    if let Some(p) = s[f]
                        && let Some(i) = points.iter().position(|q| *q == p)
                    {
                        explained[i] = true;
                        used_track[owner[i]] = true;
                    }
                }
            }
            if round == 0 && !still[f] {
                for (c, cluster) in clusters.iter().enumerate() {
                    let Some(pose) = cluster.poses[f] else {
                        continue;
                    };
                    let inv = pose.inverse();
                    for (i, p) in points.iter().enumerate() {
                        let local = inv * p;
                        // Within a link's reach of its markers.
                        if !explained[i] && local.coords.norm() < 0.4 {
                            loose[c].push(local);
                        }
                    }
                }
            }
        }
        if round == 1 {
            break;
        }
        // New markers: places in a cluster's frame where loose points gather in 30 frames or
        // more (a quarter of its posed frames at least), clear of its markers.
        let mut grew = false;
        for (c, pts) in loose.iter().enumerate() {
            let posed = clusters[c].poses.iter().flatten().count();
            let need = 30.max(posed / 4);
            let mut left: Vec<Point3<f64>> = pts.clone();
            while clusters[c].shape.len() < stereoscope_bodies::MAX_MARKERS && left.len() >= need {
                // The densest point's neighbourhood.
                let mut best = (0usize, 0usize);
                for (i, p) in left.iter().enumerate().step_by((left.len() / 400).max(1)) {
                    let n = left.iter().filter(|q| (*q - p).norm() < merge_m).count();
                    if n > best.1 {
                        best = (i, n);
                    }
                }
                if best.1 < need {
                    break;
                }
                let centre = left[best.0];
                let close: Vec<Point3<f64>> = left
                    .iter()
                    .filter(|q| (*q - centre).norm() < merge_m)
                    .copied()
                    .collect();
                let mean = Point3::from(
                    close.iter().map(|p| p.coords).sum::<Vector3<f64>>() / close.len() as f64,
                );
                left.retain(|q| (q - centre).norm() >= merge_m);
                let clear = clusters[c]
                    .shape
                    .iter()
                    .all(|s| (s - mean).norm() > 2.0 * merge_m);
                if clear {
                    clusters[c].shape.push(mean);
                    clusters[c].markers.push(Vec::new());
                    clusters[c].seen.push(vec![None; frames]);
                    clusters[c].marker_outliers.push(0.0);
                    grew = true;
                }
            }
        }
        if !grew {
            break;
        }
    }
    // Markers found in under a quarter of the frames their cluster is posed in are dropped (a
    // neighbour's marker near a joint that seldom moved), then the shapes again from what was
    // found, and the poses from them.
    for c in clusters.iter_mut() {
        let posed = c.poses.iter().flatten().count().max(1);
        let keep: Vec<bool> = c
            .seen
            .iter()
            .map(|s| s.iter().flatten().count() * 4 >= posed)
            .collect();
        if keep.iter().filter(|k| **k).count() >= 3 {
            let mut k = 0;
            c.shape.retain(|_| {
                k += 1;
                keep[k - 1]
            });
            let mut k = 0;
            c.seen.retain(|_| {
                k += 1;
                keep[k - 1]
            });
            let mut k = 0;
            c.markers.retain(|_| {
                k += 1;
                keep[k - 1]
            });
        }
        for (k, s) in c.shape.iter_mut().enumerate() {
            let (mut sum, mut n) = (Vector3::zeros(), 0usize);
            for f in 0..frames {
                if let (Some(pose), Some(p)) = (c.poses[f], c.seen[k][f]) {
                    sum += (pose.inverse() * p).coords;
                    n += 1;
                }
            }
            if n > 0 {
                *s = Point3::from(sum / n as f64);
            }
        }
        for f in 0..frames {
            let (a, b): (Vec<Point3<f64>>, Vec<Point3<f64>>) = c
                .shape
                .iter()
                .zip(&c.seen)
                .filter_map(|(s, seen)| seen[f].map(|p| (*s, p)))
                .unzip();
            c.poses[f] = if a.len() >= 3 {
                kabsch(&a, &b, &vec![1.0; a.len()]).map(|(p, _)| p)
            } else {
                None
            };
        }
    }
    (clusters, used_track)
}

/// Where `shape` lies among `points`: every way of putting three of its markers on three points
/// whose distances agree within `tol_m`, the rest of its markers then on their nearest points;
/// the way that puts the most markers within `tol_m` of a point, then with the least residual.
pub(super) fn place_shape(
    shape: &[Point3<f64>],
    points: &[Point3<f64>],
    tol_m: f64,
) -> Option<Isometry3<f64>> {
    let (n, m) = (shape.len(), points.len());
    let d = |a: &Point3<f64>, b: &Point3<f64>| (a - b).norm();
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let (sij, sjk, sik) = (
                    d(&shape[i], &shape[j]),
                    d(&shape[j], &shape[k]),
                    d(&shape[i], &shape[k]),
                );
                for p in 0..m {
                    for q in 0..m {
                        if q == p || (d(&points[p], &points[q]) - sij).abs() > tol_m {
                            continue;
                        }
                        for r in 0..m {
                            if r == p
                                || r == q
                                || (d(&points[q], &points[r]) - sjk).abs() > tol_m
                                || (d(&points[p], &points[r]) - sik).abs() > tol_m
                            {
                                continue;
                            }
                            let from = [shape[i], shape[j], shape[k]];
                            let to = [points[p], points[q], points[r]];
                            let Some((pose, _)) = kabsch(&from, &to, &[1.0; 3]) else {
                                continue;
                            };
                            let (mut a, mut b) = (Vec::new(), Vec::new());
                            for s in shape {
                                let at = pose * s;
                                if let Some(near) = points
                                    .iter()
                                    .min_by(|x, y| d(x, &at).total_cmp(&d(y, &at)))
                                    .filter(|x| d(x, &at) < tol_m)
                                {
                                    a.push(*s);
                                    b.push(*near);
                                }
                            }
                            let Some((pose, rms)) = kabsch(&a, &b, &vec![1.0; a.len()]) else {
                                continue;
                            };
                            if best
                                .as_ref()
                                .is_none_or(|(c, e, _)| a.len() > *c || (a.len() == *c && rms < *e))
                            {
                                best = Some((a.len(), rms, pose));
                            }
                        }
                    }
                }
            }
        }
    }
    best.map(|(_, _, p)| p)
}

/// Frames in which both clusters are posed.
pub(super) fn co_posed(a: &Cluster, b: &Cluster) -> usize {
    a.poses
        .iter()
        .zip(&b.poses)
        .filter(|(x, y)| x.is_some() && y.is_some())
        .count()
}

/// Where `b`'s shape lies in `a`'s frame when three of its markers match three of `a`'s
/// (distances within `tol_m`) and every other marker of `b` either lands on one of `a`'s or
/// well apart from all: the same link seen under other ids at another time.
pub(super) fn same_link(a: &Cluster, b: &Cluster, tol_m: f64) -> Option<Isometry3<f64>> {
    let (na, nb) = (a.shape.len(), b.shape.len());
    let d = |s: &[Point3<f64>], i: usize, j: usize| (s[i] - s[j]).norm();
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    for i in 0..nb {
        for j in 0..nb {
            for k in 0..nb {
                if i == j || j == k || i == k || !(i < j && j < k) {
                    continue;
                }
                for p in 0..na {
                    for q in 0..na {
                        for r in 0..na {
                            if p == q || q == r || p == r {
                                continue;
                            }
                            let ok = (d(&b.shape, i, j) - d(&a.shape, p, q)).abs() < tol_m
                                && (d(&b.shape, j, k) - d(&a.shape, q, r)).abs() < tol_m
                                && (d(&b.shape, i, k) - d(&a.shape, p, r)).abs() < tol_m;
                            if !ok {
                                continue;
                            }
                            let from = [b.shape[i], b.shape[j], b.shape[k]];
                            let to = [a.shape[p], a.shape[q], a.shape[r]];
                            let Some((a_from_b, _)) = kabsch(&from, &to, &[1.0; 3]) else {
                                continue;
                            };
                            let (mut matched, mut sq, mut fits) = (0usize, 0.0, true);
                            for s in &b.shape {
                                let at = a_from_b * s;
                                let near = a
                                    .shape
                                    .iter()
                                    .map(|x| (x - at).norm())
                                    .fold(f64::INFINITY, f64::min);
                                if near < tol_m {
                                    matched += 1;
                                    sq += near * near;
                                } else if near < 3.0 * tol_m {
                                    fits = false;
                                }
                            }
                            if fits
                                && matched >= 3
                                && best.as_ref().is_none_or(|(m, e, _)| {
                                    matched > *m || (matched == *m && sq < *e)
                                })
                            {
                                best = Some((matched, sq, a_from_b));
                            }
                        }
                    }
                }
            }
        }
    }
    best.map(|(_, _, p)| p)
}

/// Clusters of one link seen at different times (every marker's id changed while the link was
/// hidden) joined: never posed together, and their shapes match.
pub(super) fn join_time_apart(
    tracks: &[Track],
    mut clusters: Vec<Cluster>,
    frames: usize,
    tol_m: f64,
    merge_m: f64,
    outlier_m: f64,
) -> Vec<Cluster> {
    // Pairs tried and refused, by their first tracks.
    let mut refused: Vec<(usize, usize)> = Vec::new();
    let key = |c: &Cluster| c.markers.iter().flatten().copied().min().unwrap_or(0);
    'again: loop {
        for a in 0..clusters.len() {
            for b in 0..clusters.len() {
                if a == b
                    || co_posed(&clusters[a], &clusters[b]) >= 20
                    || refused.contains(&(key(&clusters[a]), key(&clusters[b])))
                {
                    continue;
                }
                // The larger (or the first) keeps its frame.
                if clusters[b].shape.len() > clusters[a].shape.len() {
                    continue;
                }
                let Some(a_from_b) = same_link(&clusters[a], &clusters[b], tol_m) else {
                    continue;
                };
                let (mut group, mut place) = (Vec::new(), Vec::new());
                for (m, s) in clusters[a].markers.iter().zip(&clusters[a].shape) {
                    for &t in m {
                        group.push(t);
                        place.push(Some(*s));
                    }
                }
                for (m, s) in clusters[b].markers.iter().zip(&clusters[b].shape) {
                    for &t in m {
                        group.push(t);
                        place.push(Some(a_from_b * s));
                    }
                }
                let joined = build_cluster(tracks, &group, frames, merge_m, outlier_m, Some(place));
                // Seen together now and then, they must still be one rigid shape.
                let before = clusters[a].shape_rms_m.max(clusters[b].shape_rms_m);
                if joined.shape_rms_m > 1.5 * before + 0.25 * tol_m {
                    refused.push((key(&clusters[a]), key(&clusters[b])));
                    continue;
                }
                let (hi, lo) = (a.max(b), a.min(b));
                clusters.remove(hi);
                clusters.remove(lo);
                clusters.push(joined);
                continue 'again;
            }
        }
        return clusters;
    }
}
