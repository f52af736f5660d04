//! The Python package (`python/`, `import fpm`): its wheel built with maturin
//! from the same crates as the CLI and installed into a virtual environment, then its
//! pytest suite
//! (python/tests/, which also runs examples/python_session.py) against the real USAF
//! data, simulated sets, and the `fpm` command for comparison.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use fpm_tests::{fpm_bin, python_venv};

/// The workspace, and the test environment's Python and its directory
/// (`target/python-package`, with maturin and the pinned test packages).
fn package_environment() -> (&'static Path, PathBuf, PathBuf) {
    let workspace = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let python = python_venv(
        "python-package",
        &workspace.join("python/requirements-test.txt"),
    );
    let venv = python
        .parent()
        .and_then(Path::parent)
        .expect("target/python-package")
        .to_path_buf();
    (workspace, python, venv)
}

/// The wheel users get (abi3, one file for every CPython from 3.9, manylinux x86_64,
/// the extension's symbols stripped: the package's files, metadata and entry points as
/// released), built once per run under `target/python-wheel` and shared by both tests:
/// the pytest suite runs against it installed, as a user's `pip install` gives it. It is
/// built in the test profile rather than the release one: the same crates, packaging and
/// settings, compiled as the rest of the suite is (dependencies and the physics
/// optimised, with debug assertions and overflow checks on), so that only the extension
/// itself is compiled and the test build's libraries are linked in. `--release` compiled
/// the whole tree a second time (about 10 of the suite's CPU-minutes); so did, for
/// fpm-physics and the crates using it, `--strip` (it strips every workspace crate: the
/// profile strips the extension instead) and features that differed from the
/// workspace's ([`the_wheel_reuses_the_test_build_s_libraries`]).
fn package_wheel() -> PathBuf {
    static WHEEL: OnceLock<PathBuf> = OnceLock::new();
    WHEEL
        .get_or_init(|| {
            let (workspace, _, venv) = package_environment();
            PathBuf::from(fpm_tests::once::once_per_run("python-wheel", || {
                let wheels = workspace.join("target/python-wheel");
                let _ = std::fs::remove_dir_all(&wheels);
                let build = Command::new(venv.join("bin/maturin"))
                    .args(["build", "--profile", "dev", "--quiet", "-m"])
                    .arg(workspace.join("python/Cargo.toml"))
                    .arg("--out")
                    .arg(&wheels)
                    .output()
                    .expect("running maturin");
                assert!(
                    build.status.success(),
                    "maturin build failed:\n{}",
                    String::from_utf8_lossy(&build.stderr)
                );
                let built: Vec<_> = std::fs::read_dir(&wheels)
                    .unwrap()
                    .map(|e| e.unwrap().path())
                    .collect();
                let [wheel] = built.as_slice() else {
                    panic!("one wheel expected: {built:?}")
                };
                wheel.display().to_string()
            }))
        })
        .clone()
}

#[test]
fn python_package_builds_and_its_tests_pass() {
    let (workspace, python, _) = package_environment();
    let wheel = package_wheel();
    // The test environment's own copy of the package, replaced by this run's wheel.
    let install = Command::new(&python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--force-reinstall",
        ])
        .arg(&wheel)
        .output()
        .expect("running pip");
    assert!(
        install.status.success(),
        "installing {}:\n{}",
        wheel.display(),
        String::from_utf8_lossy(&install.stderr)
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

/// What `pip install ptychoscope` would give a user without Rust: the release wheel
/// installed into a fresh virtual environment with NumPy alone, and the Python example
/// run there with no `cargo` or `rustc` on the PATH, importing the installed package.
#[test]
fn the_wheel_installs_into_a_fresh_environment_and_runs_the_example_without_rust() {
    let (workspace, _, _) = package_environment();
    let scratch = tempfile::tempdir().unwrap();
    let wheel = package_wheel();
    let name = wheel.file_name().unwrap().to_string_lossy().to_string();
    assert!(
        name.starts_with("ptychoscope-")
            && name.contains("-cp39-abi3-manylinux_")
            && name.ends_with("_x86_64.whl"),
        "{name}"
    );

    let fresh = scratch.path().join("venv");
    let made = Command::new("python3")
        .args(["-m", "venv"])
        .arg(&fresh)
        .output()
        .expect("python3 -m venv");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    // NumPy pinned as the test environment pins it; the wheel brings everything else.
    let numpy = std::fs::read_to_string(workspace.join("python/requirements-test.txt"))
        .unwrap()
        .lines()
        .find(|l| l.starts_with("numpy=="))
        .expect("numpy pinned in python/requirements-test.txt")
        .to_string();
    let pip = Command::new(fresh.join("bin/python"))
        .args(["-m", "pip", "install", "--quiet", &numpy])
        .arg(wheel)
        .output()
        .expect("pip install");
    assert!(
        pip.status.success(),
        "installing {name}: {}",
        String::from_utf8_lossy(&pip.stderr)
    );
    // Only the environment and the system's own directories: no ~/.cargo/bin.
    let path = format!("{}:/usr/bin:/bin", fresh.join("bin").display());
    let out = scratch.path().join("out");
    let run = Command::new(fresh.join("bin/python"))
        .args([
            "-c",
            "import runpy, shutil, sys\n\
             missing = [t for t in ('cargo', 'rustc') if shutil.which(t)]\n\
             assert not missing, f'on the PATH: {missing}'\n\
             import fpm\n\
             assert fpm.__file__.startswith(sys.prefix), fpm.__file__\n\
             print('installed at', fpm.__file__)\n\
             sys.argv = [sys.argv[1], sys.argv[2]]\n\
             runpy.run_path(sys.argv[0], run_name='__main__')",
        ])
        .arg(workspace.join("examples/python_session.py"))
        .arg(&out)
        .env_clear()
        .env("PATH", &path)
        .env("HOME", scratch.path())
        .current_dir(scratch.path())
        .output()
        .expect("running the example");
    let stdout = String::from_utf8_lossy(&run.stdout);
    println!("{stdout}");
    assert!(
        run.status.success(),
        "the example failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        stdout.contains("Δx =") && stdout.contains("wrote"),
        "{stdout}"
    );
    assert!(out.join("usaf/amplitude.tif").exists());
}

/// The crates the package shares with the rest of the workspace get the features the
/// test build gives them (python/Cargo.toml lists the ones only the rest turns on):
/// cargo unifies features over the packages of one build, and maturin builds the
/// package alone, so a crate whose features differ is compiled again for the wheel, and
/// with it everything above it up to fpm-physics and fpm-host.
#[test]
fn the_wheel_reuses_the_test_build_s_libraries() {
    let workspace = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // Each package of the selection's build with the features it is built with.
    let features = |edges: &str, selection: &[&str]| -> BTreeMap<String, BTreeSet<String>> {
        let out = Command::new(&cargo)
            .args([
                "tree", "--locked", "--prefix", "none", "-f", "{p}|{f}", "-e", edges,
            ])
            .args(selection)
            .current_dir(workspace)
            .output()
            .expect("running cargo tree");
        assert!(
            out.status.success(),
            "cargo tree {selection:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut map = BTreeMap::<String, BTreeSet<String>>::new();
        for line in String::from_utf8_lossy(&out.stdout).lines() {
            let line = line.trim_end_matches(" (*)");
            if let Some((package, on)) = line.split_once('|') {
                map.entry(package.to_string())
                    .or_default()
                    .extend(on.split(',').filter(|f| !f.is_empty()).map(String::from));
            }
        }
        map
    };
    // The test build: every member with its tests, so dev-dependencies count.
    let tested = features("normal,dev", &["--workspace"]);
    let wheel = features("normal", &["-p", "fpm-python"]);
    assert!(wheel.len() > 100, "{} packages in the wheel", wheel.len());
    let differ: Vec<String> = wheel
        .iter()
        .filter_map(|(package, on)| {
            let theirs = tested.get(package)?;
            (theirs != on).then(|| {
                format!(
                    "{package}: the test build turns on {:?}, the wheel's build {:?}",
                    theirs.difference(on).collect::<Vec<_>>(),
                    on.difference(theirs).collect::<Vec<_>>()
                )
            })
        })
        .collect();
    assert!(
        differ.is_empty(),
        "the wheel's build would compile these again: give them the same features in \
         python/Cargo.toml's list\n{}",
        differ.join("\n")
    );
}
