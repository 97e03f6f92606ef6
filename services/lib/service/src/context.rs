//! What every service is started with: the rig, which PC it is on, its iceoryx2 prefix and how
//! it joins Zenoh — the same flags for every service binary, checked the same way.

use std::path::PathBuf;
use stereoscope_rig::schema::HostSpec;
use stereoscope_rig::{Rig, RigError, RigErrorKind};
use stereoscope_transport::net::{ZenohMode, ZenohSpec};

/// Default iceoryx2 file prefix.
pub const DEFAULT_IOX_PREFIX: &str = "stsc_";

// No doc comment here: clap would give it to every command as its description.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct HostArgs {
    /// This PC's name in the rig file's `[[host]]` list (the only one if omitted).
    #[arg(long)]
    pub host: Option<String>,
    /// Prefix of iceoryx2's files (default: the host's `iceoryx2_prefix`, else "stsc_").
    #[arg(long)]
    pub iox_prefix: Option<String>,
}

// No doc comment here: clap would give it to every service as its description.
#[derive(Debug, Clone, clap::Args)]
pub struct CommonArgs {
    /// The rig file.
    #[arg(long)]
    pub rig: PathBuf,
    /// Which PC this is, and its iceoryx2 prefix (shared with `stereoscope run`).
    #[command(flatten)]
    pub place: HostArgs,
    /// client, peer or router (default: client of this host's router, or a peer with no
    /// endpoints when the rig lists no hosts).
    #[arg(long)]
    pub zenoh_mode: Option<String>,
    /// A Zenoh endpoint to connect to (`tcp/127.0.0.1:7447`); repeat for several.
    #[arg(long)]
    pub zenoh_connect: Vec<String>,
    /// A Zenoh endpoint to listen on; repeat for several.
    #[arg(long)]
    pub zenoh_listen: Vec<String>,
    #[command(flatten)]
    pub tls: TlsArgs,
}

// No doc comment here: clap would give it to every command as its description.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct TlsArgs {
    /// For tls/ endpoints: the rig's certificate authority (PEM).
    #[arg(long, requires_all = ["zenoh_tls_cert", "zenoh_tls_key"])]
    pub zenoh_tls_ca: Option<PathBuf>,
    /// For tls/ endpoints: this end's certificate (PEM).
    #[arg(long, requires_all = ["zenoh_tls_ca", "zenoh_tls_key"])]
    pub zenoh_tls_cert: Option<PathBuf>,
    /// For tls/ endpoints: this end's private key (PEM).
    #[arg(long, requires_all = ["zenoh_tls_ca", "zenoh_tls_cert"])]
    pub zenoh_tls_key: Option<PathBuf>,
}

impl TlsArgs {
    /// The three files, when all were given.
    pub fn files(&self) -> Option<stereoscope_transport::net::TlsFiles> {
        Some(stereoscope_transport::net::TlsFiles {
            ca: self.zenoh_tls_ca.clone()?,
            cert: self.zenoh_tls_cert.clone()?,
            key: self.zenoh_tls_key.clone()?,
        })
    }
}

/// A service's resolved start-up context.
#[derive(Debug, Clone)]
pub struct Context {
    pub rig_path: PathBuf,
    pub rig: Rig,
    pub host: String,
    pub iox_prefix: String,
    pub zenoh: ZenohSpec,
}

impl CommonArgs {
    /// Loads the rig and resolves host, prefix and Zenoh endpoints.
    pub fn resolve(&self) -> Result<Context, RigError> {
        let rig = Rig::load(&self.rig)?;
        let args = |key: &str, message: String| RigError {
            kind: RigErrorKind::Arguments,
            file: Some(self.rig.clone()),
            key: key.to_string(),
            message,
        };
        let host = match (&self.place.host, rig.spec.hosts.as_slice()) {
            (Some(h), []) if h == "local" => h.clone(),
            (Some(h), []) => {
                return Err(args(
                    "--host",
                    format!(
                        "{h:?}: the rig has no [[host]] sections, so every service is this PC's (omit --host)"
                    ),
                ));
            }
            (Some(h), hosts) if hosts.iter().any(|x| &x.name == h) => h.clone(),
            (Some(h), hosts) => {
                return Err(args(
                    "--host",
                    format!(
                        "{h:?} is not a [[host]] of the rig (hosts: {:?})",
                        hosts.iter().map(|h| &h.name).collect::<Vec<_>>()
                    ),
                ));
            }
            (None, [one]) => one.name.clone(),
            (None, []) => "local".to_string(),
            (None, _) => {
                return Err(args(
                    "--host",
                    "missing: the rig has several [[host]] sections; say which this PC is".into(),
                ));
            }
        };
        let host_spec = rig.spec.hosts.iter().find(|h| h.name == host).cloned();
        let iox_prefix = self
            .place
            .iox_prefix
            .clone()
            .or_else(|| host_spec.as_ref().and_then(|h| h.iceoryx2_prefix.clone()))
            .unwrap_or_else(|| DEFAULT_IOX_PREFIX.to_string());
        let zenoh = match &self.zenoh_mode {
            Some(m) => ZenohSpec {
                mode: ZenohMode::parse(m).map_err(|e| args("--zenoh-mode", e.to_string()))?,
                connect: self.zenoh_connect.clone(),
                listen: self.zenoh_listen.clone(),
                tls: self.tls.files(),
                access_control: None,
            },
            None if !self.zenoh_connect.is_empty() || !self.zenoh_listen.is_empty() => ZenohSpec {
                mode: ZenohMode::Peer,
                connect: self.zenoh_connect.clone(),
                listen: self.zenoh_listen.clone(),
                tls: self.tls.files(),
                access_control: None,
            },
            None => default_zenoh(&rig, host_spec.as_ref())?,
        };
        Ok(Context {
            rig_path: self.rig.clone(),
            rig,
            host,
            iox_prefix,
            zenoh,
        })
    }
}

/// A client of the host's router (its first listen endpoint, seen from this PC), or a lone
/// peer when the rig says nothing. With `local_auth` the client shows the host's certificate.
pub fn default_zenoh(rig: &Rig, host: Option<&HostSpec>) -> Result<ZenohSpec, RigError> {
    let Some(e) = host.and_then(stereoscope_rig::security::service_endpoint) else {
        return Ok(ZenohSpec::lone_peer());
    };
    let mut spec = ZenohSpec::client_of(&e);
    if let Some(h) = host.filter(|h| h.local_auth) {
        let index = rig
            .spec
            .hosts
            .iter()
            .position(|x| x.name == h.name)
            .unwrap_or(0);
        spec.tls = crate::router::tls_files(h, index, rig.base_dir.as_deref())?;
    }
    Ok(spec)
}

impl Context {
    /// Who service `service` (`moments/cam0`) of this context is, for
    /// [`stereoscope_transport::ServiceNode::start`].
    pub fn node_spec<'a>(&'a self, service: &'a str) -> stereoscope_transport::NodeSpec<'a> {
        stereoscope_transport::NodeSpec {
            rig: &self.rig.name,
            host: &self.host,
            service,
            iox_prefix: &self.iox_prefix,
            zenoh: &self.zenoh,
            exclusive: stereoscope_transport::Exclusive::Rig,
        }
    }

    /// The camera ids whose services run on this host.
    pub fn cameras_here(&self) -> Vec<String> {
        self.rig
            .spec
            .cameras
            .iter()
            .filter(|c| c.host.as_deref().is_none_or(|h| h == self.host))
            .map(|c| c.id.clone())
            .collect()
    }

    pub fn fusion_here(&self) -> bool {
        self.rig
            .spec
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

    const RIG: &str = include_str!("../../../../deploy/rigs/thesis-lab.toml");

    fn key_of(text: &str) -> String {
        Rig::from_toml(text).unwrap_err().key
    }

    #[test]
    fn thesis_lab_passes_and_bad_deployments_are_named() {
        Rig::from_toml(RIG).unwrap();
        let with_host = format!(
            "insecure = true\n{RIG}\n[[host]]\nname = \"pc1\"\nzenoh_listen = [\"tcp/0.0.0.0:7447\"]\n"
        );
        let rig = Rig::from_toml(&with_host).unwrap();
        assert_eq!(
            default_zenoh(&rig, rig.spec.hosts.first()).unwrap().connect,
            vec!["tcp/127.0.0.1:7447".to_string()]
        );
        let bad = format!("{RIG}\n[fusion]\nhost = \"pc9\"\n");
        let e = Rig::from_toml(&bad).unwrap_err();
        assert!(e.key == "fusion.host" && e.message.contains("pc9"), "{e}");
        let bad = RIG.replacen("id = \"cam1\"", "id = \"cam/1\"", 1);
        assert_eq!(key_of(&bad), "camera[1].id");
        let bad = RIG.replacen(
            "id = \"cam1\"",
            "id = \"cam1\"\nsource = { kind = \"synthetic\", fps = 0.0 }",
            1,
        );
        assert_eq!(key_of(&bad), "camera[1].source.fps");
        let bad = RIG.replacen(
            "id = \"cam1\"",
            "id = \"cam1\"\nsource = { kind = \"webcam\" }",
            1,
        );
        let e = Rig::from_toml(&bad).unwrap_err();
        assert!(
            e.kind == RigErrorKind::Syntax && e.message.contains("webcam"),
            "{e}"
        );
    }
}
