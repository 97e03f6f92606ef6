//! The rig's network security (`docs/deploy.md`, "Security"): which Zenoh endpoints a rig may
//! use, each PC's router with its mutual-TLS identity, and the access control every router
//! enforces — derived from the rig, so what a PC may publish follows from what runs on it.
//!
//! The trust boundary is the PC: a PC's own services reach its router over loopback; links
//! between PCs are mutual TLS, and each PC's certificate (common name = its `[[host]]` name)
//! lets it publish only what its services publish. A certificate of the rig's authority whose
//! name is not a host (a consumer: the VR or robot PC) may read and nothing else.

use crate::RigError;
use crate::error::err;
use crate::schema::{HostSpec, RigFile};
use serde_json::{Value, json};
use stereoscope_proto::names::zenoh as keys;

/// Where a PC's own services reach its router when its first listen endpoint is TLS and the
/// host names no `local_listen`.
pub const DEFAULT_LOCAL_LISTEN: &str = "tcp/127.0.0.1:7446";
/// Where a PC's own services reach its router when it says `local_auth = true`.
pub const DEFAULT_LOCAL_TLS_LISTEN: &str = "tls/127.0.0.1:7446";

/// Whether `endpoint` is `tls/` on a loopback address.
fn loopback_tls(endpoint: &str) -> bool {
    endpoint
        .strip_prefix("tls/")
        .is_some_and(|rest| reach(&format!("tcp/{rest}")) == Ok(Reach::Loopback))
}

/// What a Zenoh endpoint exposes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reach {
    /// Plain TCP or UDP on a loopback address: this PC only.
    Loopback,
    /// Mutual TLS.
    Tls,
    /// Plain TCP or UDP beyond this PC.
    Network,
}

/// A Zenoh endpoint this build cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EndpointError {
    #[error("{0:?} is not of the form tcp/ADDRESS:PORT")]
    Form(String),
    #[error("{0:?} has no :PORT")]
    NoPort(String),
    #[error("{endpoint:?}: protocol {protocol:?} is not one this build has (tcp, udp, tls)")]
    Protocol { endpoint: String, protocol: String },
}

/// Classifies `tcp/ADDRESS:PORT`, `udp/…` or `tls/…`.
pub fn reach(endpoint: &str) -> Result<Reach, EndpointError> {
    let (protocol, rest) = endpoint
        .split_once('/')
        .ok_or_else(|| EndpointError::Form(endpoint.to_string()))?;
    // Zenoh's endpoint options and metadata follow a '?' or '#'.
    let address = rest.split(['?', '#']).next().unwrap_or(rest);
    let host = match address.rsplit_once(':') {
        Some((h, port)) if port.parse::<u16>().is_ok() => h,
        _ => return Err(EndpointError::NoPort(endpoint.to_string())),
    };
    match protocol {
        "tls" => Ok(Reach::Tls),
        "tcp" | "udp" => {
            let loopback = host == "localhost"
                || host == "[::1]"
                || host
                    .parse::<std::net::Ipv4Addr>()
                    .is_ok_and(|a| a.is_loopback());
            Ok(if loopback {
                Reach::Loopback
            } else {
                Reach::Network
            })
        }
        other => Err(EndpointError::Protocol {
            endpoint: endpoint.to_string(),
            protocol: other.to_string(),
        }),
    }
}

/// Checks every host's endpoints: well formed; `tls/` only with the host's certificate;
/// plain TCP or UDP beyond loopback only when the rig says `insecure = true`.
pub(crate) fn check_hosts(file: &RigFile) -> Result<(), RigError> {
    for (i, h) in file.hosts.iter().enumerate() {
        let listen = h.zenoh_listen.iter().map(|e| ("zenoh_listen", e));
        let connect = h.zenoh_connect.iter().map(|e| ("zenoh_connect", e));
        let mut index = std::collections::HashMap::<&str, usize>::new();
        for (list, e) in listen.chain(connect) {
            let j = index.entry(list).or_default();
            let key = format!("host[{i}].{list}[{j}]");
            *j += 1;
            match reach(e).map_err(|m| err(&key, m.to_string()))? {
                Reach::Loopback => {}
                Reach::Tls if h.tls.is_none() => {
                    return Err(err(
                        key,
                        format!(
                            "{e:?} is a TLS endpoint but host {:?} has no tls = {{ ca, cert, key }} \
                             (deploy/make-certs.sh makes them)",
                            h.name
                        ),
                    ));
                }
                Reach::Tls => {}
                Reach::Network if !file.insecure => {
                    return Err(err(
                        key,
                        format!(
                            "{e:?} is plain (unauthenticated, unencrypted) Zenoh beyond this PC: \
                             use a tls/ endpoint with the host's tls = {{ ca, cert, key }} \
                             (docs/deploy.md, \"Security\"), or write insecure = true at the top \
                             of the rig to accept it"
                        ),
                    ));
                }
                Reach::Network => {}
            }
        }
        if h.local_auth && h.tls.is_none() {
            return Err(err(
                format!("host[{i}].local_auth"),
                format!(
                    "host {:?} has no tls = {{ ca, cert, key }}: with local_auth its own services \
                     show its certificate to its router",
                    h.name
                ),
            ));
        }
        if let Some(l) = &h.local_listen {
            if h.local_auth && !loopback_tls(l) {
                return Err(err(
                    format!("host[{i}].local_listen"),
                    format!(
                        "{l:?} must be a tls/ endpoint on 127.0.0.1 (local_auth: this PC's \
                         services show its certificate)"
                    ),
                ));
            }
            if !h.local_auth && reach(l) != Ok(Reach::Loopback) {
                return Err(err(
                    format!("host[{i}].local_listen"),
                    format!("{l:?} must be a tcp/ endpoint on 127.0.0.1 (this PC's services only)"),
                ));
            }
        }
        if let Some(t) = &h.tls {
            for (name, path) in [("ca", &t.ca), ("cert", &t.cert), ("key", &t.key)] {
                if path.trim().is_empty() {
                    return Err(err(format!("host[{i}].tls.{name}"), "is empty"));
                }
            }
        }
    }
    Ok(())
}

/// A listen endpoint as a client on the same PC reaches it: any-address becomes loopback.
pub fn local_endpoint(listen: &str) -> String {
    listen
        .replace("/0.0.0.0:", "/127.0.0.1:")
        .replace("/[::]:", "/[::1]:")
}

/// The endpoint a PC's own services reach its router on (`None` for a host that listens on
/// nothing).
pub fn service_endpoint(h: &HostSpec) -> Option<String> {
    if let Some(l) = &h.local_listen {
        return Some(l.clone());
    }
    if h.local_auth {
        return Some(DEFAULT_LOCAL_TLS_LISTEN.to_string());
    }
    let first = h.zenoh_listen.first()?;
    Some(match reach(first) {
        Ok(Reach::Tls) => DEFAULT_LOCAL_LISTEN.to_string(),
        _ => local_endpoint(first),
    })
}

/// The host a service whose section says `host` runs on: that one, or the only host.
fn runs_on<'a>(file: &'a RigFile, host: &'a Option<String>) -> Option<&'a str> {
    match (host, file.hosts.as_slice()) {
        (Some(h), _) => Some(h.as_str()),
        (None, [only]) => Some(only.name.as_str()),
        _ => None,
    }
}

/// The keys host `name`'s services publish on: its health and liveliness, its launcher's
/// requests that another PC's service renew a token its router lost (any service's: a host
/// certificate's holder can make tokens flap, no faster than `RENEW_AT_MOST_EVERY`), its
/// cameras' observations, previews (and the renderer's truth), the poses, bodies and models if
/// fusion runs there, and the live wand calibration's coverage (`calibrate wand --live` runs on
/// any PC).
pub fn published_by(file: &RigFile, name: &str) -> Vec<String> {
    let rig = &file.name;
    let mut out = vec![
        keys::health(rig, name, "**"),
        keys::alive(rig, name, "**"),
        keys::all_renew(rig),
        keys::wand_coverage(rig),
    ];
    for c in &file.cameras {
        if runs_on(file, &c.host) == Some(name) {
            out.push(keys::observations(rig, &c.id));
            out.push(keys::truth(rig, &c.id));
            out.push(keys::preview(rig, &c.id));
        }
    }
    if let Some(f) = &file.fusion
        && runs_on(file, &f.host) == Some(name)
    {
        out.push(keys::poses(rig));
        out.push(keys::all_poses(rig));
        out.push(keys::all_bodies(rig));
        out.push(keys::all_models(rig));
    }
    out
}

/// The Zenoh `access_control` document host `here`'s router enforces (denied unless a rule
/// allows it):
/// - its own PC (the loopback interface): everything — unless the host says `local_auth`,
///   when its own services are held to its certificate's rights below like any other PC's;
/// - any peer with a certificate of the rig's authority (a `tls` link): subscribe and ask on
///   the rig's keys, and receive what is published there;
/// - a host's certificate (common name = host name): publish what its services publish
///   ([`published_by`]), nothing else.
pub fn access_control(file: &RigFile, here: &HostSpec) -> Value {
    let everything = [
        "put",
        "delete",
        "declare_subscriber",
        "query",
        "declare_queryable",
        "reply",
        "liveliness_token",
        "declare_liveliness_subscriber",
        "liveliness_query",
    ];
    let rig_keys = format!("stereoscope/{}/**", file.name);
    let mut rules = vec![
        json!({"id": "read", "key_exprs": [rig_keys],
               "messages": ["declare_subscriber", "declare_liveliness_subscriber",
                            "liveliness_query", "query", "reply"],
               "flows": ["ingress", "egress"], "permission": "allow"}),
        json!({"id": "receive", "key_exprs": [rig_keys],
               "messages": ["put", "delete", "liveliness_token"],
               "flows": ["egress"], "permission": "allow"}),
    ];
    let mut subjects = vec![json!({"id": "rig-certificate", "link_protocols": ["tls"]})];
    let mut policies = vec![
        json!({"id": "readers", "rules": ["read", "receive"], "subjects": ["rig-certificate"]}),
    ];
    if !here.local_auth {
        rules.push(
            json!({"id": "this-pc", "key_exprs": ["**"], "messages": everything,
                          "flows": ["ingress", "egress"], "permission": "allow"}),
        );
        subjects.push(json!({"id": "this-pc", "interfaces": ["lo"]}));
        policies.push(json!({"id": "this-pc", "rules": ["this-pc"], "subjects": ["this-pc"]}));
    }
    for h in &file.hosts {
        let id = format!("host-{}", h.name);
        rules.push(json!({"id": id, "key_exprs": published_by(file, &h.name),
                          "messages": ["put", "delete", "liveliness_token"],
                          "flows": ["ingress"], "permission": "allow"}));
        subjects.push(json!({"id": id, "cert_common_names": [h.name],
                             "link_protocols": ["tls"]}));
        policies.push(json!({"id": id, "rules": [id], "subjects": [id]}));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bodies are checked when the rig loads: a symmetric one is refused naming its key and
    /// what to move; good ones load, in metres whatever the file's unit.
    #[test]
    fn bodies_are_checked_at_load() {
        // The lab's file is in centimetres.
        let square = "[[body]]\nname = \"square\"\nmarkers = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]]\n";
        let e = crate::Rig::from_toml(&format!("{LAB}\n{square}")).unwrap_err();
        assert_eq!(e.key, "body[0]", "{e}");
        assert!(
            e.message.contains("symmetric") && e.message.contains("move marker"),
            "{e}"
        );
        let good = "[[body]]\nname = \"head\"\nmarkers = [[0, 0, 0], [9, 0, 0], [0, 5, 0], [3, 2, 7]]\ntolerance = 0.2\n";
        let r = crate::Rig::from_toml(&format!("{LAB}\n{good}")).unwrap();
        let defs = crate::check::body_defs(&r.spec);
        assert!((defs[0].markers_m[1].x - 0.09).abs() < 1e-12);
        assert!((defs[0].tolerance_m - 0.002).abs() < 1e-12);
        let e = crate::Rig::from_toml(&format!("{LAB}\n{good}{good}")).unwrap_err();
        assert!(e.message.contains("appears twice"), "{e}");
    }

    #[test]
    fn endpoints_are_classified() {
        assert_eq!(reach("tcp/127.0.0.1:7447"), Ok(Reach::Loopback));
        assert_eq!(reach("tcp/localhost:7447"), Ok(Reach::Loopback));
        assert_eq!(reach("tcp/[::1]:7447"), Ok(Reach::Loopback));
        assert_eq!(reach("tcp/0.0.0.0:7447"), Ok(Reach::Network));
        assert_eq!(reach("udp/192.168.1.2:7447"), Ok(Reach::Network));
        assert_eq!(reach("tls/192.168.1.2:7447"), Ok(Reach::Tls));
        assert_eq!(reach("tls/fusion:7447?x=y"), Ok(Reach::Tls));
        let e = reach("quic/1.2.3.4:7447").unwrap_err();
        assert!(matches!(&e, EndpointError::Protocol { protocol, .. } if protocol == "quic"));
        assert!(e.to_string().contains("quic"), "{e}");
        assert!(matches!(
            reach("tcp/1.2.3.4"),
            Err(EndpointError::NoPort(_))
        ));
        assert!(matches!(reach("nothing"), Err(EndpointError::Form(_))));
    }

    const LAB: &str = include_str!("../../../../deploy/rigs/thesis-lab.toml");

    fn rig(extra: &str, hosts: &str) -> Result<crate::Rig, RigError> {
        crate::Rig::from_toml(&format!("{extra}\n{LAB}\n{hosts}"))
    }

    #[test]
    fn plain_tcp_between_pcs_needs_insecure_said_in_so_many_words() {
        let hosts = "[[host]]\nname = \"pc1\"\nzenoh_listen = [\"tcp/192.168.1.1:7447\"]\n";
        let e = rig("", hosts).unwrap_err();
        assert_eq!(e.key, "host[0].zenoh_listen[0]");
        assert!(e.message.contains("insecure = true"), "{e}");
        assert!(e.message.contains("tcp/192.168.1.1:7447"), "{e}");
        rig("insecure = true", hosts).unwrap();
    }

    #[test]
    fn a_tls_endpoint_needs_the_hosts_certificate() {
        let e = rig(
            "",
            "[[host]]\nname = \"pc1\"\n\
             zenoh_listen = [\"tcp/127.0.0.1:7447\"]\nzenoh_connect = [\"tls/10.0.0.2:7447\"]\n",
        )
        .unwrap_err();
        assert_eq!(e.key, "host[0].zenoh_connect[0]");
        assert!(e.message.contains("tls = { ca, cert, key }"), "{e}");
    }

    #[test]
    fn each_host_may_publish_only_what_its_services_publish() {
        let lab = LAB
            .replace("id = \"cam0\"", "id = \"cam0\"\nhost = \"cap\"")
            .replace("id = \"cam1\"", "id = \"cam1\"\nhost = \"cap\"");
        let r = crate::Rig::from_toml(&format!(
            "{lab}\n[fusion]\nhost = \"fus\"\n\
             [[host]]\nname = \"cap\"\nzenoh_listen = [\"tcp/127.0.0.1:7447\"]\n\
             [[host]]\nname = \"fus\"\nzenoh_listen = [\"tcp/127.0.0.1:7448\"]\n"
        ))
        .unwrap();
        let cap = published_by(&r.spec, "cap");
        let n = &r.name;
        assert!(cap.contains(&format!("stereoscope/{n}/observations/cam0")));
        assert!(!cap.iter().any(|k| k.contains("pose")), "{cap:?}");
        assert!(cap.contains(&format!("stereoscope/{n}/renew/**")));
        assert!(cap.contains(&format!("stereoscope/{n}/preview/cam1")));
        let fus = published_by(&r.spec, "fus");
        assert!(fus.contains(&format!("stereoscope/{n}/poses")));
        assert!(fus.contains(&format!("stereoscope/{n}/bodies/*")));
        assert!(fus.contains(&format!("stereoscope/{n}/models/*")));
        assert!(!fus.iter().any(|k| k.contains("observations")), "{fus:?}");
        let acl = access_control(&r.spec, &r.spec.hosts[0]);
        assert_eq!(acl["default_permission"], "deny");
        let cap_subject = acl["subjects"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["id"] == "host-cap")
            .unwrap();
        assert_eq!(cap_subject["cert_common_names"][0], "cap");
        // Loopback trusted: the interface's policy is there.
        let policy = |acl: &Value, id: &str| {
            acl["policies"]
                .as_array()
                .unwrap()
                .iter()
                .any(|p| p["id"] == id)
        };
        assert!(policy(&acl, "this-pc") && policy(&acl, "host-cap"));
        // The document is what Zenoh accepts.
        let mut cfg = zenoh::Config::default();
        cfg.insert_json5("access_control", &acl.to_string())
            .unwrap();
        // With local_auth the PC's own services have only the host certificate's rights.
        let mut here = r.spec.hosts[0].clone();
        here.local_auth = true;
        let strict = access_control(&r.spec, &here);
        assert!(!policy(&strict, "this-pc") && policy(&strict, "host-cap"));
        assert!(!strict.to_string().contains("\"lo\""), "{strict}");
        let mut cfg = zenoh::Config::default();
        cfg.insert_json5("access_control", &strict.to_string())
            .unwrap();
    }

    /// `local_auth`: the host's certificate is needed, the services' endpoint is TLS on
    /// loopback, and a plain or remote one is refused by name.
    #[test]
    fn loopback_authentication_needs_a_certificate_and_a_loopback_tls_endpoint() {
        let tls = "tls = { ca = \"ca.pem\", cert = \"pc1.pem\", key = \"pc1.key\" }\n";
        let host =
            "[[host]]\nname = \"pc1\"\nzenoh_listen = [\"tls/10.0.0.1:7447\"]\nlocal_auth = true\n";
        let e = rig(
            "",
            &host.replace("zenoh_listen = [\"tls/10.0.0.1:7447\"]\n", ""),
        )
        .unwrap_err();
        assert_eq!(e.key, "host[0].local_auth");
        assert!(e.message.contains("tls = { ca, cert, key }"), "{e}");
        let r = rig("", &format!("{host}{tls}")).unwrap();
        assert_eq!(
            service_endpoint(&r.spec.hosts[0]).as_deref(),
            Some(DEFAULT_LOCAL_TLS_LISTEN)
        );
        for (bad, why) in [
            ("tcp/127.0.0.1:7446", "tls/"),
            ("tls/10.0.0.1:7446", "127.0.0.1"),
        ] {
            let e = rig("", &format!("{host}{tls}local_listen = \"{bad}\"\n")).unwrap_err();
            assert_eq!(e.key, "host[0].local_listen");
            assert!(e.message.contains(bad) && e.message.contains(why), "{e}");
        }
        let r = rig(
            "",
            &format!("{host}{tls}local_listen = \"tls/127.0.0.1:9000\"\n"),
        )
        .unwrap();
        assert_eq!(
            service_endpoint(&r.spec.hosts[0]).as_deref(),
            Some("tls/127.0.0.1:9000")
        );
    }
}
