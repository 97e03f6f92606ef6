//! System tests across a real network: the PCs of `deploy/rigs/three-pcs.toml` (two capture
//! PCs, a fusion PC, a consumer PC) as network namespaces this test makes, joined by veth pairs
//! on a bridge, with the addresses of the deploy file; mutual TLS with certificates from
//! `deploy/make-certs.sh`; the consumer a client the project did not write (Zenoh's Python
//! binding). There is no camera here, so the one change to the deploy file is each camera's
//! source: the synthetic renderer of a scene appended to it. Skipped, saying why, where
//! network namespaces cannot be made (not root, no `ip`).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::{BIN, Proc, TempDir, repo_root};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The PCs of three-pcs.toml and their addresses there.
const HOSTS: [(&str, &str); 4] = [
    ("capture1", "192.168.10.11"),
    ("capture2", "192.168.10.12"),
    ("fusion", "192.168.10.20"),
    ("consumer", "192.168.10.30"),
];
const FUSION: &str = "tls/192.168.10.20:7447";

fn ip(args: &[&str]) -> Result<(), String> {
    let o = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ))
    }
}

/// A switch namespace with a bridge and one namespace per PC, each with `eth0` on the bridge;
/// all deleted when dropped.
struct Lan {
    prefix: String,
}

impl Lan {
    fn new() -> Result<Lan, String> {
        let lan = Lan {
            prefix: format!("st{}", std::process::id()),
        };
        let sw = lan.ns("sw");
        ip(&["netns", "add", &sw])?;
        ip(&["-n", &sw, "link", "add", "br0", "type", "bridge"])?;
        ip(&["-n", &sw, "link", "set", "br0", "up"])?;
        for (i, (host, address)) in HOSTS.iter().enumerate() {
            let ns = lan.ns(host);
            let port = format!("v{i}");
            ip(&["netns", "add", &ns])?;
            ip(&[
                "link", "add", &port, "netns", &sw, "type", "veth", "peer", "name", "eth0",
                "netns", &ns,
            ])?;
            ip(&["-n", &sw, "link", "set", &port, "master", "br0", "up"])?;
            ip(&[
                "-n",
                &ns,
                "addr",
                "add",
                &format!("{address}/24"),
                "dev",
                "eth0",
            ])?;
            ip(&["-n", &ns, "link", "set", "eth0", "up"])?;
            ip(&["-n", &ns, "link", "set", "lo", "up"])?;
        }
        Ok(lan)
    }

    fn ns(&self, host: &str) -> String {
        format!("{}{host}", self.prefix)
    }

    /// Cuts (or restores) a PC's cable at the switch.
    fn cable(&self, host: &str, up: bool) {
        let i = HOSTS.iter().position(|(h, _)| *h == host).unwrap();
        ip(&[
            "-n",
            &self.ns("sw"),
            "link",
            "set",
            &format!("v{i}"),
            if up { "up" } else { "down" },
        ])
        .unwrap();
    }

    /// `program args` on PC `host`, with this test's temporary folder as TMPDIR (launcher
    /// locks, fusion's session state).
    fn start(&self, host: &str, program: &Path, args: &[&str], tmp: &Path) -> Proc {
        let ns = self.ns(host);
        let mut all = vec!["netns", "exec", &ns, program.to_str().unwrap()];
        all.extend_from_slice(args);
        Proc::start_program(Path::new("ip"), &all, &[("TMPDIR", tmp.to_str().unwrap())])
    }
}

impl Drop for Lan {
    fn drop(&mut self) {
        for (host, _) in HOSTS {
            let _ = ip(&["netns", "del", &self.ns(host)]);
        }
        let _ = ip(&["netns", "del", &self.ns("sw")]);
    }
}

/// The deploy file with synthetic cameras: the scene appended, every `v4l` source replaced.
fn deploy_rig_with_synthetic_cameras() -> String {
    let text = std::fs::read_to_string(repo_root().join("deploy/rigs/three-pcs.toml")).unwrap();
    let mut out = String::new();
    let mut replaced = 0;
    for line in text.lines() {
        if line.starts_with("source = { kind = \"v4l\"") {
            out.push_str("source = { kind = \"synthetic\", fps = 30.0 }\n");
            replaced += 1;
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    assert_eq!(replaced, 4, "three-pcs.toml has four v4l cameras");
    out + "\n[synthetic]\nseed = 1\nnoise_sigma = 2.0\nbackground = 20.0\n\n\
           [[synthetic.target]]\nshape = \"sphere\"\nradius = 25.0\n\
           motion = { kind = \"circle\", centre = [0.0, 0.0, 800.0], radius = 300.0, period_s = 8.0 }\n\n\
           [[synthetic.target]]\nshape = \"sphere\"\nradius = 25.0\n\
           motion = { kind = \"line\", from = [-400.0, 300.0, 500.0], to = [400.0, -300.0, 1100.0], period_s = 10.0 }\n"
}

/// Processes whose command line has `arg` among its arguments.
fn processes_with_arg(arg: &str) -> Vec<i32> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(cmdline) = std::fs::read(e.path().join("cmdline")) else {
            continue;
        };
        if cmdline.split(|b| *b == 0).any(|a| a == arg.as_bytes()) {
            out.push(pid);
        }
    }
    out
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// The liveliness tokens of `zenoh_tls.py alive`'s answer.
fn alive_tokens(r: &[serde_json::Value]) -> Vec<String> {
    r[0]["alive"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v.as_str().map(str::to_string))
        .collect()
}

/// One line of `zenoh_tls.py watch`.
#[derive(Debug)]
struct Seen {
    t: f64,
    sequence: u64,
    cameras: usize,
    error_mm: Option<f64>,
}

fn lines(out: &str) -> Vec<serde_json::Value> {
    out.lines()
        .filter(|l| l.starts_with('{'))
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn frames(out: &str) -> Vec<Seen> {
    lines(out)
        .into_iter()
        .filter(|v| v.get("sequence").is_some())
        .map(|v| Seen {
            t: v["t"].as_f64().unwrap(),
            sequence: v["sequence"].as_u64().unwrap(),
            cameras: v["cameras"].as_array().unwrap().len(),
            error_mm: v["error_mm"].as_f64(),
        })
        .collect()
}

/// The last pid the launcher's log gives service `service`.
fn pid_of(log: &str, service: &str) -> i32 {
    log.rsplit(&format!("ed {service} (pid "))
        .next()
        .filter(|_| log.contains(&format!("ed {service} (pid ")))
        .and_then(|s| s.split(')').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no pid of {service} in:\n{log}"))
}

/// The output so far of `host`'s launcher.
fn old_output(launchers: &[(&str, Proc)], host: &str) -> String {
    launchers
        .iter()
        .find(|(h, _)| *h == host)
        .map(|(_, p)| p.output())
        .unwrap_or_default()
}

/// Seconds from `t` to the first of ten pose frames in a row of all four cameras after the
/// first one without them (frames already on their way at `t`, and a straggler of the old
/// services, do not count).
fn whole_again(seen: &[Seen], t: f64) -> Option<f64> {
    let gap = seen.iter().position(|s| s.t > t && s.cameras < 4)?;
    seen[gap..]
        .windows(10)
        .find(|w| w.iter().all(|s| s.cameras == 4))
        .map(|w| w[0].t - t)
}

/// Seconds from `t` until the first pose frame with all four cameras.
fn until_whole(seen: &[Seen], t: f64) -> Option<f64> {
    seen.iter()
        .find(|s| s.t > t && s.cameras == 4)
        .map(|s| s.t - t)
}

/// The longest time between two pose frames within `[from, to]`.
fn longest_gap(seen: &[Seen], from: f64, to: f64) -> f64 {
    let ts: Vec<f64> = seen
        .iter()
        .map(|s| s.t)
        .filter(|t| (from..=to).contains(t))
        .collect();
    let mut gap = ts.first().map_or(to - from, |f| f - from);
    for w in ts.windows(2) {
        gap = gap.max(w[1] - w[0]);
    }
    gap.max(ts.last().map_or(0.0, |l| to - l))
}

#[test]
fn three_pcs_over_mutual_tls_survive_kills_a_cut_cable_and_forgers() {
    let lan = match Lan::new() {
        Ok(l) => l,
        // Not a skip: CI runs as root with iproute2, and a run that cannot test the network
        // says so by failing.
        Err(e) => panic!(
            "network namespaces cannot be made here ({e}): this test needs root and iproute2"
        ),
    };
    let dir = TempDir::new("netns");
    // Zenoh segments already in /dev/shm (another program's): none may be added by this run.
    let zenoh_segments = || -> std::collections::BTreeSet<String> {
        std::fs::read_dir("/dev/shm")
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.ends_with(".zenoh"))
                    .collect()
            })
            .unwrap_or_default()
    };
    let zenoh_before = zenoh_segments();
    let certs = dir.0.join("certs");
    let make = common::make_certs;
    let named: Vec<String> = HOSTS.iter().map(|(h, a)| format!("{h}={a}")).collect();
    make(
        &certs,
        &named.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    // An intruder's certificates: a valid-looking set from another authority.
    let other = dir.0.join("other");
    make(&other, &["consumer"]);
    let rig = dir.file("rig.toml", &deploy_rig_with_synthetic_cameras());
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
    let consumer_ns = lan.ns("consumer");
    let py = |args: &[&str]| -> Vec<serde_json::Value> {
        let mut all = vec!["netns", "exec", consumer_ns.as_str()];
        let p = python.to_str().unwrap();
        all.push(p);
        all.push(client);
        all.extend_from_slice(args);
        let o = common::run_program_with_limit(Path::new("ip"), &all, Duration::from_secs(30));
        assert!(o.status.success(), "{args:?}: {}", common::stderr(&o));
        lines(&String::from_utf8_lossy(&o.stdout))
    };

    let pid = std::process::id();
    let launch = |h: &str| {
        let prefix = format!("st{pid}{h}_");
        let args = ["run", &rig, "--host", h, "--iox-prefix", &prefix];
        lan.start(h, Path::new(BIN), &args, &dir.0)
    };
    let mut launchers: Vec<(&str, Proc)> = ["fusion", "capture1", "capture2"]
        .into_iter()
        .map(|h| (h, launch(h)))
        .collect();
    let [ca, cc, ck] = cert(&certs, "consumer");
    let watch_s = "600";
    let watcher = lan.start(
        "consumer",
        &python,
        &[client, "watch", FUSION, "lab", watch_s, &ca, &cc, &ck],
        &dir.0,
    );
    let seen_now = || frames(&watcher.output());
    // Poses of all four cameras reach the consumer PC.
    let end = Instant::now() + Duration::from_secs(40);
    while seen_now().iter().filter(|s| s.cameras == 4).count() < 30 {
        if Instant::now() > end {
            let logs: Vec<String> = launchers
                .iter()
                .map(|(h, p)| format!("--- {h}\n{}", p.output()))
                .collect();
            panic!(
                "no poses of four cameras at the consumer in 40 s; watcher:\n{}\n{}",
                watcher.output(),
                logs.join("\n")
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    let steady_from = now_s();
    std::thread::sleep(Duration::from_secs(3));

    // Security: an authority the rig does not trust cannot connect, nor a client with no
    // certificate, nor plain TCP to the TLS port; the consumer's own certificate connects but
    // may publish nothing; a capture PC's may not publish poses.
    let [oa, oc, ok] = cert(&other, "consumer");
    let r = py(&["connect", FUSION, &oa, &oc, &ok]);
    assert_eq!(r[0]["connected"], false, "{r:?}");
    let plain_tcp = FUSION.replace("tls/", "tcp/");
    for endpoint in [FUSION, plain_tcp.as_str()] {
        let r = py(&["connect-plain", endpoint]);
        assert_eq!(
            r[0]["connected"], false,
            "{endpoint} without a certificate: {r:?}"
        );
    }
    // What a user reads from `stereoscope status` without a certificate, and over plain TCP.
    let status = |endpoint: &str| -> String {
        let all = [
            "netns",
            "exec",
            &consumer_ns,
            BIN,
            "status",
            "--connect",
            endpoint,
            "--rig-name",
            "lab",
        ];
        let o = common::run_program_with_limit(Path::new("ip"), &all, Duration::from_secs(30));
        assert!(
            !o.status.success(),
            "status reached {endpoint} without a certificate"
        );
        common::stderr(&o)
    };
    let said = status(FUSION);
    assert!(
        said.contains("is a TLS endpoint") && said.contains("--zenoh-tls-cert"),
        "{said}"
    );
    let said = status(&plain_tcp);
    assert!(
        said.contains("no Zenoh router answered") && said.contains("tls/"),
        "{said}"
    );
    let r = py(&["connect", FUSION, &ca, &cc, &ck]);
    assert_eq!(r[0]["connected"], true, "{r:?}");
    let all_keys = [
        "poses",
        "pose/1",
        "observations/cam0",
        "health/fusion/fusion",
        "alive/fusion/x",
    ];
    // The consumer forges every key and a liveliness token, and holds the token while the
    // rig's liveliness is asked: the forged token must not be seen even while it exists.
    let mut forger = lan.start(
        "consumer",
        &python,
        &[
            &[client, "forge", FUSION, "lab", &ca, &cc, &ck, "8"][..],
            &all_keys[..],
        ]
        .concat(),
        &dir.0,
    );
    forger.wait_for(Duration::from_secs(20), "the forged token", |o| {
        o.contains("\"token\": true")
    });
    let alive = alive_tokens(&py(&["alive", FUSION, "lab", &ca, &cc, &ck]));
    assert!(
        forger.child.try_wait().unwrap().is_none(),
        "the forger ended before the rig's liveliness was asked"
    );
    assert!(
        !alive
            .iter()
            .any(|k| k.contains("FORGED") || k.ends_with("/x")),
        "a forged token is seen while its forger holds it: {alive:?}"
    );
    forger.stop();
    let [_, c1, k1] = cert(&certs, "capture1");
    let r = py(&[
        &["forge", FUSION, "lab", &ca, &c1, &k1, "3"][..],
        &[
            "poses",
            "pose/1",
            "health/fusion/fusion",
            "observations/cam2",
        ][..],
    ]
    .concat());
    assert_eq!(r[0]["opened"], true, "{r:?}");

    // kill -9 of one service on each PC: fusion, a capture, a moment worker; then the fusion
    // PC's router (every other PC's link and the consumer's go through it).
    let mut kills = Vec::new();
    for (host, service) in [
        ("fusion", "fusion"),
        ("capture1", "capture/cam0"),
        ("capture2", "moments/cam2"),
        ("fusion", "router"),
    ] {
        let log = launchers
            .iter()
            .find(|(h, _)| *h == host)
            .unwrap()
            .1
            .output();
        let victim = pid_of(&log, service);
        kills.push((service, now_s()));
        // SAFETY: a process this test started (through its launcher).
        assert_eq!(unsafe { libc::kill(victim, libc::SIGKILL) }, 0);
        std::thread::sleep(Duration::from_secs(4));
    }

    // capture1 rebooted: its launcher, router and services killed with -9 at once, its
    // iceoryx2 files gone from /dev/shm as after a reboot, and its launcher started again, as
    // the PC's supervisor would at boot.
    let relaunched = now_s();
    let prefix = format!("st{pid}capture1_");
    let victims = processes_with_arg(&prefix);
    assert!(victims.len() >= 5, "capture1's processes: {victims:?}");
    for v in &victims {
        // SAFETY: processes this test started (their command lines carry its prefix).
        unsafe { libc::kill(*v, libc::SIGKILL) };
    }
    let old = launchers
        .iter_mut()
        .find(|(h, _)| *h == "capture1")
        .unwrap();
    let _ = old.1.child.wait();
    for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
        if e.file_name().to_string_lossy().starts_with(&prefix) {
            let _ = std::fs::remove_file(e.path());
        }
    }
    let killed_launcher = std::mem::replace(&mut old.1, launch("capture1"));
    let end = Instant::now() + Duration::from_secs(30);
    while whole_again(&seen_now(), relaunched).is_none() {
        assert!(
            Instant::now() < end,
            "no four cameras within 30 s of capture1's reboot\n{}\n{}",
            killed_launcher.output(),
            old_output(&launchers, "capture1")
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_secs(2));

    // capture2's cable out for 5 s.
    let cut = now_s();
    lan.cable("capture2", false);
    std::thread::sleep(Duration::from_secs(5));
    let restored = now_s();
    lan.cable("capture2", true);
    std::thread::sleep(Duration::from_secs(5));
    let last = now_s();

    let out = watcher.output();
    let seen = frames(&out);
    let logs: Vec<(&str, String)> = launchers.iter().map(|(h, p)| (*h, p.output())).collect();
    let context = || {
        let l: Vec<String> = logs.iter().map(|(h, o)| format!("--- {h}\n{o}")).collect();
        format!("watcher:\n{out}\n{}", l.join("\n"))
    };
    // Poses against the scene's truth.
    let errors: Vec<f64> = seen
        .iter()
        .filter(|s| s.t > steady_from && s.t < kills[0].1 && s.cameras == 4)
        .filter_map(|s| s.error_mm)
        .collect();
    assert!(
        errors.len() >= 20,
        "{} scored frames\n{}",
        errors.len(),
        context()
    );
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    // About 1 mm on an idle machine (docs/deploy.md); 3 mm leaves room for a loaded one.
    assert!(median <= 3.0, "median error {median} mm\n{}", context());
    // Nothing forged crossed a router.
    let forged: Vec<_> = lines(&out)
        .into_iter()
        .filter(|v| v.get("forged").is_some())
        .collect();
    assert!(
        forged.is_empty(),
        "forged samples reached the consumer: {forged:?}"
    );
    // Kills: poses from all four cameras again within 2 s; fusion's numbering goes on.
    for (service, t) in &kills {
        eprintln!(
            "kill -9 of {service}: four cameras again after {:?} s",
            until_whole(&seen, *t)
        );
        let back = until_whole(&seen, *t);
        assert!(
            back.is_some_and(|b| b < 2.0),
            "after kill -9 of {service}: four cameras again after {back:?} s\n{}",
            context()
        );
    }
    let (_, fusion_killed) = kills[0];
    let before = seen.iter().rfind(|s| s.t < fusion_killed).unwrap();
    let after = seen.iter().find(|s| s.t > fusion_killed).unwrap();
    assert!(
        after.sequence > before.sequence,
        "pose sequence went back after the fusion restart: {} then {}",
        before.sequence,
        after.sequence
    );
    // The cut cable: poses of the other PC's cameras go on; capture2's rejoin within 2 s.
    let gap = longest_gap(&seen, cut, restored);
    assert!(
        gap < 1.0,
        "poses stopped for {gap:.2} s with a cable out\n{}",
        context()
    );
    let back = until_whole(&seen, restored);
    assert!(
        back.is_some_and(|b| b < 2.0),
        "capture2 back after {back:?} s\n{}",
        context()
    );
    assert!(longest_gap(&seen, restored, last) < 1.0, "{}", context());
    // The launcher of capture1 killed and started again: its cameras back, measured.
    let back = whole_again(&seen, relaunched);
    eprintln!("capture1 rebooted: four cameras again after {back:?} s");
    assert!(back.is_some_and(|b| b < 30.0), "{}", context());
    // The rig's liveliness as the consumer sees it: its nine services and each PC's router
    // (a service of its launcher), nothing forged. A router can lose another PC's tokens
    // when a link comes back (docs/reliability.md); the fusion PC's launcher then asks their
    // services to declare them again, 3 s after it finds them missing. Once (2026-12-08, the
    // full suite) the fusion router dropped capture2's re-declared tokens again and again for
    // 17 s or more after the cable's return, each time asked for and renewed: all must be
    // seen together within 30 s.
    let end = Instant::now() + Duration::from_secs(30);
    let alive = loop {
        let alive = alive_tokens(&py(&["alive", FUSION, "lab", &ca, &cc, &ck]));
        if alive.len() >= 12 || Instant::now() >= end {
            break alive;
        }
        std::thread::sleep(Duration::from_millis(500));
    };
    let fusion_log = old_output(&launchers, "fusion");
    let asked: Vec<&str> = fusion_log
        .lines()
        .filter(|l| l.contains("asking it to declare it again"))
        .collect();
    eprintln!(
        "liveliness tokens renewed at the fusion PC's request: {}",
        asked.len()
    );
    for line in &asked {
        eprintln!("  {line}");
    }
    assert_eq!(alive.len(), 12, "{alive:?}\n{}", context());
    for pc in ["capture1", "capture2", "fusion"] {
        let router = format!("stereoscope/lab/alive/{pc}/router");
        assert!(alive.contains(&router), "{router} missing: {alive:?}");
    }
    assert!(
        !alive
            .iter()
            .any(|k| k.contains("FORGED") || k.ends_with("/x")),
        "{alive:?}"
    );
    // No service other than those killed restarted (the restarted launcher's may be retried
    // while the killed one's services end); every launcher is still up.
    for (host, log) in logs.iter().filter(|(h, _)| *h != "capture1") {
        for line in log.lines().filter(|l| l.contains("restarting in")) {
            assert!(
                kills
                    .iter()
                    .any(|(s, _)| line.contains(&format!(" {s} exited"))),
                "{host}: {line}\n{}",
                context()
            );
        }
    }
    for (host, mut p) in launchers {
        assert!(
            p.child.try_wait().unwrap().is_none(),
            "{host} launcher ended"
        );
        p.stop();
    }
    drop(watcher);
    // Nothing of the run is left in /dev/shm.
    let left: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(&format!("st{pid}")))
        .collect();
    assert!(left.is_empty(), "left in /dev/shm: {left:?}");
    let zenoh_left: Vec<String> = zenoh_segments()
        .difference(&zenoh_before)
        .cloned()
        .collect();
    assert!(
        zenoh_left.is_empty(),
        "Zenoh shared memory left in /dev/shm: {zenoh_left:?}"
    );
}
