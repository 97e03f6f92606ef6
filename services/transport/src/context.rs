//! What every service is started with: the rig file, which PC it is on, its iceoryx2 prefix
//! and how it joins Zenoh — the same flags for every service binary, checked the same way.
//! Also the checks of a rig file's deployment sections (`[[host]]`, `source`, `[fusion]`,
//! `[synthetic]`), each problem named by its key.

use crate::TransportError;
use crate::net::{ZenohMode, ZenohSpec};
use std::path::{Path, PathBuf};
use stereoscope_geometry::rig::Rig;
use stereoscope_proto::names::valid_segment;
use stereoscope_proto::rig::{HostSpec, MotionSpec, RigFile, SourceSpec};

/// Default iceoryx2 file prefix.
pub const DEFAULT_IOX_PREFIX: &str = "stsc_";

/// The flags every service binary takes.
#[derive(Debug, Clone, clap::Args)]
pub struct CommonArgs {
    /// The rig file.
    #[arg(long)]
    pub rig: PathBuf,
    /// This PC's name in the rig file's `[[host]]` list (the only one if omitted).
    #[arg(long)]
    pub host: Option<String>,
    /// Prefix of iceoryx2's files (default: the host's `iceoryx2_prefix`, else "stsc_").
    #[arg(long)]
    pub iox_prefix: Option<String>,
    /// client, peer or router (default: client of this host's router, or a peer with no
    /// endpoints when the rig lists no hosts).
    #[arg(long)]
    pub zenoh_mode: Option<String>,
    #[arg(long)]
    pub zenoh_connect: Vec<String>,
    #[arg(long)]
    pub zenoh_listen: Vec<String>,
}

/// A service's resolved start-up context.
#[derive(Debug, Clone)]
pub struct Context {
    pub rig_path: PathBuf,
    pub rig_file: RigFile,
    pub rig: Rig,
    pub host: String,
    pub iox_prefix: String,
    pub zenoh: ZenohSpec,
}

/// Reads and checks a rig file (cameras and deployment); errors name the file and the key.
pub fn load_rig(path: &Path) -> Result<(RigFile, Rig), TransportError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| TransportError::Config(format!("{}: {e}", path.display())))?;
    parse_rig(&text).map_err(|e| TransportError::Config(format!("{}: {e}", path.display())))
}

/// Parses and checks a rig file's text.
pub fn parse_rig(text: &str) -> Result<(RigFile, Rig), String> {
    let file = RigFile::from_toml(text).map_err(|e| e.to_string())?;
    let rig = Rig::from_file(&file).map_err(|e| e.to_string())?;
    check_deployment(&file)?;
    Ok((file, rig))
}

fn finite_positive(key: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{key}: {v} must be a finite number above zero"))
    }
}

/// Checks the sections a running rig needs; every message starts with the key.
pub fn check_deployment(file: &RigFile) -> Result<(), String> {
    if !valid_segment(&file.name) {
        return Err(format!(
            "name: {:?} must be 1–32 characters of letters, digits, '_' or '-' (it is part of network keys)",
            file.name
        ));
    }
    let mut seen = std::collections::HashSet::new();
    for (i, h) in file.hosts.iter().enumerate() {
        if !valid_segment(&h.name) {
            return Err(format!(
                "host[{i}].name: {:?} must be 1–32 characters of letters, digits, '_' or '-'",
                h.name
            ));
        }
        if !seen.insert(h.name.clone()) {
            return Err(format!("host[{i}].name: {:?} appears twice", h.name));
        }
        for (j, e) in h.zenoh_listen.iter().chain(&h.zenoh_connect).enumerate() {
            if !e.contains('/') {
                return Err(format!(
                    "host[{i}] zenoh endpoint {j}: {e:?} is not of the form tcp/ADDRESS:PORT"
                ));
            }
        }
    }
    let known_host = |key: String, h: &Option<String>| -> Result<(), String> {
        match h {
            Some(h) if !file.hosts.iter().any(|x| &x.name == h) => Err(format!(
                "{key}: {h:?} is not a [[host]] of this rig (hosts: {:?})",
                file.hosts.iter().map(|h| &h.name).collect::<Vec<_>>()
            )),
            None if file.hosts.len() > 1 => Err(format!(
                "{key}: missing; with several [[host]] sections every camera, [fusion] and [[serial]] must name its host"
            )),
            _ => Ok(()),
        }
    };
    let mut ids = std::collections::HashSet::new();
    for (i, c) in file.cameras.iter().enumerate() {
        if !valid_segment(&c.id) {
            return Err(format!(
                "camera[{i}].id: {:?} must be 1–32 characters of letters, digits, '_' or '-'",
                c.id
            ));
        }
        if !ids.insert(c.id.clone()) {
            return Err(format!("camera[{i}].id: {:?} appears twice", c.id));
        }
        known_host(format!("camera[{i}].host"), &c.host)?;
        match &c.source {
            Some(SourceSpec::Synthetic {
                fps,
                loop_frames,
                bit_depth,
            }) => {
                finite_positive(&format!("camera[{i}].source.fps"), *fps)?;
                if file.synthetic.is_none() {
                    return Err(format!(
                        "camera[{i}].source: a synthetic camera needs a [synthetic] scene"
                    ));
                }
                if loop_frames == &Some(0) {
                    return Err(format!(
                        "camera[{i}].source.loop_frames: must be at least 1"
                    ));
                }
                if let Some(b) = bit_depth
                    && *b != 8
                    && *b != 16
                {
                    return Err(format!("camera[{i}].source.bit_depth: {b} is not 8 or 16"));
                }
            }
            Some(SourceSpec::Images { fps, .. }) => {
                finite_positive(&format!("camera[{i}].source.fps"), *fps)?
            }
            Some(SourceSpec::V4l { fps: Some(f), .. }) => {
                finite_positive(&format!("camera[{i}].source.fps"), *f)?
            }
            _ => {}
        }
    }
    if let Some(f) = &file.fusion {
        known_host("fusion.host".into(), &f.host)?;
        for (k, v) in [
            ("max_skew_ms", f.max_skew_ms),
            ("max_wait_ms", f.max_wait_ms),
            ("camera_timeout_ms", f.camera_timeout_ms),
            ("max_epipolar_px", f.max_epipolar_px),
            ("max_residual_px", f.max_residual_px),
            ("association_gate", f.association_gate),
            ("drop_after_s", f.drop_after_s),
        ] {
            if let Some(v) = v {
                finite_positive(&format!("fusion.{k}"), v)?;
            }
        }
        if let Some(o) = &f.observations
            && o != "auto"
            && o != "zenoh"
        {
            return Err(format!(
                "fusion.observations: {o:?} is not \"auto\" or \"zenoh\""
            ));
        }
    }
    for (i, s) in file.serial.iter().enumerate() {
        known_host(format!("serial[{i}].host"), &s.host)?;
        if s.baud == Some(0) {
            return Err(format!("serial[{i}].baud: must be above zero"));
        }
        if let Some(m) = &s.mode
            && m != "legacy"
            && m != "framed"
        {
            return Err(format!(
                "serial[{i}].mode: {m:?} is not \"legacy\" or \"framed\""
            ));
        }
    }
    if let Some(s) = &file.synthetic {
        for (i, t) in s.targets.iter().enumerate() {
            if !matches!(t.shape.as_str(), "sphere" | "double_sphere" | "disc") {
                return Err(format!(
                    "synthetic.target[{i}].shape: {:?} is not sphere, double_sphere or disc",
                    t.shape
                ));
            }
            finite_positive(&format!("synthetic.target[{i}].radius"), t.radius)?;
            match &t.motion {
                MotionSpec::Line { period_s, .. } | MotionSpec::Circle { period_s, .. } => {
                    finite_positive(&format!("synthetic.target[{i}].motion.period_s"), *period_s)?
                }
                _ => {}
            }
        }
    }
    Ok(())
}

impl CommonArgs {
    /// Loads the rig and resolves host, prefix and Zenoh endpoints.
    pub fn resolve(&self) -> Result<Context, TransportError> {
        let (rig_file, rig) = load_rig(&self.rig)?;
        let host = match (&self.host, rig_file.hosts.as_slice()) {
            (Some(h), []) if h == "local" => h.clone(),
            (Some(h), []) => {
                return Err(TransportError::Config(format!(
                    "--host {h:?}: {} has no [[host]] sections, so every service is this PC's (omit --host)",
                    self.rig.display()
                )));
            }
            (Some(h), hosts) if hosts.iter().any(|x| &x.name == h) => h.clone(),
            (Some(h), hosts) => {
                return Err(TransportError::Config(format!(
                    "--host {h:?} is not a [[host]] of {} (hosts: {:?})",
                    self.rig.display(),
                    hosts.iter().map(|h| &h.name).collect::<Vec<_>>()
                )));
            }
            (None, [one]) => one.name.clone(),
            (None, []) => "local".to_string(),
            (None, _) => {
                return Err(TransportError::Config(format!(
                    "{} has several [[host]] sections: say which this PC is with --host",
                    self.rig.display()
                )));
            }
        };
        let host_spec = rig_file.hosts.iter().find(|h| h.name == host).cloned();
        let iox_prefix = self
            .iox_prefix
            .clone()
            .or_else(|| host_spec.as_ref().and_then(|h| h.iceoryx2_prefix.clone()))
            .unwrap_or_else(|| DEFAULT_IOX_PREFIX.to_string());
        let zenoh = match &self.zenoh_mode {
            Some(m) => ZenohSpec {
                mode: ZenohMode::parse(m)?,
                connect: self.zenoh_connect.clone(),
                listen: self.zenoh_listen.clone(),
            },
            None if !self.zenoh_connect.is_empty() || !self.zenoh_listen.is_empty() => ZenohSpec {
                mode: ZenohMode::Peer,
                connect: self.zenoh_connect.clone(),
                listen: self.zenoh_listen.clone(),
            },
            None => default_zenoh(host_spec.as_ref()),
        };
        Ok(Context {
            rig_path: self.rig.clone(),
            rig_file,
            rig,
            host,
            iox_prefix,
            zenoh,
        })
    }
}

/// A client of the host's router (its first listen endpoint, seen from this PC), or a lone
/// peer when the rig says nothing.
pub fn default_zenoh(host: Option<&HostSpec>) -> ZenohSpec {
    match host.and_then(|h| h.zenoh_listen.first()) {
        Some(e) => ZenohSpec::client_of(&local_endpoint(e)),
        None => ZenohSpec {
            mode: ZenohMode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
        },
    }
}

/// A listen endpoint as a client on the same PC reaches it: any-address becomes loopback.
pub fn local_endpoint(listen: &str) -> String {
    listen
        .replace("/0.0.0.0:", "/127.0.0.1:")
        .replace("/[::]:", "/[::1]:")
}

impl Context {
    /// The camera ids whose services run on this host.
    pub fn cameras_here(&self) -> Vec<String> {
        self.rig_file
            .cameras
            .iter()
            .filter(|c| c.host.as_deref().is_none_or(|h| h == self.host))
            .map(|c| c.id.clone())
            .collect()
    }

    pub fn fusion_here(&self) -> bool {
        self.rig_file
            .fusion
            .as_ref()
            .and_then(|f| f.host.as_deref())
            .is_none_or(|h| h == self.host)
    }

    /// The common flags that reproduce this context for a child service joining Zenoh as
    /// `zenoh` says.
    pub fn to_args(&self, zenoh: &ZenohSpec) -> Vec<String> {
        let mut a = vec![
            "--rig".to_string(),
            self.rig_path.display().to_string(),
            "--host".into(),
            self.host.clone(),
            "--iox-prefix".into(),
            self.iox_prefix.clone(),
        ];
        a.extend(zenoh.to_args());
        a
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RIG: &str = include_str!("../../../deploy/rigs/thesis-lab.toml");

    #[test]
    fn thesis_lab_passes_and_bad_deployments_are_named() {
        parse_rig(RIG).unwrap();
        let with_host =
            format!("{RIG}\n[[host]]\nname = \"pc1\"\nzenoh_listen = [\"tcp/0.0.0.0:7447\"]\n");
        let (f, _) = parse_rig(&with_host).unwrap();
        assert_eq!(
            default_zenoh(f.hosts.first()).connect,
            vec!["tcp/127.0.0.1:7447".to_string()]
        );
        let bad = format!("{RIG}\n[fusion]\nhost = \"pc9\"\n");
        let e = parse_rig(&bad).unwrap_err();
        assert!(e.contains("fusion.host") && e.contains("pc9"), "{e}");
        let bad = RIG.replacen("id = \"cam1\"", "id = \"cam/1\"", 1);
        let e = parse_rig(&bad).unwrap_err();
        assert!(e.contains("camera[1].id"), "{e}");
        let bad = RIG.replacen(
            "id = \"cam1\"",
            "id = \"cam1\"\nsource = { kind = \"synthetic\", fps = 0.0 }",
            1,
        );
        let e = parse_rig(&bad).unwrap_err();
        assert!(e.contains("camera[1].source.fps"), "{e}");
        let bad = RIG.replacen(
            "id = \"cam1\"",
            "id = \"cam1\"\nsource = { kind = \"webcam\" }",
            1,
        );
        let e = parse_rig(&bad).unwrap_err();
        assert!(e.contains("webcam"), "{e}");
    }
}
