//! Helpers shared by the system tests: run the real binary with a time limit, reading its
//! output while it runs (a full pipe must never stall it), and a private temporary folder.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub const BIN: &str = env!("CARGO_BIN_EXE_stereoscope");

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A running `stereoscope` process whose output is collected; stopped and reaped on drop.
pub struct Proc {
    pub child: Child,
    out: Arc<Mutex<String>>,
}

impl Proc {
    pub fn start(args: &[&str]) -> Proc {
        Proc::start_program(Path::new(BIN), args, &[])
    }

    /// Any program, with extra environment variables.
    pub fn start_program(program: &Path, args: &[&str], env: &[(&str, &str)]) -> Proc {
        let mut child = spawn_piped(program, args, env);
        let out = Arc::new(Mutex::new(String::new()));
        for pipe in [
            Box::new(child.stdout.take().unwrap()) as Box<dyn Read + Send>,
            Box::new(child.stderr.take().unwrap()),
        ] {
            let out = out.clone();
            std::thread::spawn(move || {
                let mut pipe = pipe;
                let mut buf = [0u8; 4096];
                while let Ok(n) = pipe.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    out.lock()
                        .unwrap()
                        .push_str(&String::from_utf8_lossy(&buf[..n]));
                }
            });
        }
        Proc { child, out }
    }

    pub fn output(&self) -> String {
        self.out.lock().unwrap().clone()
    }

    /// Waits up to `limit` for `pred` on the output so far.
    pub fn wait_for(&self, limit: Duration, what: &str, pred: impl Fn(&str) -> bool) -> String {
        let end = Instant::now() + limit;
        loop {
            let o = self.output();
            if pred(&o) {
                return o;
            }
            if Instant::now() > end {
                panic!("{what} not seen within {limit:?}; output:\n{o}");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn stop(&mut self) {
        // SAFETY: signalling our own child.
        unsafe {
            libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM);
        }
        let end = Instant::now() + Duration::from_secs(8);
        while Instant::now() < end {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.stop();
    }
}

/// `program args` from the repository root, stdin empty, stdout and stderr piped.
fn spawn_piped(program: &Path, args: &[&str], env: &[(&str, &str)]) -> Child {
    Command::new(program)
        .args(args)
        .envs(env.iter().copied())
        .current_dir(repo_root())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", program.display()))
}

/// A fresh folder for one test, removed when dropped.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(name: &str) -> Self {
        let dir =
            std::env::temp_dir().join(format!("stereoscope-test-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    /// Writes `text` to `name` in the folder and returns the path as a string.
    pub fn file(&self, name: &str, text: &str) -> String {
        let p = self.0.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_string()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs `stereoscope ARGS` from the repository root; kills and reaps it after `limit`.
pub fn run_with_limit(args: &[&str], limit: Duration) -> Output {
    run_program_with_limit(Path::new(BIN), args, limit)
}

/// Runs any program from the repository root, its output read while it runs; kills and reaps
/// it after `limit`.
pub fn run_program_with_limit(program: &Path, args: &[&str], limit: Duration) -> Output {
    let mut child = spawn_piped(program, args, &[]);
    let reader = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut buf = Vec::new();
            let _ = pipe.read_to_end(&mut buf);
            buf
        })
    };
    let out = reader(Box::new(child.stdout.take().expect("stdout")));
    let err = reader(Box::new(child.stderr.take().expect("stderr")));
    let deadline = Instant::now() + limit;
    let status: ExitStatus = loop {
        if let Some(s) = child.try_wait().expect("wait") {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "{} {args:?} did not finish within {limit:?}",
                program.display()
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    Output {
        status,
        stdout: out.join().expect("stdout reader"),
        stderr: err.join().expect("stderr reader"),
    }
}

/// The Python interpreter of a virtual environment holding the PyPI packages of
/// `tests/clients/requirements.txt` (clients the project did not write), made once under
/// `target/` and reused while the requirements stay the same. Making it needs PyPI, or a
/// mirror named by pip's own `PIP_INDEX_URL` / `PIP_FIND_LINKS`; a failure says so.
pub fn python_clients() -> PathBuf {
    use std::sync::OnceLock;
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON
        .get_or_init(|| {
            let root = repo_root();
            let requirements = root.join("tests/clients/requirements.txt");
            let wanted = std::fs::read_to_string(&requirements).unwrap();
            let target = root.join("target");
            std::fs::create_dir_all(&target).unwrap();
            // One test binary at a time makes it (flock: released if the holder dies).
            let lock = std::fs::File::create(target.join("py-clients.lock")).unwrap();
            // SAFETY: flock on a file descriptor we own.
            assert_eq!(
                unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(&lock), libc::LOCK_EX) },
                0
            );
            let venv = target.join("py-clients");
            let python = venv.join("bin/python");
            let stamp = venv.join("requirements.installed");
            if std::fs::read_to_string(&stamp).ok().as_deref() == Some(wanted.as_str())
                && python.exists()
            {
                return python;
            }
            let _ = std::fs::remove_dir_all(&venv);
            let venv_s = venv.to_str().unwrap();
            let o = run_program_with_limit(
                Path::new("python3"),
                &["-m", "venv", venv_s],
                Duration::from_secs(120),
            );
            assert!(
                o.status.success(),
                "python3 -m venv {venv_s}: {}",
                stderr(&o)
            );
            let o = run_program_with_limit(
                &python,
                &[
                    "-m",
                    "pip",
                    "install",
                    "--disable-pip-version-check",
                    "--quiet",
                    "-r",
                    requirements.to_str().unwrap(),
                ],
                Duration::from_secs(600),
            );
            assert!(
                o.status.success(),
                "installing the Python clients from PyPI ({}) failed — this test needs PyPI or a \
                 mirror in PIP_INDEX_URL / PIP_FIND_LINKS:\n{}",
                requirements.display(),
                stderr(&o)
            );
            std::fs::write(&stamp, &wanted).unwrap();
            python
        })
        .clone()
}

/// [`run_with_limit`] with a minute.
pub fn run(args: &[&str]) -> Output {
    run_with_limit(args, Duration::from_secs(60))
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The demo rig (`deploy/rigs/demo.toml`) with its VR feed on free loopback ports of this
/// test's own instead of the protocols' fixed ones (VRPN 3883, VMT 39570, opentrack 4242), so
/// that tests running side by side never share a port.
pub fn demo_rig_on_own_ports() -> String {
    let demo = std::fs::read_to_string(repo_root().join("deploy/rigs/demo.toml"))
        .unwrap_or_else(|e| panic!("deploy/rigs/demo.toml: {e}"));
    own_vr_ports(&demo)
}

/// The demo rig's `[vr]` section, every protocol on its default port.
pub const DEMO_VR: &str =
    "[vr]\nvrpn = {}\nvmt = {}\nopentrack = {}\nnatnet = {}\nqualisys = {}\nros2 = {}\nlsl = {}\n";

/// `rig` with its `[vr]` section's default ports replaced by free loopback ports.
pub fn own_vr_ports(rig: &str) -> String {
    const DEFAULTS: &str = DEMO_VR;
    if !rig.contains(DEFAULTS) {
        assert!(
            !rig.contains("[vr]"),
            "the rig's [vr] section is not the demo's: give it ports of the test's own"
        );
        return rig.to_string();
    }
    let port = || {
        stereoscope_transport::net::free_loopback_port()
            .unwrap_or_else(|e| panic!("no free loopback port: {e}"))
    };
    rig.replace(
        DEFAULTS,
        &format!(
            "[vr]\nvrpn = {{ listen = \"127.0.0.1:{}\" }}\nvmt = {{ send_to = \"127.0.0.1:{}\" }}\nopentrack = {{ send_to = \"127.0.0.1:{}\" }}\nnatnet = {{ command = \"127.0.0.1:{}\", data_port = {} }}\nqualisys = {{ base = \"127.0.0.1:{}\" }}\nros2 = {{ router = \"tcp/127.0.0.1:{}\" }}\n",
            port(),
            port(),
            port(),
            port(),
            port(),
            // Clients connect to the port after the base.
            port() - 1,
            port()
        ),
    )
}

/// `deploy/make-certs.sh OUT NAMES...`: a test authority in `out` (reused when there) and a
/// certificate per `NAME[=ADDRESS,...]`.
pub fn make_certs(out: &Path, names: &[&str]) {
    let o = std::process::Command::new(repo_root().join("deploy/make-certs.sh"))
        .arg(out)
        .args(names)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
