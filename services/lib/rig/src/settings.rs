//! Rig sections as fully defaulted settings: each default written once, here, and read by the
//! service that uses it (fusion's are `stereoscope_pipeline::fusion::FusionSettings`, the
//! workers' `moments::WorkerSettings`, the VR feed's `vr::VrSettings`). The values were checked
//! when the rig was loaded.

use crate::schema::{RigFile, SyntheticLight, SyntheticSpec, ViewerSpec};

/// Where the viewer listens when the rig does not say.
pub const DEFAULT_VIEWER_LISTEN: &str = "127.0.0.1:8750";
/// Most browsers the viewer serves at once when the rig does not say.
pub const DEFAULT_VIEWER_MAX_CLIENTS: usize = 16;

/// `[viewer]`, defaulted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewerSettings {
    /// Address and port, as written (parsed by the viewer, which names it when it does not).
    pub listen: String,
    pub max_clients: usize,
}

impl ViewerSettings {
    pub fn of(spec: Option<&ViewerSpec>) -> ViewerSettings {
        let d = ViewerSpec::default();
        let s = spec.unwrap_or(&d);
        ViewerSettings {
            listen: s
                .listen
                .clone()
                .unwrap_or_else(|| DEFAULT_VIEWER_LISTEN.to_string()),
            max_clients: s
                .max_clients
                .map_or(DEFAULT_VIEWER_MAX_CLIENTS, |m| m as usize),
        }
    }

    pub fn of_rig(file: &RigFile) -> ViewerSettings {
        ViewerSettings::of(file.viewer.as_ref())
    }
}

/// `[synthetic]`'s rendering, defaulted: the realistic setting of docs/reproduce.md.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticRender {
    pub seed: u64,
    /// Read noise, grey levels.
    pub noise_sigma: f64,
    /// Defocus blur, pixels.
    pub blur_sigma_px: f64,
    /// Background grey level.
    pub background: f64,
    /// Supersampling per axis near targets.
    pub samples: u32,
    pub light: SyntheticLight,
}

impl SyntheticRender {
    pub fn of(spec: &SyntheticSpec) -> SyntheticRender {
        SyntheticRender {
            seed: spec.seed,
            noise_sigma: spec.noise_sigma.unwrap_or(2.0),
            blur_sigma_px: spec.blur_sigma_px.unwrap_or(0.6),
            background: spec.background.unwrap_or(20.0),
            samples: spec.samples.unwrap_or(3),
            light: spec.light,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absent_sections_take_the_documented_defaults() {
        let v = ViewerSettings::of(None);
        assert_eq!(v.listen, "127.0.0.1:8750");
        assert_eq!(v.max_clients, 16);
        let s = SyntheticRender::of(&SyntheticSpec::default());
        assert_eq!(
            (s.noise_sigma, s.blur_sigma_px, s.background, s.samples),
            (2.0, 0.6, 20.0, 3)
        );
        let given = SyntheticRender::of(&SyntheticSpec {
            noise_sigma: Some(0.5),
            samples: Some(5),
            ..SyntheticSpec::default()
        });
        assert_eq!(
            (given.noise_sigma, given.samples, given.background),
            (0.5, 5, 20.0)
        );
    }
}
