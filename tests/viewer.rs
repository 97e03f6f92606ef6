//! System test of the live view in a real browser: `stereoscope demo --view` runs the real
//! services (the viewer among them, started and supervised by the launcher) on its own
//! iceoryx2 prefix and loopback ports, and headless Chromium — driven over its DevTools
//! protocol by `tests/clients/viewer_check.py` — loads the page and checks what a user sees:
//! no console errors, pose frames at fusion's rate, cameras and markers where an independent
//! projection puts them, a monitor's blob boxes where the worker found them, hostile sockets
//! answered and counted with everything staying up, and live data again after the viewer is
//! killed. Every wait is bounded; the demo and the browser are reaped.
//!
//! With `STEREOSCOPE_DOCS_SCREENSHOTS=1` the screenshots are copied into `docs/images/`
//! (how the documentation's pictures are made).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::{Proc, TempDir, repo_root};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The browser tests each run a demo and a Chromium on a 2-core machine: one at a time.
static ONE_BROWSER: Mutex<()> = Mutex::new(());

/// Runs `stereoscope demo --rig RIG --view` on a free port until the viewer serves
/// `/api/rig`: the demo and the viewer's address.
fn demo_with_view(rig: &str) -> (Proc, String) {
    let port = stereoscope_transport::net::free_loopback_port().unwrap();
    let listen = format!("127.0.0.1:{port}");
    let demo = Proc::start(&[
        "demo",
        "--rig",
        rig,
        "--view",
        "--view-listen",
        &listen,
        "--seconds",
        "300",
        "--quiet",
    ]);
    demo.wait_for(Duration::from_secs(30), "the URL", |o| {
        o.contains(&format!("http://{listen}/"))
    });
    let end = Instant::now() + Duration::from_secs(60);
    while http_status(port, "/api/rig").is_none_or(|l| !l.contains(" 200 ")) {
        assert!(
            Instant::now() < end,
            "the viewer did not serve /api/rig within 60 s; demo output:\n{}",
            demo.output()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    (demo, listen)
}

/// Chromium from the Debian package (`.ci/run` installs it).
fn chromium() -> PathBuf {
    let found = std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|d| d.join("chromium"))
            .find(|p| p.is_file())
    });
    found.unwrap_or_else(|| {
        panic!("this test needs Chromium: install the Debian package `chromium` (.ci/run does)")
    })
}

/// `GET path` on the viewer; the status line, or `None` while nothing listens.
fn http_status(port: u16, path: &str) -> Option<String> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    text.lines().next().map(str::to_string)
}

#[test]
fn the_live_view_in_a_real_browser() {
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let chromium = chromium();
    // The demo rig with its VR feed on this test's own ports.
    let dir = common::TempDir::new("viewer");
    let rig = dir.file("demo.toml", &common::demo_rig_on_own_ports());
    let (mut demo, listen) = demo_with_view(&rig);
    let shots = TempDir::new("viewer-shots");
    let script = repo_root().join("tests/clients/viewer_check.py");
    let o = common::run_program_with_limit(
        &common::python_clients(),
        &[
            script.to_str().unwrap(),
            chromium.to_str().unwrap(),
            &format!("http://{listen}"),
            shots.0.to_str().unwrap(),
        ],
        Duration::from_secs(240),
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    if !o.status.success() {
        // The screenshots of a failed run are kept for a look.
        let keep = repo_root().join("target/viewer-check-failed");
        let _ = std::fs::create_dir_all(&keep);
        for e in std::fs::read_dir(&shots.0).unwrap().flatten() {
            let _ = std::fs::copy(e.path(), keep.join(e.file_name()));
        }
    }
    assert!(
        o.status.success(),
        "viewer_check.py: {}\n{out}\ndemo output:\n{}",
        common::stderr(&o),
        demo.output()
    );
    println!("{out}");
    if std::env::var_os("STEREOSCOPE_DOCS_SCREENSHOTS").is_some() {
        let docs = repo_root().join("docs/images");
        std::fs::create_dir_all(&docs).unwrap();
        for name in ["viewer-3d.png", "viewer-top.png", "viewer-monitor.png"] {
            std::fs::copy(shots.0.join(name), docs.join(name)).unwrap();
        }
    }
    demo.stop();
}

/// The robot-arm demo in the live view: the page draws the arm as its chain (link origins and
/// the lines between them) where an independent projection of the fit's link poses puts them
/// (`tests/clients/viewer_chain.py`).
#[test]
fn the_arm_is_drawn_as_its_chain_in_a_real_browser() {
    let _one = ONE_BROWSER.lock().unwrap_or_else(|e| e.into_inner());
    let chromium = chromium();
    let rig = repo_root().join("deploy/rigs/robot-arm.toml");
    let (mut demo, listen) = demo_with_view(rig.to_str().unwrap());
    let shots = TempDir::new("viewer-chain-shots");
    let o = common::run_program_with_limit(
        &common::python_clients(),
        &[
            repo_root()
                .join("tests/clients/viewer_chain.py")
                .to_str()
                .unwrap(),
            chromium.to_str().unwrap(),
            &format!("http://{listen}"),
            shots.0.to_str().unwrap(),
        ],
        Duration::from_secs(180),
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    if !o.status.success() {
        let keep = repo_root().join("target/viewer-chain-failed");
        let _ = std::fs::create_dir_all(&keep);
        for e in std::fs::read_dir(&shots.0).unwrap().flatten() {
            let _ = std::fs::copy(e.path(), keep.join(e.file_name()));
        }
    }
    assert!(
        o.status.success(),
        "viewer_chain.py: {}\n{out}\ndemo output:\n{}",
        common::stderr(&o),
        demo.output()
    );
    println!("{out}");
    demo.stop();
}
