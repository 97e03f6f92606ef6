//! Bundles the viewer's page at build time: `web/app.js` with three.js and its orbit
//! controls from npm (versions pinned by `web/package-lock.json`) into one minified module by
//! esbuild, which the binary then serves itself (nothing is fetched when the page runs).
//! Needs Node.js and npm, and the npm registry on the first build (npm's cache after).

use std::path::{Path, PathBuf};
use std::process::Command;

fn fail(what: &str) -> ! {
    eprintln!(
        "stereoscope-viewer: {what}. The viewer's page bundles three.js from npm at build \
         time: install Node.js (20 or later) and npm, with the npm registry reachable once"
    );
    std::process::exit(1)
}

fn run(cmd: &mut Command, what: &str) {
    match cmd.status() {
        Ok(s) if s.success() => {}
        Ok(s) => fail(&format!("{what} failed ({s})")),
        Err(e) => fail(&format!("{what} could not start: {e}")),
    }
}

fn copy(from: &Path, to: &Path) {
    if let Err(e) = std::fs::copy(from, to) {
        fail(&format!(
            "copying {} to {}: {e}",
            from.display(),
            to.display()
        ));
    }
}

fn main() {
    let manifest =
        std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| fail("no CARGO_MANIFEST_DIR"));
    let out = std::env::var("OUT_DIR").unwrap_or_else(|_| fail("no OUT_DIR"));
    let web = PathBuf::from(manifest).join("web");
    let out = PathBuf::from(out);
    for f in ["package.json", "package-lock.json", "app.js", "index.html"] {
        println!("cargo:rerun-if-changed=web/{f}");
    }
    // npm installs into the build's own folder, never into the source tree; again only when
    // the lock file changes.
    let npm_dir = out.join("npm");
    if let Err(e) = std::fs::create_dir_all(&npm_dir) {
        fail(&format!("making {}: {e}", npm_dir.display()));
    }
    let lock = std::fs::read(web.join("package-lock.json"))
        .unwrap_or_else(|e| fail(&format!("reading web/package-lock.json: {e}")));
    let stamp = npm_dir.join("installed-from.lock");
    if std::fs::read(&stamp).ok().as_ref() != Some(&lock)
        || !npm_dir.join("node_modules/.bin/esbuild").exists()
    {
        copy(&web.join("package.json"), &npm_dir.join("package.json"));
        copy(
            &web.join("package-lock.json"),
            &npm_dir.join("package-lock.json"),
        );
        run(
            Command::new("npm")
                .args([
                    "ci",
                    "--ignore-scripts",
                    "--no-audit",
                    "--no-fund",
                    "--loglevel=error",
                ])
                .current_dir(&npm_dir),
            "npm ci (three.js and esbuild)",
        );
        if let Err(e) = std::fs::write(&stamp, &lock) {
            fail(&format!("writing {}: {e}", stamp.display()));
        }
    }
    // Bundled from beside node_modules so that `import "three"` resolves to the pinned copy.
    copy(&web.join("app.js"), &npm_dir.join("app.js"));
    run(
        Command::new(npm_dir.join("node_modules/.bin/esbuild"))
            .arg("app.js")
            .args(["--bundle", "--minify", "--format=esm", "--target=es2020"])
            .arg("--log-level=warning")
            .arg(format!("--outfile={}", out.join("app.bundle.js").display()))
            .current_dir(&npm_dir),
        "esbuild (bundling web/app.js)",
    );
    copy(&web.join("index.html"), &out.join("index.html"));
}
