//! The Python package (`python/`, `import fpm`): built with maturin into a virtual
//! environment from the same crates as the CLI, then its pytest suite
//! (python/tests/, which also runs examples/python_session.py) against the real USAF
//! data, simulated sets, and the `fpm` command for comparison.

use std::path::Path;
use std::process::Command;

use fpm_tests::{fpm_bin, python_venv};

#[test]
fn python_package_builds_and_its_tests_pass() {
    let workspace = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let python = python_venv(
        "python-package",
        &workspace.join("python/requirements-test.txt"),
    );
    let venv = python
        .parent()
        .and_then(Path::parent)
        .expect("target/python-package");
    // The dev profile builds the physics optimised (Cargo.toml), as the tests do.
    let build = Command::new(venv.join("bin/maturin"))
        .args(["develop", "--quiet", "-m"])
        .arg(workspace.join("python/Cargo.toml"))
        .env("VIRTUAL_ENV", venv)
        .output()
        .expect("running maturin");
    assert!(
        build.status.success(),
        "maturin develop failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let tests = Command::new(&python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider"])
        .arg(workspace.join("python/tests"))
        .env("FPM_BIN", fpm_bin())
        .current_dir(workspace)
        .output()
        .expect("running pytest");
    let report = String::from_utf8_lossy(&tests.stdout);
    println!("{report}");
    assert!(
        tests.status.success(),
        "pytest failed:\n{report}\n{}",
        String::from_utf8_lossy(&tests.stderr)
    );
    assert!(
        !report.contains("skipped"),
        "no test may be skipped here:\n{report}"
    );
}
