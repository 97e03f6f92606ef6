//! One frame set to poses: cross-camera correspondence and triangulation (thesis Eq. 4.28–4.38
//! generalised to N calibrated cameras, `stereoscope_geometry::correspond`), single-camera
//! depth from area for blobs only one camera sees (Eq. 4.15–4.27,
//! `stereoscope_geometry::depth`), world heading from the blobs' axes (Eq. 3.44 per camera,
//! fused in `stereoscope_geometry::world_heading`) unwrapped over frames into 0–360°
//! (§4.1.1, `stereoscope_vision::heading`), and object identities over time: a
//! constant-velocity prediction per object and a global minimum-cost assignment of points to
//! predictions within a gate. Ids are never reused while fusion runs.
//!
//! Correspondence knows the followed objects: each object seen in the last set is predicted
//! and projected into every camera, and a blob within `claim_px` of an object's projection is
//! claimed by it. Two blobs claimed by different objects only are never paired
//! (`stereoscope_geometry::correspond::match_labelled`): two markers on one epipolar line
//! (image row in the parallel rig) cannot pair crosswise into ghosts while they are followed.

use nalgebra::{Point2, Point3, Vector3};
use stereoscope_geometry::Camera;
use stereoscope_geometry::correspond::{ByX, Claims, CorrespondConfig, Match, match_labelled};
use stereoscope_geometry::depth::{on_axis_area, point_from_depth};
use stereoscope_geometry::triangulate::{Observation as View, triangulate};
use stereoscope_geometry::world_heading::{AxisView, fuse};
use stereoscope_numeric::angle::wrap_half_turn_deg;
use stereoscope_numeric::assign::Assigner;
use stereoscope_numeric::heading::{HeadingConfig, HeadingTracker};
use stereoscope_proto::messages::{BlobObservation, Observation, Pose, PoseMethod, TrackState};
use stereoscope_rig::RigCamera;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FuserConfig {
    pub correspond: CorrespondConfig,
    /// Largest distance of a point from an object's prediction to continue it, metres, for an
    /// object seen in the last set.
    pub gate_m: f64,
    /// How much the gate widens for each second an object has gone unseen, metres per second:
    /// the prediction of an object lost behind an occlusion or through a camera restart grows
    /// uncertain, and it should still find the object when it reappears near it.
    pub gate_growth_m_per_s: f64,
    /// An object unseen this long is forgotten.
    pub drop_after_ns: u64,
    /// Above this roundness a blob's axis is not used for heading.
    pub max_roundness: f64,
    /// A new point becomes an object — gets an id and is published — once it was continued in
    /// this many consecutive sets; until then it is tentative and dropped the first set it is
    /// missing from. A ghost of a wrong correspondence (start-up, two targets on one epipolar
    /// line) rarely lasts that long, and never takes an id.
    pub confirm_sets: u32,
    /// Two triangulated points of one set closer than this are one marker seen twice (by two
    /// groups of cameras the correspondence paired separately): the one from more cameras (then
    /// the smaller residual) is kept. Markers cannot be closer than their diameter.
    pub merge_m: f64,
    /// The capture volume, world metres (min and max corners): a point outside it is no
    /// target (a wrong correspondence triangulated beyond the scene, a reflection) and is
    /// dropped and counted before it can become an object. `None`: no bound.
    pub volume_m: Option<(Point3<f64>, Point3<f64>)>,
    /// A blob within this many pixels of where a followed object's prediction projects is
    /// claimed by that object, and is not paired with a blob only other objects claim
    /// (0: no claims).
    pub claim_px: f64,
    /// A sphere's image has the same area × distance² in every camera: a blob of a match
    /// whose area × distance² exceeds this many times that of the match's round blob (a
    /// sphere's image, roundness ≥ 0.8) holds another marker's image too (two markers merged
    /// in that view, whatever the 2D tracker saw) and leaves the match.
    pub max_area_ratio: f64,
    /// A triangulated point that continues no object starts one (a tentative object) only
    /// when this many cameras see it whole (blobs not cut by an edge; 2 asks only that it was
    /// triangulated), an object unseen in the last set is taken up again only so, and a
    /// tentative object's set counts towards `confirm_sets` only when it does; an object
    /// followed from the last set continues with two. A ghost of a wrong pair has only its
    /// pair's views, and where a third camera looks it is found out by correspondence
    /// (`stereoscope_geometry::correspond`), but near the volume's edges only two cameras may
    /// look. (Optical motion capture's "cameras to start a trajectory".)
    pub min_views_to_start: usize,
}

/// [`FuserConfig::confirm_sets`] by default.
pub const DEFAULT_CONFIRM_SETS: u32 = 3;

impl Default for FuserConfig {
    fn default() -> Self {
        FuserConfig {
            correspond: CorrespondConfig::default(),
            gate_m: 0.1,
            gate_growth_m_per_s: 0.5,
            drop_after_ns: 2_000_000_000,
            max_roundness: 0.9,
            confirm_sets: DEFAULT_CONFIRM_SETS,
            merge_m: 0.01,
            volume_m: None,
            claim_px: 6.0,
            max_area_ratio: 1.6,
            min_views_to_start: 2,
        }
    }
}

/// A 3D point recovered from one set, before identities.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub position_m: Point3<f64>,
    pub method: PoseMethod,
    /// `(camera, blob)` indices into the set.
    pub blobs: Vec<(usize, usize)>,
    pub residual_px: f64,
    pub out_of_range: bool,
}

#[derive(Debug, Clone)]
struct Object {
    /// 0 while tentative (not yet continued in `confirm_sets` sets).
    id: u32,
    /// Consecutive sets it was continued in, while tentative.
    hits: u32,
    position_m: Point3<f64>,
    velocity_m_per_s: Vector3<f64>,
    last_seen_ns: u64,
    heading: HeadingTracker,
    heading_deg: Option<f64>,
    heading_directed: bool,
}

impl Object {
    /// Where it should be at `timestamp_ns`, and how far from there a point may continue it.
    fn predict(&self, cfg: &FuserConfig, timestamp_ns: u64) -> (Point3<f64>, f64) {
        let dt = timestamp_ns.saturating_sub(self.last_seen_ns) as f64 * 1e-9;
        (
            self.position_m + self.velocity_m_per_s * dt,
            cfg.gate_m + cfg.gate_growth_m_per_s * dt,
        )
    }
}

/// Keeps the objects of one rig over time.
#[derive(Debug)]
pub struct Fuser {
    cfg: FuserConfig,
    cameras: Vec<Camera>,
    ids: Vec<String>,
    depth: Vec<Option<stereoscope_rig::DepthFromArea>>,
    objects: Vec<Object>,
    next_id: u32,
    assigner: Assigner,
    /// The time of the last set fused.
    last_set_ns: Option<u64>,
    /// Per object published in the last set: what each camera saw of it.
    pixels: Vec<(u32, Sightings)>,
    /// Points dropped for lying outside the capture volume, since start.
    pub outside_volume: u64,
    /// In a rig of several cameras, blobs no other camera matched, since start (no point:
    /// see [`Fuser::points`]).
    pub single_view_unmatched: u64,
    /// Blobs taken out of a match for an area out of line with its other views
    /// ([`FuserConfig::max_area_ratio`]), since start.
    pub area_mismatch: u64,
    /// Blobs that touch the frame's edge or their window's (cut images), since start: their
    /// points are published, but their pixels refine no body's pose ([`Fuser::pixels_of`]).
    pub clipped: u64,
    /// Blobs left out because another followed object's image is hidden in them
    /// (`Fuser::hiding`).
    pub hiding_blobs: u64,
    /// Triangulated points that continued no object and started none, seen by fewer than
    /// [`FuserConfig::min_views_to_start`] cameras, since start.
    pub too_few_views: u64,
    /// Rigid bodies' markers unseen in the last set (`expect_unseen`): when, and each one's
    /// world position and velocity.
    unseen: (u64, Vec<MarkerMotion>),
}

/// What each camera saw of one object: (rig camera index, pixel as measured).
pub type Sightings = Vec<(usize, Point2<f64>)>;

/// Points closer than `merge_m` are one marker seen twice: keeps, of each such group, the point
/// from the most cameras (then the smallest residual).
fn merge_duplicates(mut points: Vec<Point>, merge_m: f64) -> Vec<Point> {
    points.sort_by(|a, b| {
        b.blobs
            .len()
            .cmp(&a.blobs.len())
            .then(a.residual_px.total_cmp(&b.residual_px))
    });
    let mut kept: Vec<Point> = Vec::with_capacity(points.len());
    for p in points {
        if !kept
            .iter()
            .any(|k| (k.position_m - p.position_m).norm() < merge_m)
        {
            kept.push(p);
        }
    }
    kept
}

/// A blob fusion measures from: seen this frame, and not two objects' merged images (whose
/// centroid lies between them: a point there would be a ghost).
/// A marker's world position (metres) and velocity (metres per second).
pub type MarkerMotion = (Point3<f64>, Vector3<f64>);

/// How recently an object must have been seen for `Fuser::hiding` to look for its image.
const HIDDEN_WITHIN_NS: u64 = 200_000_000;

fn usable(b: &BlobObservation) -> bool {
    b.status != TrackState::Lost
        && !b.merged
        && b.x_px.is_finite()
        && b.y_px.is_finite()
        && b.area_px > 0.0
}

impl Fuser {
    /// A fuser for `cameras` (the rig's, in its order: observations name them by index).
    pub fn new(cameras: &[RigCamera], cfg: FuserConfig) -> Self {
        Fuser {
            cfg,
            cameras: cameras.iter().map(|c| c.camera).collect(),
            ids: cameras.iter().map(|c| c.id.clone()).collect(),
            depth: cameras.iter().map(|c| c.depth_from_area).collect(),
            objects: Vec::new(),
            next_id: 1,
            assigner: Assigner::default(),
            last_set_ns: None,
            pixels: Vec::new(),
            outside_volume: 0,
            single_view_unmatched: 0,
            area_mismatch: 0,
            clipped: 0,
            hiding_blobs: 0,
            too_few_views: 0,
            unseen: (0, Vec::new()),
        }
    }

    /// Objects with an id (tentative ones not counted).
    pub fn objects(&self) -> usize {
        self.objects.iter().filter(|o| o.id != 0).count()
    }

    /// Whether object `id` is still followed (seen, or unseen for less than `drop_after`).
    pub fn has_object(&self, id: u32) -> bool {
        id != 0 && self.objects.iter().any(|o| o.id == id)
    }

    /// Numbers new objects from `first` on (a restarted fusion continuing its session).
    pub fn with_first_id(mut self, first: u32) -> Self {
        self.next_id = first.max(1);
        self
    }

    /// The id the next new object gets.
    pub fn next_id(&self) -> u32 {
        self.next_id
    }

    /// Per set camera and kept blob: the objects of the last set whose prediction at
    /// `timestamp_ns` projects within `claim_px` of it.
    fn claims(
        &self,
        set: &[(usize, Observation)],
        pixels: &[Vec<Point2<f64>>],
        timestamp_ns: u64,
    ) -> Vec<Vec<Claims>> {
        let mut out: Vec<Vec<Claims>> = pixels.iter().map(|p| vec![Vec::new(); p.len()]).collect();
        if self.cfg.claim_px <= 0.0 {
            return out;
        }
        let by_x: Vec<ByX> = pixels.iter().map(|p| ByX::new(p)).collect();
        for o in &self.objects {
            if o.id == 0 || self.last_set_ns != Some(o.last_seen_ns) {
                continue;
            }
            let (predicted, _) = o.predict(&self.cfg, timestamp_ns);
            for (s, (c, _)) in set.iter().enumerate() {
                let Some(q) = self.cameras[*c].project(&predicted) else {
                    continue;
                };
                for (j, _) in by_x[s].near(&pixels[s], q, self.cfg.claim_px) {
                    out[s][j].push(o.id);
                }
            }
        }
        out
    }

    /// Where the markers of the bodies found in the set of `timestamp_ns` that were not seen
    /// are (world position and velocity, from each body's pose): `Fuser::hiding` looks for
    /// them in the next set's blobs.
    pub fn expect_unseen(&mut self, timestamp_ns: u64, markers: Vec<MarkerMotion>) {
        self.unseen = (timestamp_ns, markers);
    }

    /// Per set camera and kept blob: whether it hides another object's image. A followed
    /// object (seen within [`HIDDEN_WITHIN_NS`]), or a found body's unseen marker
    /// ([`Fuser::expect_unseen`]), that no blob of a view claims, and whose
    /// prediction projects inside a blob's box there, is behind or merged with that blob's
    /// target in that view: the blob's centroid is of a shape cut or grown by the other (a
    /// marker passing in front of a double ball moved its centroid 1.4 px, 6 cm in depth),
    /// before its area or the worker's merge rule shows it. Its blob gives no point.
    fn hiding(
        &self,
        set: &[(usize, Observation)],
        kept: &[Vec<usize>],
        pixels: &[Vec<Point2<f64>>],
        timestamp_ns: u64,
    ) -> Vec<Vec<bool>> {
        let mut out: Vec<Vec<bool>> = pixels.iter().map(|p| vec![false; p.len()]).collect();
        if self.cfg.claim_px <= 0.0 {
            return out;
        }
        let dt_unseen = timestamp_ns.saturating_sub(self.unseen.0) as f64 * 1e-9;
        let followed = self
            .objects
            .iter()
            .filter(|o| {
                o.id != 0 && timestamp_ns.saturating_sub(o.last_seen_ns) <= HIDDEN_WITHIN_NS
            })
            .map(|o| o.predict(&self.cfg, timestamp_ns).0);
        let unseen = self
            .unseen
            .1
            .iter()
            .filter(|_| dt_unseen * 1e9 <= HIDDEN_WITHIN_NS as f64)
            .map(|(p, v)| p + v * dt_unseen);
        let by_x: Vec<ByX> = pixels.iter().map(|p| ByX::new(p)).collect();
        for predicted in followed.chain(unseen) {
            for (s, (c, obs)) in set.iter().enumerate() {
                let Some(q) = self.cameras[*c].project(&predicted) else {
                    continue;
                };
                if by_x[s]
                    .near(&pixels[s], q, self.cfg.claim_px)
                    .next()
                    .is_some()
                {
                    continue;
                }
                for (j, &i) in kept[s].iter().enumerate() {
                    let [x0, y0, x1, y1] = obs.blobs[i].bbox_px;
                    if q.x >= x0 as f64 - 1.0
                        && q.x <= x1 as f64 + 1.0
                        && q.y >= y0 as f64 - 1.0
                        && q.y <= y1 as f64 + 1.0
                    {
                        out[s][j] = true;
                    }
                }
            }
        }
        out
    }

    /// `m` without the blobs whose area is out of line with its round blob's
    /// ([`FuserConfig::max_area_ratio`]), re-triangulated; `None` when fewer than two views
    /// remain or they no longer fit.
    fn area_consistent(
        &self,
        set: &[(usize, Observation)],
        kept: &[Vec<usize>],
        cams: &[Camera],
        pixels: &[Vec<Point2<f64>>],
        m: Match,
    ) -> (Option<Match>, u64) {
        let scaled: Vec<(f64, bool)> = m
            .blobs
            .iter()
            .map(|&(c, j)| {
                let b = &set[c].1.blobs[kept[c][j]];
                let d = (cams[c].position_world() - m.point.point_world).norm();
                (b.area_px * d * d, b.roundness >= 0.8)
            })
            .collect();
        let Some(round) = scaled
            .iter()
            .filter(|(_, r)| *r)
            .map(|(a, _)| *a)
            .min_by(f64::total_cmp)
        else {
            return (Some(m), 0);
        };
        let bound = self.cfg.max_area_ratio * round;
        if scaled.iter().all(|(a, _)| *a <= bound) {
            return (Some(m), 0);
        }
        let keep: Vec<(usize, usize)> = m
            .blobs
            .iter()
            .zip(&scaled)
            .filter(|(_, (a, _))| *a <= bound)
            .map(|(b, _)| *b)
            .collect();
        let removed = (m.blobs.len() - keep.len()) as u64;
        if keep.len() < 2 {
            return (None, removed);
        }
        let views: Vec<View> = keep
            .iter()
            .map(|&(c, j)| View {
                camera: c,
                pixel: pixels[c][j],
            })
            .collect();
        let fits = triangulate(cams, &views)
            .ok()
            .filter(|t| t.rms_px <= self.cfg.correspond.max_residual_px);
        (
            fits.map(|t| Match {
                blobs: keep,
                point: t,
            }),
            removed,
        )
    }

    /// The 3D points of one set (`(rig camera index, observation)` pairs) taken at
    /// `timestamp_ns`.
    pub fn points(&mut self, set: &[(usize, Observation)], timestamp_ns: u64) -> Vec<Point> {
        let cams: Vec<Camera> = set.iter().map(|(c, _)| self.cameras[*c]).collect();
        // Only blobs seen this frame; keep their indices. (A blob cut by the frame's edge or
        // its window has its centroid pulled inwards, up to its radius: its point is
        // published, but it does not refine a body's pose: `pixels_of`.)
        self.clipped += set
            .iter()
            .flat_map(|(_, o)| &o.blobs)
            .filter(|b| b.status != TrackState::Lost && b.clipped)
            .count() as u64;
        let kept: Vec<Vec<usize>> = set
            .iter()
            .map(|(_, o)| {
                (0..o.blobs.len())
                    .filter(|&i| usable(&o.blobs[i]))
                    .collect()
            })
            .collect();
        let pixels: Vec<Vec<Point2<f64>>> = set
            .iter()
            .zip(&kept)
            .map(|((_, o), k)| {
                k.iter()
                    .map(|&i| Point2::new(o.blobs[i].x_px, o.blobs[i].y_px))
                    .collect()
            })
            .collect();
        let (kept, pixels) = if self.cameras.len() >= 2 {
            let hiding = self.hiding(set, &kept, &pixels, timestamp_ns);
            let hidden = hiding.iter().flatten().filter(|&&h| h).count();
            self.hiding_blobs += hidden as u64;
            if hidden == 0 {
                (kept, pixels)
            } else {
                let keep = |v: usize, j: usize| !hiding[v][j];
                (
                    kept.iter()
                        .enumerate()
                        .map(|(v, k)| (0..k.len()).filter(|&j| keep(v, j)).map(|j| k[j]).collect())
                        .collect(),
                    pixels
                        .iter()
                        .enumerate()
                        .map(|(v, p)| (0..p.len()).filter(|&j| keep(v, j)).map(|j| p[j]).collect())
                        .collect(),
                )
            }
        } else {
            (kept, pixels)
        };
        let mut points = Vec::new();
        let mut used: Vec<Vec<bool>> = kept.iter().map(|k| vec![false; k.len()]).collect();
        let labels = if self.cameras.len() >= 2 {
            self.claims(set, &pixels, timestamp_ns)
        } else {
            Vec::new()
        };
        if set.len() >= 2 {
            for m in match_labelled(&cams, &pixels, &labels, &self.cfg.correspond) {
                for &(c, j) in &m.blobs {
                    used[c][j] = true;
                }
                let (m, removed) = self.area_consistent(set, &kept, &cams, &pixels, m);
                self.area_mismatch += removed;
                let Some(m) = m else { continue };
                let blobs: Vec<(usize, usize)> = m
                    .blobs
                    .iter()
                    .map(|&(c, j)| {
                        used[c][j] = true;
                        (c, kept[c][j])
                    })
                    .collect();
                points.push(Point {
                    position_m: m.point.point_world,
                    method: PoseMethod::Triangulated,
                    blobs,
                    residual_px: m.point.rms_px,
                    out_of_range: false,
                });
            }
        }
        // One marker triangulated twice: keep the point from more cameras.
        let mut points = merge_duplicates(points, self.cfg.merge_m);
        // Blobs no other camera matched: depth from their area, in a rig of one camera with a
        // model (thesis Eq. 4.15–4.27). In a rig of several, none: a blob only one of several
        // cameras sees is most often a target merged with another in the other views, or a
        // late frame's, and the area of a marker's small image is no measure of its depth
        // (±10 % in the area of a 20-pixel blob is ±5 % in depth: 11 cm at 2.2 m; the rig's
        // model is also one target's, and a marker of another size lands centimetres off).
        let several = self.cameras.len() >= 2;
        for (s, (c, o)) in set.iter().enumerate() {
            if several {
                self.single_view_unmatched +=
                    (0..kept[s].len()).filter(|&j| !used[s][j]).count() as u64;
                continue;
            }
            for (j, &i) in kept[s].iter().enumerate() {
                if used[s][j] {
                    continue;
                }
                let b = &o.blobs[i];
                let pixel = Point2::new(b.x_px, b.y_px);
                let Some(model) = self.depth[*c] else {
                    continue;
                };
                // The models are fitted on the axis: bring an off-axis area back first.
                let Ok(area_px) = on_axis_area(&self.cameras[*c], pixel, b.area_px) else {
                    continue;
                };
                let Ok(d) = model.model.depth_from_area(area_px, model.range_m) else {
                    continue;
                };
                let Ok(p) = point_from_depth(&self.cameras[*c], pixel, d.depth) else {
                    continue;
                };
                // Two cameras' single views of one object that correspondence rejected must not
                // become two objects: keep the first point within the gate.
                if points
                    .iter()
                    .any(|q: &Point| (q.position_m - p).norm() < self.cfg.gate_m)
                {
                    continue;
                }
                points.push(Point {
                    position_m: p,
                    method: PoseMethod::DepthFromArea,
                    blobs: vec![(s, i)],
                    residual_px: 0.0,
                    out_of_range: !d.in_range,
                });
            }
        }
        points
    }

    /// The world axis of a point from its blobs' image axes, when any camera sees one.
    fn heading_of(&self, set: &[(usize, Observation)], p: &Point) -> Option<(f64, bool)> {
        let views: Vec<AxisView> = p
            .blobs
            .iter()
            .filter_map(|&(s, i)| {
                let (c, o) = &set[s];
                let b = o.blobs.get(i)?;
                let round = !(b.roundness <= self.cfg.max_roundness);
                Some(AxisView {
                    camera: *c,
                    centroid_px: Point2::new(b.x_px, b.y_px),
                    angle_deg: if b.directed {
                        b.heading_deg
                    } else {
                        b.orientation_deg
                    },
                    directed: b.directed,
                    weight: if round { 0.0 } else { 1.0 - b.roundness },
                })
            })
            .collect();
        let h = fuse(&self.cameras, &views, &p.position_m)?;
        Some((h.heading_deg, h.directed))
    }

    /// Fuses one set taken at `timestamp_ns` into poses, updating the objects.
    pub fn fuse(&mut self, set: &[(usize, Observation)], timestamp_ns: u64) -> Vec<Pose> {
        // Forget objects unseen for too long, and tentative ones missing from the last set.
        let drop_after = self.cfg.drop_after_ns;
        let last_set = self.last_set_ns;
        self.objects.retain(|o| {
            if o.id == 0 {
                last_set.is_none_or(|t| o.last_seen_ns >= t)
            } else {
                timestamp_ns.saturating_sub(o.last_seen_ns) <= drop_after
            }
        });
        // (Before the set's time is kept: the claims are made by the objects of the last set.)
        let mut points = self.points(set, timestamp_ns);
        self.last_set_ns = Some(timestamp_ns);
        if let Some((lo, hi)) = self.cfg.volume_m {
            let before = points.len();
            points.retain(|p| (0..3).all(|i| p.position_m[i] >= lo[i] && p.position_m[i] <= hi[i]));
            self.outside_volume += (before - points.len()) as u64;
        }
        let headings: Vec<Option<(f64, bool)>> =
            points.iter().map(|p| self.heading_of(set, p)).collect();
        // Assign points to predictions.
        let mut cost = Vec::with_capacity(self.objects.len() * points.len());
        for o in &self.objects {
            let (predicted, gate) = o.predict(&self.cfg, timestamp_ns);
            let gate2 = gate * gate;
            cost.extend(points.iter().map(|p| {
                let d2 = (p.position_m - predicted).norm_squared();
                if d2 <= gate2 { d2 } else { f64::INFINITY }
            }));
        }
        let assignment: Vec<Option<usize>> = self
            .assigner
            .solve(&cost, self.objects.len(), points.len())
            .to_vec();
        let mut owner: Vec<Option<usize>> = vec![None; points.len()];
        for (oi, a) in assignment.iter().enumerate() {
            if let Some(pi) = a {
                owner[*pi] = Some(oi);
            }
        }
        let mut poses = Vec::with_capacity(points.len());
        let mut pixels = Vec::with_capacity(points.len());
        for (pi, p) in points.iter().enumerate() {
            // Whole blobs only: the centroid of one cut by the frame's edge or its window is
            // pulled inwards, and where several are cut their rays may meet off any marker.
            let views = if p.method == PoseMethod::Triangulated {
                let mut cams: Vec<usize> = p
                    .blobs
                    .iter()
                    .filter(|&&(s, i)| !set[s].1.blobs[i].clipped)
                    .map(|&(s, _)| s)
                    .collect();
                cams.dedup();
                cams.len()
            } else {
                usize::MAX
            };
            // Two asks nothing more of a point than that it was triangulated.
            let enough = self.cfg.min_views_to_start <= 2 || views >= self.cfg.min_views_to_start;
            // An object back after sets unseen is taken up again as a new one is started:
            // its prediction has grown uncertain, and its gate wide.
            let resumed = owner[pi]
                .is_some_and(|oi| last_set.is_some_and(|t| self.objects[oi].last_seen_ns < t));
            if (owner[pi].is_none() || resumed) && !enough {
                self.too_few_views += 1;
                continue;
            }
            let oi = match owner[pi] {
                Some(oi) => {
                    let o = &mut self.objects[oi];
                    let dt = timestamp_ns.saturating_sub(o.last_seen_ns) as f64 * 1e-9;
                    if dt > 0.0 {
                        let v = (p.position_m - o.position_m) / dt;
                        // Light smoothing: the prediction only has to land inside the gate.
                        o.velocity_m_per_s = o.velocity_m_per_s * 0.3 + v * 0.7;
                    }
                    o.position_m = p.position_m;
                    o.last_seen_ns = timestamp_ns;
                    if o.id == 0 && enough {
                        o.hits += 1;
                        if o.hits >= self.cfg.confirm_sets {
                            o.id = self.next_id;
                            self.next_id += 1;
                        }
                    }
                    oi
                }
                None => {
                    let confirmed = self.cfg.confirm_sets <= 1;
                    self.objects.push(Object {
                        id: if confirmed { self.next_id } else { 0 },
                        hits: 1,
                        position_m: p.position_m,
                        velocity_m_per_s: Vector3::zeros(),
                        last_seen_ns: timestamp_ns,
                        heading: HeadingTracker::new(HeadingConfig {
                            ambiguous_step_deg: 60.0,
                            max_roundness: 1.0,
                            predict_angular_velocity: true,
                        }),
                        heading_deg: None,
                        heading_directed: false,
                    });
                    if confirmed {
                        self.next_id += 1;
                    }
                    self.objects.len() - 1
                }
            };
            let o = &mut self.objects[oi];
            if let Some((h, directed)) = headings[pi] {
                // The tracker unwraps an axis in (−90, 90] into 0–360° (or takes a direction).
                let u = o
                    .heading
                    .update(wrap_half_turn_deg(h), 0.0, directed.then_some(h));
                o.heading_deg = Some(u.heading_deg);
                o.heading_directed = o.heading_directed || directed;
            }
            if o.id == 0 {
                continue;
            }
            let mut cams: Vec<String> = p
                .blobs
                .iter()
                .map(|&(s, _)| self.ids[set[s].0].clone())
                .collect();
            cams.dedup();
            pixels.push((
                o.id,
                p.blobs
                    .iter()
                    .map(|&(si, bi)| (set[si].0, &set[si].1.blobs[bi]))
                    .filter(|(_, b)| !b.clipped)
                    .map(|(c, b)| (c, Point2::new(b.x_px, b.y_px)))
                    .collect(),
            ));
            poses.push(Pose {
                object_id: o.id,
                position_m: [o.position_m.x, o.position_m.y, o.position_m.z],
                velocity_m_per_s: [
                    o.velocity_m_per_s.x,
                    o.velocity_m_per_s.y,
                    o.velocity_m_per_s.z,
                ],
                heading_deg: o.heading_deg,
                heading_directed: o.heading_directed,
                method: p.method,
                cameras: cams,
                residual_px: p.residual_px,
                out_of_range: p.out_of_range,
                body: None,
                model: None,
            });
        }
        poses.sort_by_key(|p| p.object_id);
        self.pixels = pixels;
        poses
    }

    /// The pixels (rig camera index, distorted pixel as measured) each camera saw of object
    /// `id` in the last set fused, whole blobs only (a clipped blob's centroid is pulled
    /// inwards).
    pub fn pixels_of(&self, id: u32) -> &[(usize, Point2<f64>)] {
        self.sightings().pixels_of(id)
    }

    /// The rig's cameras, by rig camera index.
    pub fn cameras(&self) -> &[Camera] {
        &self.cameras
    }

    /// What the cameras saw of each object of the last set fused, for the bodies' refinement.
    pub fn sightings(&self) -> SetSightings<'_> {
        SetSightings {
            cameras: &self.cameras,
            pixels: &self.pixels,
        }
    }
}

/// What the cameras saw of each object in one set: the rig's cameras (by rig camera index) and
/// each published object's pixels as measured (whole blobs only).
#[derive(Debug, Clone, Copy)]
pub struct SetSightings<'a> {
    pub cameras: &'a [Camera],
    pixels: &'a [(u32, Sightings)],
}

impl<'a> SetSightings<'a> {
    /// The pixels (rig camera index, distorted pixel as measured) each camera saw of object
    /// `id`.
    pub fn pixels_of(&self, id: u32) -> &'a [(usize, Point2<f64>)] {
        self.pixels
            .iter()
            .find(|(i, _)| *i == id)
            .map_or(&[], |(_, v)| v.as_slice())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::SCHEMA_VERSION;
    use stereoscope_rig::Rig;

    const RIG: &str = include_str!("../../../../deploy/rigs/demo.toml");

    /// A fuser whose points become objects in their first set.
    fn confirmed_at_once(rig: &Rig) -> Fuser {
        Fuser::new(
            &rig.cameras,
            FuserConfig {
                confirm_sets: 1,
                ..FuserConfig::default()
            },
        )
    }

    /// The set of both demo cameras seeing one ball at `point`.
    fn set_at(rig: &Rig, point: Point3<f64>, t_ns: u64) -> Vec<(usize, Observation)> {
        (0..2)
            .map(|c| {
                let px = rig.cameras[c].camera.project(&point).unwrap();
                let blob = BlobObservation {
                    track_id: 1,
                    status: TrackState::Tracked,
                    area_px: 60.0,
                    x_px: px.x,
                    y_px: px.y,
                    mu20: 300.0,
                    mu02: 300.0,
                    mu11: 0.0,
                    orientation_deg: 0.0,
                    roundness: 1.0,
                    heading_deg: 0.0,
                    directed: false,
                    heading_ambiguous: true,
                    clipped: false,
                    merged: false,
                    window_px: [0, 0, 319, 239],
                    bbox_px: [0, 0, 1, 1],
                };
                let o = Observation {
                    schema: SCHEMA_VERSION,
                    rig: "demo".into(),
                    camera: rig.cameras[c].id.clone(),
                    sequence: t_ns,
                    timestamp_ns: t_ns,
                    frame_published_ns: t_ns,
                    published_ns: t_ns,
                    width_px: 320,
                    height_px: 240,
                    threshold: 100,
                    dark: false,
                    full_frame: false,
                    dropped_blobs: 0,
                    blobs: vec![blob],
                };
                (c, o)
            })
            .collect()
    }

    /// One ball at `point` as the cameras `views` (`(rig camera, cut by an edge)`) see it.
    fn seen_by(
        rig: &Rig,
        point: Point3<f64>,
        t_ns: u64,
        views: &[(usize, bool)],
    ) -> Vec<(usize, Observation)> {
        let template = set_at(&Rig::from_toml(RIG).unwrap(), point, t_ns)
            .remove(0)
            .1;
        views
            .iter()
            .map(|&(c, clipped)| {
                let cam = &rig.cameras[c];
                let px = cam.camera.project(&point).unwrap();
                let mut o = template.clone();
                o.camera = cam.id.clone();
                o.rig = rig.name.clone();
                o.width_px = 640;
                o.height_px = 480;
                o.blobs[0].x_px = px.x;
                o.blobs[0].y_px = px.y;
                o.blobs[0].clipped = clipped;
                o.blobs[0].window_px = [0, 0, 639, 479];
                (c, o)
            })
            .collect()
    }

    /// In a rig of six cameras a marker starts only when three see it whole; it then goes on
    /// with two, and is taken up again after a set unseen only with three.
    #[test]
    fn a_marker_starts_with_three_whole_views_and_goes_on_with_two() {
        let rig = Rig::from_toml(&stereoscope_rig::scenes::dense_ring(6, 1, 30.0, None)).unwrap();
        let cfg = crate::fusion::FusionSettings::of_rig(&rig.spec).fuser;
        assert_eq!(cfg.min_views_to_start, 3);
        let mut f = Fuser::new(
            &rig.cameras,
            FuserConfig {
                confirm_sets: 1,
                ..cfg
            },
        );
        let p = Point3::new(0.1, -0.05, 0.9);
        let ms = 33_000_000;
        // Two whole views and two cut by an edge: no start.
        let two_whole = [(0, false), (1, false), (2, true), (3, true)];
        assert!(f.fuse(&seen_by(&rig, p, ms, &two_whole), ms).is_empty());
        assert_eq!(f.too_few_views, 1);
        // Three whole: it starts.
        let three_whole = [(0, false), (1, false), (2, false), (3, true)];
        let first = f.fuse(&seen_by(&rig, p, 2 * ms, &three_whole), 2 * ms);
        assert_eq!(first.len(), 1, "{first:?}");
        let id = first[0].object_id;
        // Followed: two cameras alone carry it on.
        let two = [(0, false), (1, false)];
        let next = f.fuse(&seen_by(&rig, p, 3 * ms, &two), 3 * ms);
        assert_eq!(next.iter().map(|p| p.object_id).collect::<Vec<_>>(), [id]);
        // A set without it, then back with two whole views: not taken up; with three, it is.
        assert!(f.fuse(&seen_by(&rig, p, 4 * ms, &[]), 4 * ms).is_empty());
        assert!(
            f.fuse(&seen_by(&rig, p, 5 * ms, &two_whole), 5 * ms)
                .is_empty()
        );
        assert_eq!(f.too_few_views, 2);
        let back = f.fuse(&seen_by(&rig, p, 6 * ms, &three_whole), 6 * ms);
        assert_eq!(back.iter().map(|p| p.object_id).collect::<Vec<_>>(), [id]);
    }

    /// An object gone for 0.6 s (a camera restart, an occlusion) and back 0.15 m from its
    /// prediction keeps its id; one gone longer than `drop_after` gets a new one.
    #[test]
    fn one_marker_triangulated_twice_is_one_point() {
        let pt = |x: f64, cams: usize, residual_px: f64| Point {
            position_m: Point3::new(x, 0.0, 1.0),
            method: PoseMethod::Triangulated,
            blobs: (0..cams).map(|c| (c, 0)).collect(),
            residual_px,
            out_of_range: false,
        };
        // 3.5 mm apart (seen in the 8-camera soak): one marker; 30 mm apart: two.
        let out = merge_duplicates(
            vec![pt(0.0, 2, 0.1), pt(0.0035, 4, 0.3), pt(0.03, 2, 0.2)],
            0.01,
        );
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].blobs.len(), 4, "the point from more cameras is kept");
        assert!((out[1].position_m.x - 0.03).abs() < 1e-12);
        let out = merge_duplicates(vec![pt(0.0, 3, 0.5), pt(0.002, 3, 0.2)], 0.01);
        assert_eq!(out.len(), 1);
        assert!(
            (out[0].residual_px - 0.2).abs() < 1e-12,
            "then the smaller residual"
        );
    }

    #[test]
    fn a_point_becomes_an_object_only_when_it_lasts() {
        let rig = Rig::from_toml(RIG).unwrap();
        let mut f = Fuser::new(&rig.cameras, FuserConfig::default());
        let dt = 33_333_333u64;
        let p = Point3::new(0.05, -0.03, 0.6);
        // A ghost seen in two sets, then gone: never published, never takes an id.
        let ghost = Point3::new(-0.2, 0.1, 0.9);
        assert!(f.fuse(&set_at(&rig, ghost, dt), dt).is_empty());
        assert!(f.fuse(&set_at(&rig, ghost, 2 * dt), 2 * dt).is_empty());
        assert!(f.fuse(&set_at(&rig, p, 3 * dt), 3 * dt).is_empty());
        assert_eq!((f.objects(), f.next_id()), (0, 1));
        // A real one, continued in three sets: published from the third, as object 1.
        assert!(f.fuse(&set_at(&rig, p, 4 * dt), 4 * dt).is_empty());
        let poses = f.fuse(&set_at(&rig, p, 5 * dt), 5 * dt);
        assert_eq!(poses.iter().map(|x| x.object_id).collect::<Vec<_>>(), [1]);
        assert!(f.has_object(1) && !f.has_object(0));
        // Missing from one set, a confirmed object keeps its id.
        let poses = f.fuse(&set_at(&rig, p, 7 * dt), 7 * dt);
        assert_eq!(poses[0].object_id, 1);
    }

    #[test]
    fn an_object_back_from_a_short_loss_keeps_its_id() {
        let rig = Rig::from_toml(RIG).unwrap();
        let mut f = confirmed_at_once(&rig);
        let s = 1_000_000_000u64;
        let p = Point3::new(0.05, -0.03, 0.6);
        let id = |poses: &[Pose]| {
            assert_eq!(poses.len(), 1, "{poses:?}");
            poses[0].object_id
        };
        let first = id(&f.fuse(&set_at(&rig, p, s), s));
        assert_eq!(id(&f.fuse(&set_at(&rig, p, s + s / 30), s + s / 30)), first);
        // 0.6 s unseen, back 0.15 m away: beyond the 0.1 m gate of a tracked object, within
        // the gate widened by 0.5 m/s × 0.6 s.
        let back = p + Vector3::new(0.15, 0.0, 0.0);
        let t = s + s / 30 + 6 * s / 10;
        assert_eq!(id(&f.fuse(&set_at(&rig, back, t), t)), first);
        // Gone for longer than drop_after (2 s): a new object.
        let t = t + 2 * s + s / 10;
        let again = id(&f.fuse(&set_at(&rig, back, t), t));
        assert!(again > first, "{again} {first}");
    }

    /// In a rig of two cameras, a blob only one camera sees gives no point — a late frame's
    /// set, a camera down, or a blob far from everything alike — and the object keeps its id
    /// when both see it again.
    #[test]
    fn a_rig_of_several_cameras_publishes_no_one_view_points() {
        let rig = Rig::from_toml(RIG).unwrap();
        let mut f = Fuser::new(&rig.cameras, FuserConfig::default());
        let dt = 33_333_333u64;
        let at = Point3::new(-0.1, 0.05, 0.6);
        for k in 1..=5 {
            f.fuse(&set_at(&rig, at, k * dt), k * dt);
        }
        let id = f.next_id() - 1;
        let far = Point3::new(0.3, -0.3, 0.2);
        for (k, p) in [(6, at), (7, at), (8, far), (9, far), (10, far), (11, far)] {
            let mut set = set_at(&rig, p, k * dt);
            set.truncate(1);
            assert!(f.fuse(&set, k * dt).is_empty(), "set {k}");
        }
        assert_eq!(f.single_view_unmatched, 6);
        let poses = f.fuse(&set_at(&rig, at, 12 * dt), 12 * dt);
        assert_eq!(poses.len(), 1);
        assert_eq!(poses[0].object_id, id);
        assert_eq!(f.next_id(), id + 1);
    }
    /// The set of both demo cameras seeing balls at `points`, each blob's box 3 px round its
    /// centroid.
    fn set_of(rig: &Rig, points: &[Point3<f64>], t_ns: u64) -> Vec<(usize, Observation)> {
        let mut set = set_at(rig, points[0], t_ns);
        for (c, o) in &mut set {
            let proto = o.blobs[0].clone();
            o.blobs = points
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let px = rig.cameras[*c].camera.project(p).unwrap();
                    let (x, y) = (px.x.round() as u32, px.y.round() as u32);
                    BlobObservation {
                        track_id: k as u32 + 1,
                        x_px: px.x,
                        y_px: px.y,
                        bbox_px: [x - 3, y - 3, x + 3, y + 3],
                        ..proto.clone()
                    }
                })
                .collect();
        }
        set
    }

    /// A marker whose image one camera loses inside another's blob (merged with it, or passing
    /// in front of it) before the blob's area shows it: that blob's centroid is shifted, and
    /// it gives no point. The same for a found body's unseen marker, known from the body's
    /// pose.
    #[test]
    fn a_blob_that_hides_a_followed_marker_gives_no_point() {
        let rig = Rig::from_toml(RIG).unwrap();
        let mut f = confirmed_at_once(&rig);
        let dt = 33_333_333u64;
        let (a, b) = (Point3::new(-0.1, 0.15, 0.4), Point3::new(-0.1, 0.18, 0.6));
        for k in 1..=3 {
            assert_eq!(f.fuse(&set_of(&rig, &[a, b], k * dt), k * dt).len(), 2);
        }
        // Camera 0 sees one blob where both images meet: B's image gone, A's centroid 1.5 px
        // towards it, the box grown over B's projection.
        let mut set = set_of(&rig, &[a, b], 4 * dt);
        let pb = rig.cameras[0].camera.project(&b).unwrap();
        let blob = &mut set[0].1.blobs[0];
        blob.x_px += 1.5 * (pb.x - blob.x_px).signum();
        for (k, v) in [pb.x, pb.y, pb.x, pb.y].into_iter().enumerate() {
            let v = v.round() as u32;
            blob.bbox_px[k] = if k < 2 {
                blob.bbox_px[k].min(v)
            } else {
                blob.bbox_px[k].max(v)
            };
        }
        set[0].1.blobs.truncate(1);
        let poses = f.fuse(&set, 4 * dt);
        assert!(poses.is_empty(), "{poses:?}");
        assert_eq!(f.hiding_blobs, 1);
        // Both seen apart again: both published.
        assert_eq!(f.fuse(&set_of(&rig, &[a, b], 5 * dt), 5 * dt).len(), 2);

        // A body's marker never followed as an object, known only from the body's pose.
        let mut g = confirmed_at_once(&rig);
        for k in 1..=3 {
            assert_eq!(g.fuse(&set_of(&rig, &[a], k * dt), k * dt).len(), 1);
        }
        let mut set = set_of(&rig, &[a], 4 * dt);
        set[0].1.blobs[0].bbox_px = [0, 0, 319, 239];
        assert_eq!(g.fuse(&set, 4 * dt).len(), 1, "nothing expected there yet");
        g.expect_unseen(4 * dt, vec![(b, Vector3::zeros())]);
        assert!(g.fuse(&set, 5 * dt).is_empty());
        assert_eq!(g.hiding_blobs, 1);
    }
}
