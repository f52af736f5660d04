//! The Python side of the frame contract (`tools/camera-python/fpm_camera.py`), as a
//! vendor SDK's frame loop would use it: its NumPy example camera answers the trigger
//! pulses of the emulated controller, and a whole `fpm acquire` takes its frames.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use fpm_host::dataset::Dataset;
use fpm_tests::{child, python_venv, workspace, Emulator, Ready, TempDir};

/// A Python with the contract's packages (iceoryx2, NumPy; pinned in
/// tools/camera-python/requirements.txt), in a virtual environment under target/.
fn python() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_venv(
            "python-camera",
            &workspace().join("tools/camera-python/requirements.txt"),
        )
    })
}

/// An acquisition from an example camera of tools/camera-python (`script` with
/// `args`, plus the rig and camera ids and a ready file) behind the emulated
/// controller, `step_ms` per LED: the scratch directory (kept alive), the dataset
/// directory and `acquisition.json`.
fn acquire_from(
    tag: &str,
    script: &str,
    args: &[&str],
    step_ms: u32,
) -> (TempDir, PathBuf, serde_json::Value) {
    let id = format!("{tag}-{}", std::process::id());
    let dir = TempDir::new(tag);
    let emu = Emulator::start_at(&dir.0.join("ctl.tty"), &["--rig", &id]);
    let ready = dir.0.join("camera.ready");
    let mut command = Command::new(python());
    command
        .current_dir(workspace().join("tools/camera-python"))
        .arg(script)
        .args(args)
        .args(["--rig", &id, "--camera", &id])
        .arg("--ready-file")
        .arg(&ready)
        .stdout(Stdio::null());
    let _camera = child(
        command,
        script,
        Ready::FileExists(&ready, Duration::from_secs(60)),
    );
    let out = dir.0.join("data");
    let run = fpm_tests::acquire_command(&emu.port(), &id, step_ms, &out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report = fpm_tests::acquisition_report(&out);
    (dir, out, report)
}

/// Every LED labelled, and every frame the one its LED made: the NumPy camera draws
/// 1000 + 32·row + col into each frame from the pulse's lit LED, and stamps it on a
/// clock 2.5 s ahead of the controller's.
#[test]
fn a_python_publisher_feeds_a_whole_acquisition() {
    let (_dir, out, report) = acquire_from("camera-python", "example_numpy_camera.py", &[], 15);
    let capture = &report["capture"];
    assert_eq!(capture["labelled"], 441, "{capture}");
    assert_eq!(capture["extra_frames"], 0, "{capture}");
    fpm_tests::assert_labelled_live(capture);
    let offset_s = capture["clock_offset_ns"].as_f64().unwrap() / 1e9;
    assert!((offset_s - 2.5).abs() < 0.01, "clock offset {offset_s} s");
    let ds = Dataset::load(&out).unwrap();
    assert_eq!(ds.frames.len(), 441);
    // The camera said what it applied (raw 12-bit counts), and the dataset states it.
    let settings = &report["camera_settings"];
    assert_eq!(settings["model"], "example NumPy camera", "{settings}");
    assert_eq!(ds.manifest.camera.gamma, Some(1.0));
    let dark = 100.0; // fpm acquire's default --dark-level
    for (k, f) in ds.frames.iter().enumerate() {
        let led = f.entry.led;
        let want = 1000.0 + 32.0 * led.row as f32 + led.col as f32 - dark;
        let got = ds.corrected(k).mean().unwrap();
        assert!(
            (got - want).abs() < 0.5,
            "the frame labelled ({}, {}) shows {got}, its LED would give {want}",
            led.row,
            led.col
        );
    }
}

/// A real camera SDK without hardware: Basler's pypylon on pylon's camera emulation
/// (only that transport layer is opened: no discovery broadcast), triggered in
/// software on each trigger-out pulse of the emulated controller, Mono12 frames
/// published through `fpm_camera`: every LED labelled, none extra.
#[test]
fn pypylons_emulated_camera_feeds_a_whole_acquisition() {
    let (_dir, out, report) = acquire_from(
        "camera-pypylon",
        "example_pypylon_camera.py",
        &["--emulated"],
        40,
    );
    // The emulation stamps 0, so the example stamps the host's clock when Python fires
    // the trigger: on a loaded machine that can lag the pulse by more than the
    // labelling tolerance, and such a frame is reported extra and its LED taken again.
    let capture = &report["capture"];
    let missing = capture["missing"].as_array().unwrap().len();
    assert!(missing <= 3, "{capture}");
    assert!(
        capture["extra_frames"].as_u64().unwrap() as usize <= missing,
        "{capture}"
    );
    fpm_tests::assert_labelled_live(capture);
    assert_eq!(
        report["still_missing"].as_array().map(Vec::len),
        Some(0),
        "{report}"
    );
    let ds = Dataset::load(&out).unwrap();
    assert_eq!(ds.frames.len(), 441);
    assert_eq!(ds.frames[0].raw.dim(), (64, 64));
    assert_eq!(ds.manifest.camera.bit_depth, Some(12));
    // The emulation's settings as pypylon read them: its Gamma feature at 1, raw counts.
    let settings = &report["camera_settings"];
    assert_eq!(settings["vendor"], "Basler", "{settings}");
    assert_eq!(settings["pixel_format"], "Mono12", "{settings}");
    assert_eq!(settings["encoding_gamma"], 1.0, "{settings}");
    assert_eq!(ds.manifest.camera.gamma, Some(1.0));
}
