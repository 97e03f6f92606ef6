//! Real camera drivers. **V4L2** against the kernel's own virtual camera driver, `vivid`: this machine loads
//! no kernel module, so the test boots the Debian kernel under QEMU (TCG emulation), with a
//! busybox initramfs holding `vivid` and its dependencies from `/lib/modules`, the real
//! `stereoscope` binary and the C libraries it links. In the guest, `stereoscope grab` reads
//! the camera as a rig describes it (format, size, rate, controls by name) and prints what
//! the moment worker finds; the serial console brings that back. Two vivid instances: the
//! first a webcam, the second an HDMI input looped from its HDMI output, where the guest plays
//! a frame the renderer made on the host. Two small C helpers (`tests/guest/`), built
//! statically with the host's C compiler, press vivid's Disconnect and play that frame.
//!
//! Needs the Debian packages `qemu-system-x86` and `busybox-static`, gcc, and a Debian kernel
//! (`linux-image-amd64` installed, or unpacked into `target/vivid-kernel`): `.ci/run` sees to
//! all three; the test fails, naming them, without.
//!
//! **GenICam** through Aravis against Aravis's own GigE Vision camera emulator,
//! `arv-fake-gv-camera-0.8` (Debian `aravis-tools`), on loopback: `stereoscope grab` opens it as
//! a rig describes it and the moment worker reads its frames. The emulator answers on GigE
//! Vision's control port, 3956, fixed by the protocol: no other test uses it.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test helpers may fail loudly

use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The newest Debian kernel with the vivid module, and its modules folder: installed, or
/// unpacked from its package into `target/vivid-kernel` (what `.ci/run` does).
fn kernel() -> (PathBuf, PathBuf) {
    let unpacked = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/vivid-kernel");
    let mut found: Vec<(PathBuf, PathBuf)> = [PathBuf::from("/"), unpacked]
        .iter()
        .flat_map(|root| {
            std::fs::read_dir(root.join("boot"))
                .into_iter()
                .flatten()
                .flatten()
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().to_string();
                    let version = name.strip_prefix("vmlinuz-")?.to_string();
                    let modules = root.join("lib/modules").join(&version);
                    modules
                        .join("kernel/drivers/media/test-drivers/vivid/vivid.ko")
                        .exists()
                        .then_some((e.path(), modules))
                })
                .collect::<Vec<_>>()
        })
        .collect();
    found.sort();
    found.pop().unwrap_or_else(|| {
        panic!(
            "this test needs a Debian kernel with the vivid module: install the package \
             `linux-image-amd64`, or unpack it into target/vivid-kernel (.ci/run does: \
             `apt-get download` and `dpkg-deb -x`)"
        )
    })
}

fn need(tool: &str, package: &str) -> PathBuf {
    std::env::var_os("PATH")
        .and_then(|p| {
            std::env::split_paths(&p)
                .map(|d| d.join(tool))
                .find(|p| p.exists())
        })
        .unwrap_or_else(|| {
            panic!("this test needs {tool}: install the Debian package `{package}` (.ci/run does)")
        })
}

/// A `newc` cpio archive, as the kernel unpacks an initramfs.
struct Cpio {
    out: Vec<u8>,
    ino: u32,
}

impl Cpio {
    fn entry(&mut self, name: &str, mode: u32, data: &[u8]) {
        self.ino += 1;
        let header = format!(
            "070701{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}{:08x}",
            self.ino,
            mode,
            0,
            0,
            1,
            0,
            data.len(),
            0,
            0,
            0,
            0,
            name.len() + 1,
            0
        );
        self.out.extend_from_slice(header.as_bytes());
        self.out.extend_from_slice(name.as_bytes());
        self.out.push(0);
        while !self.out.len().is_multiple_of(4) {
            self.out.push(0);
        }
        self.out.extend_from_slice(data);
        while !self.out.len().is_multiple_of(4) {
            self.out.push(0);
        }
    }
    fn dir(&mut self, name: &str) {
        self.entry(name, 0o040755, &[]);
    }
    fn file(&mut self, name: &str, data: &[u8], exec: bool) {
        self.entry(name, if exec { 0o100755 } else { 0o100644 }, data);
    }
    fn link(&mut self, name: &str, target: &str) {
        self.entry(name, 0o120777, target.as_bytes());
    }
    fn finish(mut self) -> Vec<u8> {
        self.entry("TRAILER!!!", 0, &[]);
        self.out
    }
}

/// Every parent folder of `path` not yet in the archive.
fn parents(cpio: &mut Cpio, made: &mut std::collections::BTreeSet<String>, path: &str) {
    let mut at = String::new();
    let parts: Vec<&str> = path.split('/').filter(|s| !s.is_empty()).collect();
    for p in &parts[..parts.len().saturating_sub(1)] {
        if !at.is_empty() {
            at.push('/');
        }
        at.push_str(p);
        if made.insert(at.clone()) {
            cpio.dir(&at);
        }
    }
}

/// A module's `depends=` (its `.modinfo` entry: the modules it needs, by name).
fn depends(module: &Path) -> Vec<String> {
    let bytes = std::fs::read(module).unwrap();
    let key = b"depends=";
    let Some(at) = bytes.windows(key.len()).position(|w| w == key) else {
        return Vec::new();
    };
    let rest = &bytes[at + key.len()..];
    let end = rest.iter().position(|&b| b == 0).unwrap_or(rest.len());
    String::from_utf8_lossy(&rest[..end])
        .split(',')
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect()
}

/// vivid and every module it needs, each after its own needs: from each module's `depends=`
/// (what depmod reads), so an unpacked kernel package without `modules.dep` serves as well.
fn load_order(modules: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut std::collections::BTreeMap<String, PathBuf>) {
        for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if let Some(stem) = p
                .file_name()
                .and_then(|n| n.to_str())
                .and_then(|n| n.strip_suffix(".ko"))
            {
                out.insert(stem.replace('-', "_"), p);
            }
        }
    }
    fn visit(
        name: &str,
        all: &std::collections::BTreeMap<String, PathBuf>,
        done: &mut Vec<PathBuf>,
    ) {
        let path = all
            .get(&name.replace('-', "_"))
            .unwrap_or_else(|| panic!("module {name} is not in the kernel's modules"));
        if done.contains(path) {
            return;
        }
        for d in depends(path) {
            visit(&d, all, done);
        }
        done.push(path.clone());
    }
    let mut all = std::collections::BTreeMap::new();
    walk(&modules.join("kernel"), &mut all);
    let mut done = Vec::new();
    visit("vivid", &all, &mut done);
    done
}

/// The shared libraries `binary` loads, by `ldd`.
fn libraries(binary: &Path) -> Vec<PathBuf> {
    let out = Command::new("ldd")
        .arg(binary)
        .output()
        .expect("running ldd");
    String::from_utf8_lossy(&out.stdout)
        .split_whitespace()
        .filter(|w| w.starts_with('/'))
        .map(PathBuf::from)
        .collect()
}

/// A camera section of a rig for vivid's capture device.
fn rig(size: [u32; 2], source: &str) -> String {
    format!(
        "name = \"vivid\"\nunits = \"mm\"\n\n[[camera]]\nid = \"cam0\"\nimage_size = [{}, {}]\n\
         focal_length_mm = 4.0\npixel_pitch_um = [3.0, 3.0]\n\
         pose = {{ position = [0.0, 0.0, 2000.0], look_at = [0.0, 0.0, 0.0], up = [0.0, 1.0, 0.0] }}\n\
         source = {source}\nmoments = {{ threshold = \"auto\", max_objects = 10 }}\n",
        size[0], size[1]
    )
}

/// A helper of `tests/guest/` (`v4l2_button`: presses a V4L2 button control by name, vivid's
/// "Disconnect"; `v4l2_out`: plays a PGM on a V4L2 output device), built statically with the
/// host's C compiler for the guest.
fn guest_helper(name: &str) -> Vec<u8> {
    let cc = need("cc", "gcc");
    let dir = std::env::temp_dir().join(format!("stsc-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join(name);
    let source = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/guest")
        .join(format!("{name}.c"));
    let o = Command::new(cc)
        .args(["-static", "-O2", "-o"])
        .arg(&out)
        .arg(&source)
        .output()
        .expect("running cc");
    assert!(
        o.status.success(),
        "building {}: {}",
        source.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let bytes = std::fs::read(&out).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    bytes
}

/// Boots the guest with `runs` (name, rig text, grab arguments, shell commands run beside the
/// grab from its start) and returns each run's output and exit status.
fn boot(
    runs: &[(&str, String, &str, &str)],
    files: &[(&str, Vec<u8>)],
) -> Vec<(String, String, i32)> {
    let qemu = need("qemu-system-x86_64", "qemu-system-x86");
    let busybox = ["/usr/bin/busybox", "/bin/busybox"]
        .into_iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
        .unwrap_or_else(|| {
            panic!("this test needs busybox: install the Debian package `busybox-static`")
        });
    let linked = Command::new("ldd")
        .arg(&busybox)
        .output()
        .expect("running ldd");
    assert!(
        !linked.status.success(),
        "{} is linked dynamically; the guest needs the static one: install the Debian package \
         `busybox-static`",
        busybox.display()
    );
    let (vmlinuz, modules) = kernel();
    let binary = PathBuf::from(env!("CARGO_BIN_EXE_stereoscope"));

    let mut cpio = Cpio {
        out: Vec::new(),
        ino: 0,
    };
    let mut made = std::collections::BTreeSet::new();
    for d in ["bin", "dev", "proc", "sys", "tmp", "lib", "modules", "rigs"] {
        made.insert(d.to_string());
        cpio.dir(d);
    }
    cpio.file("bin/busybox", &std::fs::read(&busybox).unwrap(), true);
    for tool in [
        "sh", "mount", "insmod", "sleep", "poweroff", "echo", "killall",
    ] {
        cpio.link(&format!("bin/{tool}"), "busybox");
    }
    // vivid after what it needs, in load order.
    for (i, m) in load_order(&modules).iter().enumerate() {
        let name = m.file_name().unwrap().to_string_lossy();
        cpio.file(
            &format!("modules/{i:02}-{name}"),
            &std::fs::read(m).unwrap(),
            false,
        );
    }
    cpio.file("bin/stereoscope", &std::fs::read(&binary).unwrap(), true);
    cpio.file("bin/v4l2-button", &guest_helper("v4l2_button"), true);
    cpio.file("bin/v4l2-out", &guest_helper("v4l2_out"), true);
    for (path, bytes) in files {
        parents(&mut cpio, &mut made, path);
        cpio.file(path, bytes, false);
    }
    for lib in libraries(&binary) {
        let inside = lib.to_string_lossy().trim_start_matches('/').to_string();
        parents(&mut cpio, &mut made, &inside);
        let bytes = std::fs::read(&lib).unwrap_or_else(|e| panic!("{}: {e}", lib.display()));
        cpio.file(&inside, &bytes, true);
    }
    let mut init = String::from(
        "#!/bin/sh\nmount -t proc proc /proc\nmount -t sysfs sys /sys\nmount -t devtmpfs dev /dev\n\
         for m in /modules/*.ko; do\n  case $m in *vivid.ko) insmod $m n_devs=2 node_types=0x1,0x101 num_inputs=4,1 \
         input_types=0xe4,0x3 num_outputs=2,1 output_types=0x2,0x1 ;; \
         *) insmod $m ;; esac\ndone\nn=0\nwhile [ ! -e /dev/video0 ] && [ $n -lt 100 ]; do sleep 0.1; \
         n=$((n+1)); done\n",
    );
    for (name, text, args, during) in runs {
        cpio.file(&format!("rigs/{name}.toml"), text.as_bytes(), false);
        let beside = if during.is_empty() {
            String::new()
        } else {
            format!("( {during} ) &\n")
        };
        init.push_str(&format!(
            "echo '@@ begin {name}'\n{beside}/bin/stereoscope grab /rigs/{name}.toml --camera cam0 {args} /tmp/{name} 2>&1\necho \"@@ end {name} $?\"\nwait\n"
        ));
    }
    init.push_str("poweroff -f\n");
    cpio.file("init", init.as_bytes(), true);
    let dir = std::env::temp_dir().join(format!("stereoscope-vivid-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let initrd = dir.join("initrd.cpio");
    std::fs::write(&initrd, cpio.finish()).unwrap();

    let mut child = Command::new(qemu)
        .args([
            "-accel",
            "tcg",
            "-m",
            "1024",
            "-smp",
            "1",
            "-nographic",
            "-no-reboot",
        ])
        .arg("-kernel")
        .arg(&vmlinuz)
        .arg("-initrd")
        .arg(&initrd)
        .args(["-append", "console=ttyS0 quiet panic=-1"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting qemu-system-x86_64");
    // Bounded: the guest powers off when its runs are done (about 10 s here); 180 s allows a
    // loaded machine.
    let mut stdout = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut all = Vec::new();
        let _ = stdout.read_to_end(&mut all);
        all
    });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if start.elapsed() > Duration::from_secs(180) {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let console = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut stderr);
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        status.is_some(),
        "the guest did not power off in 180 s; its console:\n{console}\n{stderr}"
    );
    let _ = std::io::stderr().write_all(console.as_bytes());
    runs.iter()
        .map(|(name, _, _, _)| {
            let begin = format!("@@ begin {name}");
            let end = format!("@@ end {name} ");
            let a = console
                .find(&begin)
                .unwrap_or_else(|| panic!("run {name} did not start; console:\n{console}"));
            let b = console[a..]
                .find(&end)
                .map(|b| a + b)
                .unwrap_or_else(|| panic!("run {name} did not end; console:\n{console}"));
            let code: i32 = console[b + end.len()..]
                .split_whitespace()
                .next()
                .and_then(|c| c.parse().ok())
                .unwrap_or(-1);
            (
                name.to_string(),
                console[a + begin.len()..b].replace('\r', ""),
                code,
            )
        })
        .collect()
}

/// A guest shell line that waits (bounded, 60 s of guest time) until run `name`'s grab has
/// saved its `frame`th frame, then runs `then`: a fault injected while the camera streams,
/// however slowly the emulated guest starts the grab on a loaded machine.
fn after_frame(name: &str, frame: u32, then: &str) -> String {
    format!(
        "n=0; while [ ! -e /tmp/{name}/cam0-{frame:04}.pgm ] && [ $n -lt 1200 ]; do sleep 0.05; \
         n=$((n+1)); done; {then}"
    )
}

/// The frames' (camera frame number, ms after the first) from grab's lines.
fn frames(out: &str) -> Vec<(u64, f64)> {
    out.lines()
        .filter_map(|l| {
            let seq = l.split("camera's frame ").nth(1)?.split(',').next()?;
            let ms = l.split("exposed ").nth(1)?.split(" ms").next()?;
            Some((seq.parse().ok()?, ms.parse().ok()?))
        })
        .collect()
}

/// The camera's stamps, not the reader's: between two frames, as many periods as their
/// frame numbers are apart. vivid stamps a frame when its thread fills it, which in the
/// emulated guest is late by up to 19 ms in the stream's first three frames (measured:
/// intervals of 52 ms there, the driver skipping a frame number) and after them by up to 3 ms
/// on an idle machine, 8.8 ms while the whole test suite loads both cores; the bound below is
/// 12 ms from the fourth frame on — a third of a period at 30 fps, where a reader's own stamps
/// after a stall would be a period off — and the numbers must rise.
fn stamps_follow_frame_numbers(f: &[(u64, f64)], fps: f64, out: &str) {
    for w in f.windows(2) {
        assert!(
            w[1].0 > w[0].0 && w[1].1 > w[0].1,
            "numbers or time went back: {out}"
        );
    }
    for w in f[3..].windows(2) {
        let periods = (w[1].0 - w[0].0) as f64;
        let ms = w[1].1 - w[0].1;
        assert!(
            (ms - periods * 1000.0 / fps).abs() < 12.0,
            "frames {} and {}: {ms} ms apart: {out}",
            w[0].0,
            w[1].0
        );
    }
}

#[test]
fn vivid_frames_stamps_and_controls() {
    // The renderer's frame of three still markers at 1280 × 720, and the blobs the moment worker
    // finds in it here: the guest plays it on vivid's HDMI output, which vivid loops to its
    // HDMI input.
    let host = std::env::temp_dir().join(format!("stsc-vivid-scene-{}", std::process::id()));
    std::fs::create_dir_all(&host).unwrap();
    let scene = format!(
        "{}\n[synthetic]\nseed = 3\nnoise_sigma = 2.0\nbackground = 20.0\n\
         [[synthetic.target]]\nshape = \"sphere\"\nradius = 12.0\nmotion = {{ kind = \"static\", position = [-150.0, 40.0, 0.0] }}\n\
         [[synthetic.target]]\nshape = \"sphere\"\nradius = 12.0\nmotion = {{ kind = \"static\", position = [90.0, -60.0, 0.0] }}\n\
         [[synthetic.target]]\nshape = \"sphere\"\nradius = 12.0\nmotion = {{ kind = \"static\", position = [200.0, 120.0, 0.0] }}\n",
        rig([1280, 720], "{ kind = \"synthetic\", fps = 30.0 }")
    );
    let o = grab(&host, &scene, &["--count", "1"]);
    let rendered = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{rendered}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let pgm = std::fs::read(host.join("cam0-0001.pgm")).unwrap();
    let _ = std::fs::remove_dir_all(&host);
    let square = "test_pattern = \"100% Black\", osd_text_mode = \"None\", show_square = true";
    // vivid's square at 640 × 360 and 30 fps in `format`.
    let square_at_30 = |format: &str| {
        rig(
            [640, 360],
            &format!(
                "{{ kind = \"v4l\", device = \"/dev/video0\", format = \"{format}\", fps = 30.0, \
                 controls = {{ {square} }} }}"
            ),
        )
    };
    let runs = boot(
        &[
            (
                "grey",
                rig(
                    [640, 360],
                    &format!(
                        "{{ kind = \"v4l\", device = \"/dev/video0\", format = \"GREY\", fps = 30.0, \
                     readout_us = 4000.0, controls = {{ {square} }} }}"
                    ),
                ),
                "--count 15 --every 0",
                "",
            ),
            (
                "yuyv",
                rig(
                    [1280, 720],
                    &format!(
                        "{{ kind = \"v4l\", device = \"/dev/video0\", format = \"YUYV\", fps = 12.5, \
                     controls = {{ {square}, timestamp_source = \"Start of Exposure\", \
                     percentage_of_dropped_buffers = 50 }} }}"
                    ),
                ),
                "--count 15 --every 0",
                "",
            ),
            (
                "badcontrol",
                rig(
                    [640, 360],
                    "{ kind = \"v4l\", device = \"/dev/video0\", controls = { brightness = 9999 } }",
                ),
                "--count 1",
                "",
            ),
            (
                "badrate",
                rig(
                    [1280, 720],
                    "{ kind = \"v4l\", device = \"/dev/video0\", fps = 30.0 }",
                ),
                "--count 1",
                "",
            ),
            (
                "nocontrol",
                rig(
                    [640, 360],
                    "{ kind = \"v4l\", device = \"/dev/video0\", controls = { focus_absolute = 3 } }",
                ),
                "--count 1",
                "",
            ),
            ("y16", square_at_30("Y16"), "--count 5 --every 0", ""),
            (
                "stall",
                square_at_30("GREY"),
                "--count 40 --every 0",
                &after_frame(
                    "stall",
                    5,
                    "killall -STOP stereoscope; sleep 1.5; killall -CONT stereoscope",
                ),
            ),
            (
                "unplug",
                square_at_30("GREY"),
                "--count 60 --every 0",
                &after_frame("unplug", 20, "/bin/v4l2-button /dev/video0 disconnect"),
            ),
            (
                "loop",
                rig(
                    [1280, 720],
                    "{ kind = \"v4l\", device = \"/dev/video1\", format = \"YUYV\", \
                 controls = { osd_text_mode = \"None\", loop_video = true } }",
                ),
                "--count 3 --every 0.5",
                "/bin/v4l2-out /dev/video2 /frames/scene.pgm 150 30",
            ),
        ],
        &[("frames/scene.pgm", pgm)],
    );
    let blob_lines = |text: &str| -> Vec<String> {
        text.lines()
            .filter(|l| l.starts_with("blob "))
            .map(str::to_string)
            .collect()
    };
    let on_host = blob_lines(&rendered);
    assert_eq!(on_host.len(), 3, "{rendered}");
    let out = |name: &str| {
        runs.iter()
            .find(|r| r.0 == name)
            .map(|r| (r.1.clone(), r.2))
            .unwrap()
    };

    // GREY at 640 × 360: the driver named, the size and rate the rig asked for, the driver's
    // end-of-frame stamps (vivid has no exposure control) less the readout the rig gives,
    // every frame numbered in turn, and vivid's square (256 × 256, centred) found where it is
    // drawn.
    let (grey, code) = out("grey");
    assert_eq!(code, 0, "{grey}");
    assert!(
        grey.contains("v4l2 /dev/video0 (vivid: vivid) Grey 640×360 30.0 fps"),
        "{grey}"
    );
    assert!(
        grey.contains("the driver's end of frame stamp (exposure unknown) less 4.00 ms readout"),
        "{grey}"
    );
    assert!(
        grey.contains("centroid (319.50, 179.50) px, area 65536 px²"),
        "{grey}"
    );
    let f = frames(&grey);
    assert_eq!(f.len(), 15, "{grey}");
    stamps_follow_frame_numbers(&f, 30.0, &grey);

    // YUYV at 1280 × 720 (vivid's webcam gives it at 12.5 fps), start-of-exposure stamps, half the buffers dropped by the driver:
    // the luma gives the same square, scaled; the drops show as gaps in the frame numbers
    // with the time between frames their multiples.
    let (yuyv, code) = out("yuyv");
    assert_eq!(code, 0, "{yuyv}");
    assert!(yuyv.contains("Yuyv 1280×720 12.5 fps"), "{yuyv}");
    assert!(
        yuyv.contains("the driver's start of exposure stamp (exposure unknown)"),
        "{yuyv}"
    );
    assert!(yuyv.contains("centroid (639.50, 359.50) px"), "{yuyv}");
    let f = frames(&yuyv);
    assert_eq!(f.len(), 15, "{yuyv}");
    let gaps = f.windows(2).filter(|w| w[1].0 > w[0].0 + 1).count();
    assert!(
        gaps >= 3,
        "too few frame numbers skipped with 50 % dropped: {yuyv}"
    );
    stamps_follow_frame_numbers(&f, 12.5, &yuyv);

    // A control the camera has, outside its range; a control it lacks: named, with what the
    // camera has, and no frame read.
    let (bad, code) = out("badcontrol");
    assert_ne!(code, 0, "{bad}");
    assert!(
        bad.contains("control brightness: 9999 is outside the control's 0 to 255"),
        "{bad}"
    );
    let (rate, code) = out("badrate");
    assert_ne!(code, 0, "{rate}");
    assert!(
        rate.contains("/dev/video0: the camera gives 12.5 fps at 1280×720, not the 30 fps asked"),
        "{rate}"
    );
    let (none, code) = out("nocontrol");
    assert_ne!(code, 0, "{none}");
    assert!(
        none.contains("control focus_absolute: the camera has no such control")
            && none.contains("\"show_square\""),
        "{none}"
    );

    // Y16: vivid's 16-bit grey, read as 16-bit frames; the square found as in GREY.
    let (y16, code) = out("y16");
    assert_eq!(code, 0, "{y16}");
    assert!(y16.contains("Y16 640×360 30.0 fps"), "{y16}");
    assert!(
        y16.contains("centroid (319.50, 179.50) px, area 65536 px²"),
        "{y16}"
    );

    // A consumer that stops reading for 1.5 s (the grab stopped by a signal once it has saved
    // five frames): the driver fills the four buffers queued and drops the frames after them,
    // so the frames read after carry the driver's stamps, as many periods apart as their
    // numbers across the stall — not the burst of their late reading. In the emulated guest
    // vivid's own thread skips frame numbers when it runs late (intervals of 3–7 periods
    // while the grab reads, on a loaded machine), so the frames filled during the stall are
    // not consecutive and the stall shows as stamps: some six intervals in a row (the four
    // buffers and the frames in hand on either side) span more than 1.2 s, where the reading
    // alone spans about 0.4 s.
    let (stall, code) = out("stall");
    assert_eq!(code, 0, "{stall}");
    let f = frames(&stall);
    assert_eq!(f.len(), 40, "{stall}");
    let widest_ms = f.windows(7).map(|w| w[6].1 - w[0].1).fold(0.0f64, f64::max);
    assert!(
        widest_ms > 1200.0,
        "no six intervals span the reader's 1.5 s stall ({widest_ms} ms at most): {stall}"
    );
    stamps_follow_frame_numbers(&f, 30.0, &stall);

    // The renderer's frame played on vivid's HDMI output and looped to its HDMI input: read
    // through the V4L2 source, YUYV at vivid's 720p60, the moment worker finds the very blobs
    // it finds in the rendered frame on the host — centroids, areas and orientations to the
    // printed digit (the last frame's, 1 s in; the frame 0.5 s in has the same three).
    let (looped, code) = out("loop");
    assert_eq!(code, 0, "{looped}");
    assert!(
        looped.contains("/dev/video1 (vivid: vivid) Yuyv 1280×720 60.0 fps"),
        "{looped}"
    );
    assert_eq!(
        blob_lines(&looped),
        on_host,
        "{looped}\non the host:\n{rendered}"
    );
    assert!(looped.matches(", 3 blobs)").count() >= 2, "{looped}");

    // Unplugged while streaming (vivid's Disconnect pressed by another process once 20 frames are saved):
    // the reads say the camera is gone and it is being opened again, the device comes back
    // once nothing holds it, and the same grab reads on to its 60 frames, their numbers going
    // on from the last before the loss by the frame periods it was away.
    let (unplug, code) = out("unplug");
    assert_eq!(code, 0, "{unplug}");
    assert!(unplug.contains("pressed Disconnect"), "{unplug}");
    assert!(
        unplug.contains("skipped a frame: /dev/video0:")
            && unplug.contains("opening the camera again"),
        "{unplug}"
    );
    let f = frames(&unplug);
    assert_eq!(f.len(), 60, "{unplug}");
    assert!(
        f.windows(2).all(|w| w[1].0 > w[0].0),
        "frame numbers went back: {unplug}"
    );
    // The second or so the camera was away is a gap of as many frame periods.
    let (gap, ms) = f
        .windows(2)
        .map(|w| (w[1].0 - w[0].0, w[1].1 - w[0].1))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    assert!(
        ms > 500.0 && (gap as f64 - ms / (1000.0 / 30.0)).abs() <= 1.0,
        "{gap} frame numbers over the {ms} ms the camera was away: {unplug}"
    );
}

/// Starts Aravis's fake GigE Vision camera on loopback (serial `serial`), reaped on drop.
struct FakeCamera(std::process::Child);

impl FakeCamera {
    fn start(serial: &str, lost_per_thousand: u32) -> FakeCamera {
        let bin = need("arv-fake-gv-camera-0.8", "aravis-tools");
        let child = Command::new(bin)
            .args(["-i", "127.0.0.1", "-s", serial])
            .args(["-r", &lost_per_thousand.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        FakeCamera(child)
    }
}

impl Drop for FakeCamera {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `stereoscope grab` on `rig_text`, retried (bounded) while the emulator is still starting.
fn grab(dir: &Path, rig_text: &str, args: &[&str]) -> std::process::Output {
    let rig = dir.join("rig.toml");
    std::fs::write(&rig, rig_text).unwrap();
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        let mut all = vec!["grab", rig.to_str().unwrap(), "--camera", "cam0"];
        all.extend_from_slice(args);
        all.push(dir.to_str().unwrap());
        let o = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
            .args(&all)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        // The emulator not answering yet: "no such camera" / a timeout opening it.
        if o.status.success() || Instant::now() > end || !err.contains("opening") {
            return o;
        }
        std::thread::sleep(Duration::from_millis(300));
    }
}

#[test]
fn genicam_frames_from_aravis_fake_camera() {
    let dir = std::env::temp_dir().join(format!("stsc-genicam-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let _camera = FakeCamera::start("STSC1", 0);
    let source = "{ kind = \"genicam\", camera = \"127.0.0.1\", fps = 20.0, exposure_us = 2000.0 }";
    let o = grab(
        &dir,
        &rig([512, 512], source),
        &["--count", "5", "--every", "0.1"],
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    // The camera as the rig asked: 8-bit, 512 × 512, 20 fps, 2 ms exposure.
    assert!(
        out.contains("genicam 127.0.0.1 Gray8 512×512 20") && out.contains("exposure 2000 µs"),
        "{out}"
    );
    // Its frame numbers rise, and so do its stamps, from the camera's clock: the emulator is a
    // process that runs late when the machine is busy (measured: a frame 100 ms late while
    // CI builds), so a frame is never stamped earlier than its period after the one before,
    // and never more than half a second later — stamps taken when frames are read would bunch
    // buffers read together. The first saved frames are left out: the camera's clock is mapped
    // by the smallest transfer seen so far, which the first frames overestimate.
    let f = frames(&out);
    assert_eq!(f.len(), 5, "{out}");
    assert!(f.windows(2).all(|w| w[1].0 > w[0].0), "{out}");
    for w in f[2..].windows(2) {
        let periods = w[1].0.saturating_sub(w[0].0) as f64;
        let ms = w[1].1 - w[0].1;
        assert!(
            periods >= 1.0 && ms >= periods * 50.0 - 8.0 && ms <= periods * 50.0 + 500.0,
            "frames {} and {}: {ms} ms apart: {out}",
            w[0].0,
            w[1].0
        );
    }
    // The emulator's test pattern (bright squares drifting over a gradient): blobs the moment
    // worker finds in every frame.
    assert_eq!(
        out.lines()
            .filter(|l| l.contains("camera's frame") && !l.contains(", 0 blobs)"))
            .count(),
        5,
        "{out}"
    );
    let pgm = std::fs::read(dir.join("cam0-0001.pgm")).unwrap();
    assert!(pgm.starts_with(b"P5\n512 512\n255\n"), "{:?}", &pgm[..16]);

    // The exposure reaches the sensor: the emulator's image scales with it, and at 0.5 ms
    // nothing stands over the threshold.
    let dim = source.replace("2000.0", "500.0");
    let o = grab(
        &dir,
        &rig([512, 512], &dim),
        &["--count", "2", "--every", "0.1"],
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success() && out.contains("exposure 500 µs"),
        "{out}"
    );
    assert_eq!(out.matches(", 0 blobs)").count(), 2, "{out}");

    // Mono16: 16-bit frames (a 16-bit PGM), blobs found on the 16-bit threshold.
    let mono16 = source.replace("fps = 20.0", "fps = 20.0, format = \"Mono16\"");
    let o = grab(
        &dir,
        &rig([512, 512], &mono16),
        &["--count", "2", "--every", "0.1"],
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success() && out.contains("genicam 127.0.0.1 Gray16 512×512"),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!out.contains(", 0 blobs)"), "{out}");
    let pgm = std::fs::read(dir.join("cam0-0001.pgm")).unwrap();
    assert!(pgm.starts_with(b"P5\n512 512\n65535\n"), "{:?}", &pgm[..18]);

    // Triggers. A hardware line: the camera waits for a pulse that never comes (the emulator
    // has no line); grab says so while it waits, and gives up after 5 s. The software trigger fired by the capture at 5 fps
    // (the emulator in trigger mode otherwise paces itself at 25 Hz, or at the line's pulses:
    // none): frames come 200 ms apart. "free" turns every trigger off again. A source the camera
    // lacks is refused with the ones it has.
    let triggered = |t: &str| {
        source
            .replace("fps = 20.0", "fps = 5.0")
            .replace(" }", &format!(", trigger = \"{t}\" }}"))
    };
    std::fs::write(dir.join("line.toml"), rig([512, 512], &triggered("Line0"))).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
        .args(["grab", dir.join("line.toml").to_str().unwrap()])
        .args(["--camera", "cam0", "--count", "1"])
        .arg(dir.to_str().unwrap())
        .output()
        .unwrap();
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(
        !o.status.success() && out.contains("it waits for its trigger on Line0"),
        "{out}{err}"
    );
    let o = grab(
        &dir,
        &rig([512, 512], &triggered("Software")),
        &["--count", "4", "--every", "0.5"],
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success() && out.contains("software trigger at 5 fps"),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let f = frames(&out);
    assert_eq!(f.len(), 4, "{out}");
    for w in f[1..].windows(2) {
        let per_frame = (w[1].1 - w[0].1) / (w[1].0 - w[0].0) as f64;
        assert!(
            (150.0..300.0).contains(&per_frame),
            "{per_frame} ms a frame: {out}"
        );
    }
    let o = grab(
        &dir,
        &rig([512, 512], &triggered("free")),
        &["--count", "2", "--every", "0.1"],
    );
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success() && out.contains("free-running"), "{out}");
    std::fs::write(dir.join("line7.toml"), rig([512, 512], &triggered("Line7"))).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
        .args(["grab", dir.join("line7.toml").to_str().unwrap()])
        .args(["--camera", "cam0", "--count", "1"])
        .arg(dir.to_str().unwrap())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains(
                "setting TriggerSource Line7: the camera's trigger sources are Line0, Software"
            ),
        "{err}"
    );

    // A camera that is not there: the error names the rig's camera and the device asked for.
    let rig_file = dir.join("missing.toml");
    std::fs::write(
        &rig_file,
        rig(
            [512, 512],
            "{ kind = \"genicam\", camera = \"Aravis-NoSuch-0\" }",
        ),
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
        .args(["grab", rig_file.to_str().unwrap(), "--camera", "cam0"])
        .arg(dir.to_str().unwrap())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("cam0") && err.contains("Aravis-NoSuch-0") && err.lines().count() <= 3,
        "{err}"
    );
    drop(_camera);

    // The capture service on the emulator losing 2 packets in a thousand, killed and started
    // again mid-stream: incomplete frames are counted and dropped, the camera is opened again
    // and frames resume in the same process, its numbers going on.
    let lossy = FakeCamera::start("STSC2", 2);
    let router = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let run_rig = dir.join("run.toml");
    std::fs::write(
        &run_rig,
        format!(
            "{}\n[[host]]\nname = \"pc\"\nzenoh_listen = [\"tcp/127.0.0.1:{router}\"]\niceoryx2_prefix = \"stsc_gc{}_\"\n",
            rig([512, 512], source),
            std::process::id()
        ),
    )
    .unwrap();
    let mut launcher = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
        .args(["run", run_rig.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let capture = || -> Option<serde_json::Value> {
        let o = Command::new(env!("CARGO_BIN_EXE_stereoscope"))
            .args(["status", run_rig.to_str().unwrap(), "--json"])
            .output()
            .ok()?;
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).ok()?;
        v["services"]
            .as_array()?
            .iter()
            .find(|s| s["service"] == "capture/cam0")
            .map(|s| s["health"].clone())
    };
    let wait = |what: &str, pred: &dyn Fn(&serde_json::Value) -> bool| -> serde_json::Value {
        let end = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(h) = capture().filter(|h| pred(h)) {
                return h;
            }
            assert!(
                Instant::now() < end,
                "capture never {what}: {:?}",
                capture()
            );
            std::thread::sleep(Duration::from_millis(300));
        }
    };
    let n = |h: &serde_json::Value, k: &str| h[k].as_u64().unwrap_or(0);
    let bad = |h: &serde_json::Value| {
        h["detail"]["rejected.bad_frame"]
            .as_str()
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or(0)
    };
    let before = wait("processed 40 frames and dropped an incomplete one", &|h| {
        n(h, "processed") >= 40 && bad(h) > 0
    });
    drop(lossy);
    let lost = wait("noticed the camera gone", &|h| {
        h["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("opening the camera again"))
    });
    let _back = FakeCamera::start("STSC2", 0);
    let after = wait("resumed", &|h| {
        n(h, "processed") >= n(&lost, "processed") + 40
    });
    assert_eq!(
        n(&after, "pid"),
        n(&before, "pid"),
        "the capture service was restarted: {after:?}"
    );
    // Stopped as a user stops it (SIGTERM: the launcher stops its services), then reaped.
    // SAFETY: signalling a child this test started and has not reaped.
    unsafe {
        libc::kill(launcher.id() as i32, libc::SIGTERM);
    }
    let end = Instant::now() + Duration::from_secs(15);
    while launcher.try_wait().unwrap().is_none() {
        if Instant::now() > end {
            let _ = launcher.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut log = String::new();
    if let Some(mut e) = launcher.stderr.take() {
        let _ = e.read_to_string(&mut log);
    }
    let _ = launcher.wait();
    assert!(!log.contains("restarting"), "{log}");
    let _ = std::fs::remove_dir_all(&dir);
}
