//! The synthetic camera: the rig's `[synthetic]` scene rendered through this camera's
//! calibrated model by `stereoscope_render`, with ground truth per frame. Frame `k` shows the
//! scene at `k / fps` seconds; with `loop_frames` the first N frames are rendered once and
//! repeated (so a benchmark can run at rates the renderer cannot reach live).

use crate::source::{FrameSource, Read, SourceError};
use nalgebra::{Point3, Vector3};
use stereoscope_geometry::Camera;
use stereoscope_proto::frame::PixelFormat;
use stereoscope_proto::messages::TargetTruth;
use stereoscope_render::{
    Actor, Background, Blink, Light, Motion, RenderOptions, Scene, Shape, render_u8, render_u16,
    scene_at,
};
use stereoscope_rig::models::{ModelMotion, RigModel};
use stereoscope_rig::schema::{
    BodySpec, MotionSpec, RigFile, SyntheticLight, SyntheticSpec, SyntheticTarget, TargetShape,
};

pub struct SyntheticSource {
    camera: Camera,
    actors: Vec<Actor>,
    base: Scene,
    opts: RenderOptions,
    fps: f64,
    format: PixelFormat,
    looped: Option<Vec<(Vec<u8>, Vec<TargetTruth>)>>,
    last_truth: Vec<TargetTruth>,
    has_axis: Vec<bool>,
    /// Each target's body name, for a rigid-body target.
    body: Vec<Option<String>>,
}

impl std::fmt::Debug for SyntheticSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SyntheticSource({} targets)", self.actors.len())
    }
}

fn p3(v: [f64; 3], s: f64) -> Point3<f64> {
    Point3::new(v[0] * s, v[1] * s, v[2] * s)
}

/// One actor of the scene, whether it has an axis, and the rigid body it carries.
pub type SceneActor = (Actor, bool, Option<String>);

/// A model target's actors: one per link that carries markers, its markers as spheres of
/// `radius_m` in the link's frame, moved by the target's `joints` motion. Each carries the
/// name `<model>/<link>` as its truth's body, so the truth gives the link's pose.
fn model_actors(t: &SyntheticTarget, motion: &ModelMotion, scale: f64) -> Vec<SceneActor> {
    let model = std::sync::Arc::new(motion.model.clone());
    (0..model.links.len())
        .filter_map(|l| {
            let spheres: Vec<(Vector3<f64>, f64)> = model
                .markers
                .iter()
                .filter(|m| m.link == l)
                .map(|m| (m.in_link_m.coords, t.radius * scale))
                .collect();
            (!spheres.is_empty()).then(|| {
                (
                    Actor {
                        shape: Shape::Markers { spheres },
                        contrast: t.contrast.unwrap_or(180.0),
                        motion: Motion::Link {
                            model: model.clone(),
                            link: l,
                            world_from_root: motion.world_from_root,
                            swings: motion.swings.clone(),
                        },
                        hidden: motion
                            .hide
                            .filter(|h| h.0 == l)
                            .map(|(_, every_s, for_s)| Blink { every_s, for_s }),
                    },
                    true,
                    Some(format!("{}/{}", model.name, model.links[l].name)),
                )
            })
        })
        .collect()
}

/// The scene's actors (metres) from the rig file's `[synthetic]` section (file units): one per
/// target, and one per marked link of a model target.
pub fn actors(
    spec: &SyntheticSpec,
    bodies: &[BodySpec],
    motions: &[ModelMotion],
    scale: f64,
) -> Vec<SceneActor> {
    spec.targets
        .iter()
        .enumerate()
        .flat_map(|(i, t)| {
            if t.shape == TargetShape::Model {
                return motions
                    .iter()
                    .find(|m| m.target == i)
                    .map(|m| model_actors(t, m, scale))
                    .unwrap_or_default();
            }
            let r = t.radius * scale;
            // (shape, has an axis); the first three are symmetric end to end.
            let (shape, has_axis) = match t.shape {
                TargetShape::DoubleSphere => (Shape::DoubleSphere { radius_m: r }, true),
                TargetShape::Disc => (Shape::Disc { radius_m: r }, false),
                TargetShape::Sphere => (Shape::Sphere { radius_m: r }, false),
                TargetShape::Model => (
                    Shape::Markers {
                        spheres: Vec::new(),
                    },
                    false,
                ),
                TargetShape::Rectangle => (
                    Shape::Rectangle {
                        half_x_m: r,
                        half_y_m: r / 2.0,
                    },
                    true,
                ),
                // The rig's check makes sure the grid is given; the origin dot (column 0, row
                // 0) 1.5× the others, as `target dot-grid` prints it.
                TargetShape::DotGrid => {
                    let g = t.grid.unwrap_or(stereoscope_rig::schema::GridSpec {
                        cols: 2,
                        rows: 2,
                        spacing: 1.0,
                    });
                    let s = g.spacing * scale;
                    let (cx, cy) = ((g.cols - 1) as f64 * s / 2.0, (g.rows - 1) as f64 * s / 2.0);
                    let dots = (0..g.rows)
                        .flat_map(|j| (0..g.cols).map(move |i| (i, j)))
                        .map(|(i, j)| {
                            let radius = if (i, j) == (0, 0) { 1.5 * r } else { r };
                            (
                                Vector3::new(i as f64 * s - cx, j as f64 * s - cy, 0.0),
                                radius,
                            )
                        })
                        .collect();
                    (Shape::Dots { dots }, true)
                }
                // The rig's check makes sure the body exists.
                TargetShape::Body => {
                    let markers = t
                        .body
                        .as_ref()
                        .and_then(|n| bodies.iter().find(|b| &b.name == n))
                        .map(|b| b.markers.clone())
                        .unwrap_or_default();
                    let spheres = markers
                        .iter()
                        .map(|m| (Vector3::new(m[0], m[1], m[2]) * scale, r))
                        .collect();
                    (Shape::Markers { spheres }, true)
                }
            };
            let motion = match &t.motion {
                MotionSpec::Static {
                    position,
                    heading_deg,
                } => Motion::Static {
                    position: p3(*position, scale),
                    heading_deg: *heading_deg,
                },
                MotionSpec::Line { from, to, period_s } => Motion::Line {
                    from: p3(*from, scale),
                    to: p3(*to, scale),
                    period_s: *period_s,
                },
                MotionSpec::Circle {
                    centre,
                    radius,
                    period_s,
                } => Motion::Circle {
                    centre: p3(*centre, scale),
                    radius_m: radius * scale,
                    period_s: *period_s,
                },
                MotionSpec::Spin {
                    position,
                    deg_per_s,
                } => Motion::Spin {
                    position: p3(*position, scale),
                    deg_per_s: *deg_per_s,
                },
                MotionSpec::Head {
                    centre,
                    radius,
                    period_s,
                    turn_period_s,
                    nod_deg,
                } => Motion::Head {
                    centre: p3(*centre, scale),
                    radius_m: radius * scale,
                    period_s: *period_s,
                    turn_period_s: *turn_period_s,
                    nod_deg: *nod_deg,
                },
                MotionSpec::Wander {
                    centre,
                    extent,
                    seed,
                } => Motion::Wander {
                    centre: p3(*centre, scale),
                    extent_m: Vector3::new(extent[0], extent[1], extent[2]) * scale,
                    seed: *seed ^ spec.seed,
                },
                // Only a model target moves by joints (the rig's check).
                MotionSpec::Joints { base, .. } => Motion::Static {
                    position: p3(*base, scale),
                    heading_deg: 0.0,
                },
            };
            let body = (t.shape == TargetShape::Body)
                .then(|| t.body.clone())
                .flatten();
            vec![(
                Actor {
                    shape,
                    contrast: t.contrast.unwrap_or(180.0),
                    motion,
                    hidden: None,
                },
                has_axis,
                body,
            )]
        })
        .collect()
}

impl SyntheticSource {
    /// The synthetic camera `camera_index` of a rig whose `[synthetic]` scene is `file`'s and
    /// whose kinematic models are `models` (the rig's, for targets of shape "model").
    pub fn new(
        file: &RigFile,
        models: &[RigModel],
        camera: Camera,
        camera_index: usize,
        fps: f64,
        loop_frames: Option<u32>,
        bit_depth: Option<u32>,
    ) -> Result<Self, SourceError> {
        let spec = file.synthetic.as_ref().ok_or(SourceError::NoScene)?;
        let render = stereoscope_rig::settings::SyntheticRender::of(spec);
        let scale = file.units.metres();
        let motions = stereoscope_rig::models::model_motions(file, models);
        let mut all = actors(spec, &file.bodies, &motions, scale);
        let body: Vec<Option<String>> = all.iter_mut().map(|a| a.2.take()).collect();
        let (actors, has_axis): (Vec<Actor>, Vec<bool>) =
            all.into_iter().map(|(a, h, _)| (a, h)).unzip();
        let base = Scene {
            background: Background {
                level: render.background,
                gradient_per_px: (0.0, 0.0),
            },
            light: match render.light {
                SyntheticLight::Overhead => Scene::default().light,
                SyntheticLight::Ring => Light::Ring,
            },
            ..Scene::default()
        };
        let opts = RenderOptions {
            samples: render.samples,
            blur_sigma_px: render.blur_sigma_px,
            noise_sigma: render.noise_sigma,
            shot_noise_gain: None,
            seed: render.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ camera_index as u64,
        };
        let format = if bit_depth == Some(16) {
            PixelFormat::Gray16
        } else {
            PixelFormat::Gray8
        };
        let mut s = SyntheticSource {
            camera,
            actors,
            base,
            opts,
            fps,
            format,
            looped: None,
            last_truth: Vec::new(),
            has_axis,
            body,
        };
        if let Some(n) = loop_frames {
            let (w, h) = s.size();
            let len = w as usize * h as usize * s.format.bytes_per_pixel();
            let mut frames = Vec::with_capacity(n as usize);
            for k in 0..n as u64 {
                let mut buf = vec![0u8; len];
                s.render(k, k as f64 / fps, &mut buf)?;
                frames.push((buf, s.last_truth.clone()));
            }
            s.looped = Some(frames);
        }
        Ok(s)
    }

    fn render(&mut self, index: u64, t_s: f64, out: &mut [u8]) -> Result<(), SourceError> {
        let (scene, states) = scene_at(&self.base, &self.actors, t_s);
        let opts = RenderOptions {
            seed: self.opts.seed ^ index.wrapping_mul(0xD1B5_4A32_D192_ED03),
            ..self.opts
        };
        let bad = SourceError::Render;
        let truth = match self.format {
            PixelFormat::Gray8 => {
                let f = render_u8(&self.camera, &scene, &opts).map_err(bad)?;
                out.copy_from_slice(f.image.as_slice());
                f.truth
            }
            PixelFormat::Gray16 => {
                let f = render_u16(&self.camera, &scene, &opts, 256.0).map_err(bad)?;
                for (d, s) in out.chunks_exact_mut(2).zip(f.image.as_slice()) {
                    d.copy_from_slice(&s.to_le_bytes());
                }
                f.truth
            }
        };
        self.last_truth = states
            .iter()
            .zip(&truth)
            .enumerate()
            .map(|(i, (s, t))| TargetTruth {
                target: i as u32,
                position_m: [s.position.x, s.position.y, s.position.z],
                heading_deg: s.heading_deg.rem_euclid(360.0),
                has_axis: self.has_axis.get(i).copied().unwrap_or(false),
                symmetric: true,
                visible: t.visible,
                area_px: t.area_px,
                // Out of view the renderer's centroid is NaN; the protocol's numbers are
                // finite (a truth with a NaN was refused whole, and the demo scored nothing).
                centroid_px: if t.visible {
                    [t.centroid_px.x, t.centroid_px.y]
                } else {
                    [0.0, 0.0]
                },
                body: self.body.get(i).cloned().flatten(),
                orientation_xyzw: self.body.get(i).and_then(|b| b.as_ref()).map(|_| {
                    let q = s.world_from_body().rotation;
                    [q.i, q.j, q.k, q.w]
                }),
            })
            .collect();
        Ok(())
    }
}

impl FrameSource for SyntheticSource {
    fn describe(&self) -> String {
        let (w, h) = self.size();
        format!(
            "synthetic {}×{} at {} fps, {} targets{}",
            w,
            h,
            self.fps,
            self.actors.len(),
            self.looped
                .as_ref()
                .map(|l| format!(", {} frames looped", l.len()))
                .unwrap_or_default()
        )
    }

    fn format(&self) -> PixelFormat {
        self.format
    }

    fn size(&self) -> (u32, u32) {
        (self.camera.intrinsics.width, self.camera.intrinsics.height)
    }

    fn fps(&self) -> Option<f64> {
        Some(self.fps)
    }

    fn realtime(&self) -> bool {
        true
    }

    fn read(&mut self, index: u64, t_s: f64, out: &mut [u8]) -> Result<Read, SourceError> {
        if let Some(frames) = &self.looped {
            let (buf, truth) = &frames[ping_pong(index, frames.len())];
            out.copy_from_slice(buf);
            self.last_truth = truth.clone();
        } else {
            self.render(index, t_s, out)?;
        }
        Ok(Read::Frame {
            timestamp_ns: None,
            sequence: None,
        })
    }

    fn truth(&self) -> Option<Vec<TargetTruth>> {
        Some(self.last_truth.clone())
    }
}

/// The `index`-th frame of `n` pre-rendered ones played forward, then backward, then forward
/// again (0, 1, …, n−1, n−2, …, 1, 0, 1, …): the targets turn back instead of jumping from
/// their last position to their first, which a tracker would see as every object lost and
/// new ones found at each loop.
pub fn ping_pong(index: u64, n: usize) -> usize {
    if n < 2 {
        return 0;
    }
    let period = 2 * (n as u64 - 1);
    let p = index % period;
    (if p < n as u64 { p } else { period - p }) as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereoscope_proto::messages::{Message, Truth};

    #[test]
    fn looped_frames_turn_back_instead_of_jumping() {
        let seq: Vec<usize> = (0..10).map(|i| ping_pong(i, 4)).collect();
        assert_eq!(seq, [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]);
        assert_eq!(ping_pong(7, 1), 0);
        assert_eq!(ping_pong(u64::MAX, 240), ping_pong(u64::MAX % 478, 240));
    }

    /// A target out of the camera's view is in the truth as not visible, with finite numbers:
    /// the truth message passes the receivers' checks (a NaN centroid made it refused whole).
    #[test]
    fn a_target_out_of_view_gives_a_valid_truth() {
        let text = include_str!("../../../../deploy/rigs/demo.toml").to_string()
            + "\n[[synthetic.target]]\nshape = \"sphere\"\nradius = 2.0\n\
               motion = { kind = \"circle\", centre = [900.0, 0.0, 40.0], radius = 1.0, period_s = 8.0 }\n";
        let rig = stereoscope_rig::Rig::from_toml(&text).unwrap();
        let mut src = SyntheticSource::new(
            &rig.spec,
            &rig.models,
            rig.cameras[0].camera,
            0,
            30.0,
            None,
            None,
        )
        .unwrap();
        let (w, h) = src.size();
        let mut buf = vec![0u8; (w * h) as usize];
        src.read(0, 1.0, &mut buf).unwrap();
        let targets = src.truth().unwrap();
        let out = targets.last().unwrap();
        assert!(!out.visible && out.centroid_px == [0.0, 0.0], "{out:?}");
        let truth = Truth {
            schema: 1,
            camera: "cam0".into(),
            sequence: 0,
            timestamp_ns: 1,
            targets,
        };
        Truth::from_json(&truth.to_json()).unwrap();
    }
}
