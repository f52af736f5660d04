//! Real camera stacks into the frame contract: Debian's GigE Vision camera simulator
//! (`arv-fake-gv-camera-0.8`, aravis 0.8) on loopback, driven by `fpm camera run
//! --aravis` through libaravis. Everything stays on 127.0.0.1: the camera is always
//! opened by address, never found by a discovery broadcast. One fake camera can listen
//! on 127.0.0.1 at a time (GVCP's port is fixed), so these tests take turns.

use std::fs::File;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use fpm_frames::{FrameSubscriber, ServiceNames};
use fpm_tests::{child, fpm_bin, ChildProcess, Ready, TempDir};
use nix::fcntl::Flock;

const FAKE_CAMERA: &str = "arv-fake-gv-camera-0.8";

/// This test's turn with a fresh fake camera (serial from `tag`): hold both. The turn
/// is a file lock, as tests run as threads (cargo test) or processes (nextest).
fn own_fake_camera(tag: &str) -> (Flock<File>, ChildProcess) {
    own_fake_camera_with_serial(&unique(tag))
}

fn own_fake_camera_with_serial(serial: &str) -> (Flock<File>, ChildProcess) {
    let turn = fpm_tests::once::exclusive("fake-gige-camera");
    (turn, fake_camera(serial))
}

/// `fpm camera run --aravis 127.0.0.1 ARGS`, which must fail: its stderr.
fn refused(args: &[&str]) -> String {
    let mut all = vec!["camera", "run", "--aravis", "127.0.0.1"];
    all.extend_from_slice(args);
    let out = fpm(&all);
    assert!(!out.status.success(), "fpm {all:?} ran");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A fresh fake camera on 127.0.0.1 with serial `serial`, answering.
fn fake_camera(serial: &str) -> ChildProcess {
    let mut command = Command::new(FAKE_CAMERA);
    command
        .args(["-i", "127.0.0.1", "-s", serial])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    if Command::new(FAKE_CAMERA).arg("--help").output().is_err() {
        panic!("{FAKE_CAMERA} is not installed: apt install aravis-tools (.ci/run does)");
    }
    let mut camera = child(command, "fake GigE Vision camera", Ready::Started);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let out = fpm(&["camera", "list", "--address", "127.0.0.1", "--json"]);
        if out.status.success() && String::from_utf8_lossy(&out.stdout).contains(serial) {
            return camera;
        }
        if let Some(status) = camera.try_wait() {
            panic!("the fake camera exited at start-up: {status}");
        }
        assert!(Instant::now() < deadline, "the fake camera never answered");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn fpm(args: &[&str]) -> std::process::Output {
    Command::new(fpm_bin())
        .args(args)
        .output()
        .expect("running fpm")
}

/// `fpm camera run --aravis 127.0.0.1 …` with its log in `dir/camera.log`, ready once
/// it has written the settings it applied.
fn camera_run(dir: &Path, camera: &str, extra: &[&str]) -> ChildProcess {
    let applied = dir.join("applied.json");
    let log = std::fs::File::create(dir.join("camera.log")).unwrap();
    let mut command = Command::new(fpm_bin());
    command
        .args(["camera", "run", "--aravis", "127.0.0.1", "--camera", camera])
        .arg("--settings-out")
        .arg(&applied)
        .args(extra)
        .stdout(Stdio::null())
        .stderr(log);
    child(
        command,
        "fpm camera run",
        Ready::FileExists(&applied, Duration::from_secs(20)),
    )
}

/// A name no other run uses (at most 12 characters: GigE Vision serial numbers are
/// short).
fn unique(tag: &str) -> String {
    format!(
        "{tag}{:08X}",
        fastrand() ^ std::process::id().rotate_left(16)
    )
}

fn fastrand() -> u32 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos()
}

#[test]
/// The fake camera is found by its address, with its identity, and nothing else is
/// asked (no broadcast).
fn the_camera_is_listed_by_address() {
    let serial = unique("LIST");
    let (_turn, _camera) = own_fake_camera_with_serial(&serial);
    let out = fpm(&["camera", "list", "--address", "127.0.0.1", "--json"]);
    assert!(out.status.success(), "{out:?}");
    let list: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let cam = &list[0];
    assert_eq!(cam["serial"], serial.as_str(), "{list}");
    assert_eq!(cam["vendor"], "Aravis");
    assert_eq!(cam["protocol"], "GigEVision");
    assert_eq!(cam["address"], "127.0.0.1");
    let text =
        String::from_utf8(fpm(&["camera", "list", "--address", "127.0.0.1"]).stdout).unwrap();
    assert!(
        text.contains(&serial) && text.contains("127.0.0.1"),
        "{text}"
    );
}

#[test]
/// Frames at each pixel format the camera has reach a subscriber with the size, bit
/// depth, exposure and consecutive numbers the settings asked for, stamped by the
/// camera's clock at its frame rate; Mono8 pixels are the simulator's diagonal ramp
/// (value = x + y + frame id, mod 255), so rows, columns and order are checked too.
fn frames_at_each_pixel_format_reach_the_contract() {
    let (_turn, _camera) = own_fake_camera("FMT");
    for (format, bits) in [("Mono8", 8u32), ("Mono16", 16)] {
        let dir = TempDir::new(&format!("camera-{format}"));
        let id = unique(&format!("cam-{format}"));
        let names = ServiceNames::for_camera(&id);
        let frames = FrameSubscriber::create(&names).unwrap();
        let (w, h) = (320u32, 240u32);
        let roi = format!("16,8,{w},{h}");
        let mut run = camera_run(
            &dir.0,
            &id,
            &[
                "--pixel-format",
                format,
                "--roi",
                &roi,
                "--exposure-us",
                "10000",
                "--gain",
                "0",
                "--trigger",
                "Off",
                "--frames",
                "12",
            ],
        );
        let applied: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.0.join("applied.json")).unwrap())
                .unwrap();
        assert_eq!(applied["pixel_format"], format);
        assert_eq!(applied["roi"], serde_json::json!([16, 8, w, h]));
        assert_eq!(applied["bit_depth"], bits);
        assert_eq!(applied["trigger_mode"], "Off");
        let mut got = vec![];
        let deadline = Instant::now() + Duration::from_secs(20);
        while got.len() < 10 && Instant::now() < deadline {
            if let Some(f) = frames.next(Duration::from_millis(200)).unwrap() {
                let hd = *f.header();
                assert_eq!((hd.width, hd.height, hd.bit_depth), (w, h, bits), "{hd:?}");
                assert_eq!(hd.exposure_us, 10_000);
                assert_eq!(f.pixels().len(), (w * h) as usize);
                if format == "Mono8" {
                    let p = f.pixels();
                    let p00 = p[0] as u32;
                    for y in 0..h {
                        for x in 0..w {
                            let want = (p00 + x + y) % 255;
                            assert_eq!(
                                p[(y * w + x) as usize] as u32,
                                want,
                                "frame {} pixel ({x}, {y})",
                                hd.frame_number
                            );
                        }
                    }
                }
                got.push(hd);
            }
        }
        assert!(got.len() >= 10, "{format}: only {} frames", got.len());
        let mut intervals = vec![];
        for pair in got.windows(2) {
            assert_eq!(pair[1].frame_number, pair[0].frame_number + 1, "{got:?}");
            intervals.push(pair[1].timestamp_ns as f64 - pair[0].timestamp_ns as f64);
        }
        // The simulator runs at 25 frames/s by its own clock (after a first frame at
        // the start of the acquisition, off its grid).
        intervals.sort_by(f64::total_cmp);
        let median = intervals[intervals.len() / 2];
        assert!(
            (median - 40e6).abs() < 2e6,
            "{format}: {intervals:?} ns between frames"
        );
        let status = wait_exit(&mut run, Duration::from_secs(20));
        assert!(status.success(), "{status}: {}", log(&dir.0));
        let log = log(&dir.0);
        assert!(log.contains("12 frames published, 0 incomplete"), "{log}");
        assert!(log.contains("stream: "), "{log}");
    }
}

fn log(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("camera.log")).unwrap_or_default()
}

fn wait_exit(run: &mut ChildProcess, timeout: Duration) -> std::process::ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = run.try_wait() {
            return status;
        }
        assert!(Instant::now() < deadline, "still running after {timeout:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
/// A colour camera (the simulator's BayerRG8) publishes the LEDs' channel: its own
/// pixels, one per 2 × 2 cell, half the region each way; without a channel it refuses,
/// naming the mosaic.
fn a_colour_camera_publishes_the_leds_channel() {
    let (_turn, _camera) = own_fake_camera("RGB");
    let err = refused(&["--camera", "rgb", "--pixel-format", "BayerRG8"]);
    assert!(
        err.contains("BayerRG8") && err.contains("--channel"),
        "{err}"
    );
    let dir = TempDir::new("camera-colour");
    let id = unique("cam-rgb");
    let frames = FrameSubscriber::create(&ServiceNames::for_camera(&id)).unwrap();
    let _run = camera_run(
        &dir.0,
        &id,
        &[
            "--pixel-format",
            "BayerRG8",
            "--channel",
            "G",
            "--roi",
            "0,0,320,240",
            "--trigger",
            "Off",
        ],
    );
    let applied: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.0.join("applied.json")).unwrap())
            .unwrap();
    assert_eq!(applied["bayer"], "RGGB", "{applied}");
    assert_eq!(applied["channel"], "G", "{applied}");
    assert_eq!(applied["published_size"], serde_json::json!([160, 120]));
    assert_eq!(applied["published_pixel_factor"], 2);
    let deadline = Instant::now() + Duration::from_secs(20);
    let frame = loop {
        if let Some(f) = frames.next(Duration::from_millis(200)).unwrap() {
            break *f.header();
        }
        assert!(Instant::now() < deadline, "no frame: {}", log(&dir.0));
    };
    assert_eq!(
        (frame.width, frame.height, frame.bit_depth),
        (160, 120, 8),
        "{frame:?}"
    );
}

#[test]
/// Settings the camera cannot take are refused before anything streams, naming them.
fn impossible_settings_are_refused_by_name() {
    let (_turn, _camera) = own_fake_camera("BAD");
    let err = refused(&["--camera", "bad", "--pixel-format", "Mono12Packed"]);
    assert!(
        err.contains("Mono12Packed") && err.contains("Mono16"),
        "{err}"
    );
    let dir = TempDir::new("camera-bad-config");
    let config = dir.0.join("camera.toml");
    std::fs::write(&config, "exposure = 100\n").unwrap();
    let err = refused(&["--config", config.to_str().unwrap()]);
    assert!(
        err.contains("camera.toml") && err.contains("exposure"),
        "{err}"
    );
    let out = fpm(&["camera", "list", "--address", "127.0.0.1"]);
    assert!(out.status.success());
}

#[test]
/// A camera that disappears mid-stream ends the run with an error that names it,
/// within seconds, instead of waiting forever.
fn a_camera_that_disappears_ends_the_run_with_a_clear_error() {
    let (_turn, mut camera) = own_fake_camera("GONE");
    let dir = TempDir::new("camera-gone");
    let id = unique("cam-gone");
    let frames = FrameSubscriber::create(&ServiceNames::for_camera(&id)).unwrap();
    let mut run = camera_run(
        &dir.0,
        &id,
        &[
            "--pixel-format",
            "Mono8",
            "--roi",
            "0,0,128,128",
            "--trigger",
            "Off",
            "--lost-after-s",
            "1",
        ],
    );
    let mut seen = 0;
    let deadline = Instant::now() + Duration::from_secs(20);
    while seen < 3 && Instant::now() < deadline {
        if frames.next(Duration::from_millis(200)).unwrap().is_some() {
            seen += 1;
        }
    }
    assert_eq!(seen, 3, "{}", log(&dir.0));
    camera.kill();
    let killed = Instant::now();
    let status = wait_exit(&mut run, Duration::from_secs(30));
    let log = log(&dir.0);
    assert!(!status.success(), "{log}");
    assert!(
        log.contains("camera 127.0.0.1 stopped answering")
            || log.contains("camera 127.0.0.1 is gone"),
        "{log}"
    );
    eprintln!(
        "the lost camera was reported {:.1} s after it died",
        killed.elapsed().as_secs_f64()
    );
}

#[test]
/// A whole `fpm acquire` against the emulated controller with the fake GigE Vision
/// camera: the trigger cable is stood in for by a software trigger fired on each
/// trigger-out pulse the emulator publishes. The camera's clock (the Unix epoch, ns)
/// has nothing in common with the controller's, and it starts a frame only on its own
/// 40 ms tick: every LED is still labelled, and no frame is extra.
fn an_acquisition_with_the_fake_camera_labels_every_led() {
    let (_turn, _camera) = own_fake_camera("ACQ");
    let dir = TempDir::new("camera-acquire");
    let rig = unique("rig-acq");
    let id = unique("cam-acq");
    let emu = fpm_tests::Emulator::start_at(&dir.0.join("ctl.tty"), &["--rig", &rig]);
    let _run = camera_run(
        &dir.0,
        &id,
        &[
            "--rig",
            &rig,
            "--pixel-format",
            "Mono8",
            "--roi",
            "0,0,256,256",
        ],
    );
    let out_dir = dir.0.join("acq");
    let out = fpm_tests::acquire_command(&emu.port(), &id, 180, &out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        log(&dir.0)
    );
    let report = fpm_tests::acquisition_report(&out_dir);
    let capture = &report["capture"];
    assert_eq!(capture["requested"], 441, "{capture}");
    // The simulator now and then loses a software trigger, or answers one far later
    // than its tick (a frame then matches no step: extra, never mislabelled): such an
    // LED is taken again (the retake), and the dataset is whole.
    let missing = capture["missing"].as_array().unwrap().len();
    assert!(missing <= 3, "{capture}");
    assert!(
        capture["extra_frames"].as_u64().unwrap() as usize <= missing,
        "{capture}"
    );
    let retaken = report["retake"]["labelled"].as_u64().unwrap_or(0);
    assert_eq!(
        capture["labelled"].as_u64().unwrap() + retaken,
        441,
        "{report}"
    );
    assert_eq!(
        report["still_missing"].as_array().map(Vec::len),
        Some(0),
        "{report}"
    );
    assert_eq!(capture["ambiguous_frames"], 0, "{capture}");
    fpm_tests::assert_labelled_live(capture);
    assert_eq!(report["frames_in_dataset"], 441);
    // What the camera applied, as it reported it, is in the acquisition's record.
    let settings = &report["camera_settings"];
    assert_eq!(settings["pixel_format"], "Mono8", "{settings}");
    assert_eq!(settings["bit_depth"], 8, "{settings}");
    assert_eq!(
        settings["roi"],
        serde_json::json!([0, 0, 256, 256]),
        "{settings}"
    );
    assert_eq!(settings["trigger_source"], "Software", "{settings}");
    assert_eq!(settings["model"], "Fake", "{settings}");
    // The simulator has no Gamma or LUT feature: raw counts, and the dataset says so.
    assert_eq!(settings["encoding_gamma"], 1.0, "{settings}");
    let dataset = std::fs::read_to_string(out_dir.join("dataset.toml")).unwrap();
    assert!(dataset.contains("bit_depth = 8"), "{dataset}");
    assert!(dataset.contains("gamma = 1.0"), "{dataset}");
    let log = log(&dir.0);
    assert!(log.contains("trigger On Software"), "{log}");
}
