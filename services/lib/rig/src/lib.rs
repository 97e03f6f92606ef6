//! The rig: one TOML file describing a rig's cameras, PCs and services, read once into a typed,
//! checked [`Rig`] that every service and command shares (`docs/rig.md`). Nothing else parses
//! the file: the schema ([`schema`]), its checks (`check.rs`), the cameras built from it
//! ([`cameras`]) and the moment workers' settings ([`moments`]) all live here, and every problem
//! is one [`RigError`] naming the file, the key and the value. What a service is started with
//! (the rig plus its place and Zenoh endpoints) is `stereoscope-service`'s: this crate knows no
//! transport and no command line.

pub mod cameras;
mod check;
pub mod error;
pub mod models;
pub mod moments;
pub mod scenes;
pub mod schema;
pub mod security;
pub mod settings;
pub mod truth;
pub mod vr;
pub mod watch;

use std::path::{Path, PathBuf};

pub use cameras::{DepthFromArea, RigCamera, camera_spec};
pub use check::{
    FPS_RANGE, MAX_BAUD, MAX_CONFIRM_SETS, MAX_DROP_AFTER_S, MAX_LOOP_BYTES, MAX_PIXELS,
    MAX_REPLAY_SPEED, MAX_SIDE_PX, MAX_TOLERANCE_PX, MAX_WAIT_MS, body_defs, resolve,
};
pub use error::{RigError, RigErrorKind};
pub use schema::{RigFile, Units};

use stereoscope_geometry::Camera;

/// A rig file, read and checked: its typed sections, and its cameras in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    /// The file it was read from.
    pub path: Option<PathBuf>,
    /// Where relative source paths start (the file's folder).
    pub base_dir: Option<PathBuf>,
    /// The file's sections, every value checked.
    pub spec: RigFile,
    pub name: String,
    /// The cameras, in the file's order, in metres.
    pub cameras: Vec<RigCamera>,
    /// The kinematic models (`[[model]]`), built and checked.
    pub models: Vec<models::RigModel>,
}

impl Rig {
    /// Reads and checks a rig file; every error names `path`.
    pub fn load(path: &Path) -> Result<Rig, RigError> {
        let text = std::fs::read_to_string(path).map_err(|e| RigError {
            kind: RigErrorKind::Read,
            file: Some(path.to_path_buf()),
            key: String::new(),
            message: e.to_string(),
        })?;
        let spec = parse(&text).map_err(|e| e.in_file(path))?;
        let mut rig = Rig::from_spec(spec, path.parent()).map_err(|e| e.in_file(path))?;
        rig.path = Some(path.to_path_buf());
        Ok(rig)
    }

    /// Parses and checks a rig file's text (relative source paths start at the current
    /// folder).
    pub fn from_toml(text: &str) -> Result<Rig, RigError> {
        Rig::from_spec(parse(text)?, None)
    }

    /// Parses and checks the rig text a recording keeps, all but its sources' files: a
    /// recording is replayed where those files need not be.
    pub fn from_recording(text: &str) -> Result<Rig, RigError> {
        Rig::checked(parse(text)?, None, false)
    }

    /// Checks parsed sections; `base` is where relative source paths start.
    pub fn from_spec(spec: RigFile, base: Option<&Path>) -> Result<Rig, RigError> {
        Rig::checked(spec, base, true)
    }

    fn checked(spec: RigFile, base: Option<&Path>, sources: bool) -> Result<Rig, RigError> {
        check::check(&spec, base, sources)?;
        let cameras = cameras::build_cameras(&spec)?;
        let models = models::build_models(&spec, base)?;
        models::check_hidden_links(&spec, &models)?;
        let rig = Rig {
            path: None,
            base_dir: base.map(Path::to_path_buf),
            name: spec.name.clone(),
            spec,
            cameras,
            models,
        };
        for i in 0..rig.cameras.len() {
            rig.worker_settings(i)?;
        }
        Ok(rig)
    }

    pub fn camera_index(&self, id: &str) -> Option<usize> {
        self.cameras.iter().position(|c| c.id == id)
    }

    pub fn cameras(&self) -> Vec<Camera> {
        self.cameras.iter().map(|c| c.camera).collect()
    }

    /// Metres per unit of the file's numbers.
    pub fn metres_per_unit(&self) -> f64 {
        self.spec.units.metres()
    }

    /// A source path of the file, relative to the file's folder unless absolute.
    pub fn source_path(&self, p: &str) -> PathBuf {
        check::resolve(self.base_dir.as_deref(), p)
    }

    /// The moment worker's settings for camera `index` (checked at load).
    pub fn worker_settings(&self, index: usize) -> Result<moments::WorkerSettings, RigError> {
        let (Some(spec), Some(cam)) = (self.spec.cameras.get(index), self.cameras.get(index))
        else {
            return Err(error::err(
                format!("camera[{index}]"),
                format!("the rig has {} cameras", self.cameras.len()),
            ));
        };
        moments::worker_settings(
            spec.moments.as_ref(),
            cam.camera.intrinsics.par(),
            spec.image_size,
            check::max_level(spec.source.as_ref()),
            &format!("camera[{index}].moments"),
        )
    }
}

/// Parses a rig file's text; a syntax error or an unknown key or word is named with its line.
fn parse(text: &str) -> Result<RigFile, RigError> {
    RigFile::from_toml(text).map_err(|e| RigError {
        kind: RigErrorKind::Syntax,
        file: None,
        key: String::new(),
        message: e.to_string().trim().to_string(),
    })
}
