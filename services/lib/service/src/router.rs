//! A PC's Zenoh router as the rig describes it (`docs/deploy.md`, "Security"): its endpoints,
//! the loopback one its own services reach it on, and with TLS its certificate and the access
//! control every router enforces (`stereoscope_rig::security`).

use std::path::Path;
use stereoscope_rig::error::err;
use stereoscope_rig::schema::{HostSpec, RigFile};
use stereoscope_rig::security::{Reach, access_control, local_endpoint, reach, service_endpoint};
use stereoscope_rig::{RigError, resolve};
use stereoscope_transport::net::{TlsFiles, ZenohMode, ZenohSpec};

/// The host's TLS files, resolved against the rig file's folder and checked readable.
pub fn tls_files(
    h: &HostSpec,
    index: usize,
    base: Option<&Path>,
) -> Result<Option<TlsFiles>, RigError> {
    let Some(t) = &h.tls else { return Ok(None) };
    let file = |name: &str, p: &str| {
        let path = resolve(base, p);
        match std::fs::File::open(&path) {
            Ok(_) => Ok(path),
            Err(e) => Err(err(
                format!("host[{index}].tls.{name}"),
                format!("{} cannot be read: {e}", path.display()),
            )),
        }
    };
    Ok(Some(TlsFiles {
        ca: file("ca", &t.ca)?,
        cert: file("cert", &t.cert)?,
        key: file("key", &t.key)?,
    }))
}

/// Host `name`'s router: its endpoints, plus the loopback one for its services when that is
/// not among them; with TLS, its certificate and the rig's access control.
pub fn router_spec(
    file: &RigFile,
    name: &str,
    base: Option<&Path>,
) -> Result<Option<ZenohSpec>, RigError> {
    let Some((index, h)) = file.hosts.iter().enumerate().find(|(_, h)| h.name == name) else {
        return Ok(None);
    };
    let Some(local) = service_endpoint(h) else {
        return Ok(None);
    };
    let mut listen = h.zenoh_listen.clone();
    // A TLS listener serves this PC's services only when they show the host's certificate.
    let served = listen
        .iter()
        .any(|e| local_endpoint(e) == local && (h.local_auth || reach(e) != Ok(Reach::Tls)));
    if !served {
        listen.push(local);
    }
    let tls = tls_files(h, index, base)?;
    let access_control = tls.as_ref().map(|_| access_control(file, h).to_string());
    Ok(Some(ZenohSpec {
        mode: ZenohMode::Router,
        connect: h.zenoh_connect.clone(),
        listen,
        tls,
        access_control,
    }))
}
