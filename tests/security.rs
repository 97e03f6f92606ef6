//! System test of `[[host]] local_auth` (docs/deploy.md, "Security"): loopback not trusted.
//! One PC on loopback runs the demo rig with its router on mutual TLS only; its own services
//! reach it with the host's certificate; clients the project did not write (Zenoh's Python
//! binding) try what a local user could. Certificates from `deploy/make-certs.sh`; own
//! iceoryx2 prefix, own loopback ports, every wait bounded, every child reaped.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::{Proc, TempDir, repo_root};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};
use stereoscope_transport::net;

fn lines(out: &str) -> Vec<serde_json::Value> {
    out.lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// With `local_auth = true` the rig runs (its services show the host's certificate on
/// loopback, poses reach a consumer), and a local program is held to what a certificate
/// allows: plain TCP finds no listener, another authority's certificate is refused, and a
/// consumer's certificate may read but what it forges on the poses, a camera's observations
/// and a liveliness token never reaches a reader. `stereoscope status` on the PC reaches the
/// router with the host's certificate and sees every service alive.
#[test]
fn a_pc_that_trusts_no_loopback_client_runs_and_refuses_local_forgers() {
    let dir = TempDir::new("localauth");
    let make = |out: &Path, names: &[&str]| {
        let o = Command::new(repo_root().join("deploy/make-certs.sh"))
            .arg(out)
            .args(names)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let certs = dir.0.join("certs");
    make(&certs, &["pc=127.0.0.1", "consumer"]);
    let other = dir.0.join("other");
    make(&other, &["consumer"]);
    let (listen, local) = (
        net::free_loopback_port().unwrap(),
        net::free_loopback_port().unwrap(),
    );
    let demo = std::fs::read_to_string(repo_root().join("deploy/rigs/demo.toml")).unwrap();
    assert!(
        demo.contains(common::DEMO_VR),
        "the demo rig's [vr] changed"
    );
    let rig = dir.file(
        "rig.toml",
        &format!(
            "{}\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tls/127.0.0.1:{listen}\"]\n\
             local_listen = \"tls/127.0.0.1:{local}\"\nlocal_auth = true\n\
             iceoryx2_prefix = \"stsc_la{}_\"\n\
             tls = {{ ca = \"certs/ca.pem\", cert = \"certs/pc.pem\", key = \"certs/pc.key\" }}\n",
            demo.replace(common::DEMO_VR, ""),
            std::process::id()
        ),
    );
    let mut launcher = Proc::start(&["run", &rig, "--host", "pc"]);
    let python = common::python_clients();
    let client = repo_root().join("tests/clients/zenoh_tls.py");
    let client = client.to_str().unwrap();
    let cert = |d: &Path, name: &str| -> [String; 3] {
        [
            d.join("ca.pem").display().to_string(),
            d.join(format!("{name}.pem")).display().to_string(),
            d.join(format!("{name}.key")).display().to_string(),
        ]
    };
    let py = |args: &[&str]| -> Vec<serde_json::Value> {
        let mut all = vec![client];
        all.extend_from_slice(args);
        let o = common::run_program_with_limit(&python, &all, Duration::from_secs(40));
        assert!(o.status.success(), "{args:?}: {}", common::stderr(&o));
        lines(&String::from_utf8_lossy(&o.stdout))
    };
    let endpoint = format!("tls/127.0.0.1:{listen}");
    let local_endpoint = format!("tls/127.0.0.1:{local}");
    let [ca, cc, ck] = cert(&certs, "consumer");
    // A reader with the rig's consumer certificate, on loopback, for the whole test.
    let watcher = Proc::start_program(
        &python,
        &[
            client,
            "watch",
            &local_endpoint,
            "demo",
            "30",
            &ca,
            &cc,
            &ck,
        ],
        &[],
    );
    let end = Instant::now() + Duration::from_secs(40);
    while lines(&watcher.output())
        .iter()
        .filter(|v| v.get("sequence").is_some())
        .count()
        < 30
    {
        assert!(
            Instant::now() < end,
            "no poses at a consumer in 40 s; watcher:\n{}\nlauncher:\n{}",
            watcher.output(),
            launcher.output()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // Plain TCP on either port finds no Zenoh (a TLS listener refuses it); another
    // authority's certificate is refused.
    for port in [listen, local] {
        let r = py(&["connect-plain", &format!("tcp/127.0.0.1:{port}")]);
        assert_eq!(r[0]["connected"], false, "plain TCP on {port}: {r:?}");
    }
    let [oa, oc, ok] = cert(&other, "consumer");
    let r = py(&["connect", &local_endpoint, &oa, &oc, &ok]);
    assert_eq!(r[0]["connected"], false, "another authority: {r:?}");
    // A consumer's certificate forges the poses, a camera's observations and a token.
    let forged = py(&[
        "forge",
        &local_endpoint,
        "demo",
        &ca,
        &cc,
        &ck,
        "4",
        "poses",
        "observations/cam0",
        "bodies/head",
    ]);
    assert!(
        forged.iter().any(|v| v["opened"] == true),
        "the forger never connected: {forged:?}"
    );
    let alive = py(&["alive", &endpoint, "demo", &ca, &cc, &ck]);
    let tokens = alive[0]["alive"].as_array().unwrap();
    assert!(
        !tokens
            .iter()
            .any(|t| t.as_str().unwrap_or("").contains("FORGED")),
        "{alive:?}"
    );
    // `status` on the PC: through the host's certificate, every service alive.
    let o = common::run_with_limit(&["status", &rig, "--json"], Duration::from_secs(30));
    assert!(o.status.success(), "{}", common::stderr(&o));
    let status: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    let services = status["services"].as_array().unwrap();
    for service in ["fusion", "capture/cam0", "moments/cam1"] {
        assert!(
            services
                .iter()
                .any(|s| s["service"] == service && s["alive"] == true),
            "{service} not alive in status: {status}"
        );
    }
    let mut watcher = watcher;
    watcher.wait_for(Duration::from_secs(60), "the watcher's end", |o| {
        o.contains("\"done\"")
    });
    let seen = lines(&watcher.output());
    assert!(
        !seen.iter().any(|v| v.get("forged").is_some()),
        "a forged sample reached the reader: {:?}",
        seen.iter().find(|v| v.get("forged").is_some())
    );
    watcher.stop();
    launcher.stop();
    let log = launcher.output();
    assert!(!log.contains("restarted"), "{log}");
}
