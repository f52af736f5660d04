//! Helpers for tests that run the real programs: build and find the `fpm` binary,
//! start rig processes (through `fpm_rig::process`, as the demo does), stop or kill
//! them.

pub mod browser;
pub mod once;
/// The service's own blocking client, failing the test on a failed request.
pub mod http {
    pub use fpm_serve::client::Response;

    /// [`fpm_serve::client::send`], the test failing if the request cannot be made.
    pub fn request(
        address: std::net::SocketAddr,
        method: &str,
        path: &str,
        headers: &[(&str, &str)],
        body: Option<&str>,
    ) -> Response {
        fpm_serve::client::send(address, method, path, headers, body)
            .unwrap_or_else(|e| panic!("{e:#}"))
    }
}

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

/// The Python of a virtual environment `target/<name>` with the pinned packages of
/// `requirements` installed, made (or remade, when the requirements changed) on first
/// use. Needs Python ≥ 3.9 with `venv`; the packages come from PyPI.
pub fn python_venv(name: &str, requirements: &Path) -> PathBuf {
    // Tests run as threads of one process (cargo test) or as processes (nextest): one
    // makes the environment, the others wait for it.
    let _making = once::exclusive(&format!("venv-{name}"));
    let workspace = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    let venv = workspace.join("target").join(name);
    let python = venv.join("bin/python");
    let stamp = venv.join("requirements.txt");
    let current = std::fs::read(&stamp).ok() == std::fs::read(requirements).ok();
    if !python.exists() || !current {
        let run = |cmd: &mut Command, what: &str| {
            let out = cmd.output().unwrap_or_else(|e| panic!("{what}: {e}"));
            assert!(
                out.status.success(),
                "{what}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        };
        run(
            Command::new("python3").args(["-m", "venv"]).arg(&venv),
            "making a Python virtual environment (python3 -m venv)",
        );
        run(
            Command::new(&python)
                .args(["-m", "pip", "install", "--quiet", "-r"])
                .arg(requirements),
            &format!("installing {}", requirements.display()),
        );
        std::fs::copy(requirements, &stamp).expect("stamping the environment");
    }
    python
}

/// The `fpm` executable, built with the same profile as the running test and with
/// the whole workspace's features (`--workspace --tests --bins`, as `cargo test
/// --workspace` resolves them), so that it reuses the libraries the test build made;
/// `-p ptychoscope` alone resolves fewer features and rebuilt most of the tree.
pub fn fpm_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        let exe = std::env::current_exe().expect("test executable path");
        // target/<profile>/deps/<test> → <profile>
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("target/<profile>");
        let profile = profile_dir
            .file_name()
            .and_then(|s| s.to_str())
            .unwrap_or("debug")
            .to_string();
        PathBuf::from(once::once_per_run(&format!("fpm-bin-{profile}"), || {
            build_fpm(&profile)
        }))
    })
}

fn build_fpm(profile: &str) -> String {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args([
        "build",
        "--quiet",
        "--workspace",
        "--tests",
        "--bins",
        "--message-format=json",
    ])
    .current_dir(workspace());
    if profile != "debug" {
        cmd.args(["--profile", profile]);
    }
    let out = cmd
        .stderr(Stdio::inherit())
        .output()
        .expect("running cargo build");
    assert!(out.status.success(), "cargo build of fpm failed");
    let stdout = String::from_utf8_lossy(&out.stdout);
    stdout
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|v| {
            v["reason"] == "compiler-artifact"
                && v["target"]["name"] == "fpm"
                && v["profile"]["test"] == false
        })
        .filter_map(|v| v["executable"].as_str().map(String::from))
        .next_back()
        .expect("cargo reported the fpm executable")
}

/// Which controller a conformance test talks to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    /// `fpm emulator`: the firmware logic compiled for the host.
    HostEmulator,
    /// `fpm emulator --firmware`: the real firmware image in an emulated RP2040.
    Firmware,
}

impl Target {
    /// Start this target's controller linked at `link`. `host_options` configure the
    /// host-compiled emulator; the firmware image has its board built in and takes
    /// only the emulated camera's, the rig's and the flash's options among them
    /// (`--no-camera`, `--camera-latency-us N`, `--camera-exposure-us N`, `--rig NAME`,
    /// `--serial N`, `--flash FILE`, `--power-cut-after N`).
    pub fn start(self, link: &Path, host_options: &[&str]) -> Emulator {
        match self {
            Target::HostEmulator => Emulator::start_at(link, host_options),
            Target::Firmware => {
                let uf2 = firmware_uf2().to_string_lossy().into_owned();
                let mut args = vec!["--firmware", uf2.as_str()];
                let mut options = host_options.iter();
                while let Some(&option) = options.next() {
                    match option {
                        "--no-camera" => args.push(option),
                        "--rig" => {
                            args.push(option);
                            args.extend(options.next());
                        }
                        "--camera-latency-us"
                        | "--camera-exposure-us"
                        | "--serial"
                        | "--flash"
                        | "--power-cut-after" => {
                            args.push(option);
                            args.extend(options.next());
                        }
                        _ => {}
                    }
                }
                Emulator::start_at(link, &args)
            }
        }
    }
}

/// The workspace's root (the repository).
pub fn workspace() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// A Python with NumPy, tifffile, SciPy and h5py (tests/import_sources/requirements.txt,
/// in target/python-import): what writes other labs' files for the import tests, and
/// the independent forward model's sets (tests/independent/simulate.py).
pub fn python_with_numpy() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        python_venv(
            "python-import",
            &workspace().join("tests/import_sources/requirements.txt"),
        )
    })
}

/// The firmware image users flash (`fpm-led-controller.uf2`, the chain on one data
/// line), built for the RP2040 if it is not there yet, with the RP2040 emulator's Node
/// packages installed (`npm ci` in tools/rp2040).
pub fn firmware_uf2() -> &'static Path {
    firmware_uf2_with_lanes(1)
}

/// The firmware image for a chain wired as `lanes` data lanes (1, 2 or 4), as
/// [`firmware_uf2`].
pub fn firmware_uf2_with_lanes(lanes: u8) -> &'static Path {
    static UF2: OnceLock<Vec<(u8, PathBuf)>> = OnceLock::new();
    let images = UF2.get_or_init(|| {
        // Once per run: another test process may be writing the same UF2 files.
        let release = PathBuf::from(once::once_per_run("firmware-uf2", build_firmware_images));
        FIRMWARE_IMAGES
            .map(|(lanes, name)| (lanes, release.join(name).with_extension("uf2")))
            .to_vec()
    });
    images
        .iter()
        .find(|(n, _)| *n == lanes)
        .map(|(_, uf2)| uf2.as_path())
        .unwrap_or_else(|| panic!("no firmware image for {lanes} lanes (1, 2 or 4)"))
}

/// Build the firmware images and their UF2 files, and install the RP2040 emulator's
/// Node packages: the directory of the images.
fn build_firmware_images() -> String {
    let root = workspace();
    let release = root.join("target/thumbv6m-none-eabi/release");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let run = |cmd: &mut Command, what: &str| {
        let status = cmd
            .stdout(Stdio::null())
            .status()
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        assert!(status.success(), "{what} failed: {status}");
    };
    // Built from its own directory so its .cargo/config.toml (target, linker
    // scripts) applies; cargo makes this a no-op when nothing changed.
    run(
        Command::new(&cargo)
            .args(["build", "--release", "--quiet"])
            .current_dir(root.join("firmware/rp2040"))
            .env_remove("CARGO_TARGET_DIR"),
        "building the RP2040 firmware",
    );
    for name in FIRMWARE_IMAGES.map(|(_, name)| name) {
        let elf = release.join(name);
        run(
            Command::new(&cargo)
                .args(["run", "--quiet", "-p", "fpm-fwtool", "--", "uf2"])
                .arg(&elf)
                .arg(elf.with_extension("uf2"))
                .current_dir(root),
            "writing the firmware's UF2 image",
        );
    }
    let harness = root.join("tools/rp2040");
    if !harness.join("node_modules/rp2040js").is_dir() {
        run(
            Command::new("npm")
                .args(["ci", "--no-audit", "--no-fund"])
                .current_dir(&harness),
            "installing the RP2040 emulator (npm ci in tools/rp2040)",
        );
    }
    release.display().to_string()
}

/// The firmware's images: the chain's data lanes and the ELF's name.
const FIRMWARE_IMAGES: [(u8, &str); 3] = fpm_fwtool::build::IMAGES;

/// Run `fpm args…`, which must succeed (its stderr in the panic otherwise); its stdout.
pub fn fpm_stdout(args: &[&str]) -> String {
    let out = Command::new(fpm_bin())
        .args(args)
        .output()
        .expect("run fpm");
    assert!(
        out.status.success(),
        "fpm {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `fpm acquire` against controller `port` and camera `camera` (its frame service
/// `fpm simulate acquisition --out OUT` of a `size`² field, `seed`, the array where
/// the dataset says it is (centred, unturned), and `extra` options.
pub fn simulate_centred(out: &Path, size: &str, seed: &str, extra: &[&str]) {
    simulate_centred_set("acquisition", out, size, seed, extra)
}

/// [`simulate_centred`] of a pdcFPM calibration set (`fpm simulate calibration`).
pub fn simulate_centred_calibration(out: &Path, size: &str, seed: &str, extra: &[&str]) {
    simulate_centred_set("calibration", out, size, seed, extra)
}

fn simulate_centred_set(kind: &str, out: &Path, size: &str, seed: &str, extra: &[&str]) {
    let out = out.to_string_lossy();
    let mut args = vec![
        "simulate", kind, "--out", &out, "--size", size, "--seed", seed,
    ];
    args.extend_from_slice(&ON_AXIS[..6]);
    args.extend_from_slice(extra);
    fpm_stdout(&args);
}

/// A virtual camera's (or simulator's) array exactly where the controller says,
/// 92 mm below the sample: for tests about labels, not geometry.
pub const ON_AXIS: [&str; 8] = [
    "--dx-mm",
    "0",
    "--dy-mm",
    "0",
    "--theta-deg",
    "0",
    "--height-mm",
    "92",
];

/// A float32 image file (a reconstruction's or DPC's output).
pub fn read_f32(path: &Path) -> fpm_physics::Image {
    match fpm_host::dataset::image_io::read(path) {
        Ok(fpm_host::dataset::image_io::Pixels::F32(a)) => a,
        Ok(other) => panic!("{} is not float32: {} bits", path.display(), other.bits()),
        Err(e) => panic!("{}: {}", path.display(), e.reason()),
    }
}

/// id), `step_ms` per LED, into `out`.
pub fn acquire_command(port: &str, camera: &str, step_ms: u32, out: &Path) -> Command {
    let mut cmd = Command::new(fpm_bin());
    cmd.args(["acquire", "--port", port, "--frames", camera, "--out"])
        .arg(out)
        .args(["--step-ms", &step_ms.to_string()]);
    cmd
}

/// The `acquisition.json` an acquisition wrote into `out`.
pub fn acquisition_report(out: &Path) -> serde_json::Value {
    let path = out.join("acquisition.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A capture (`acquisition.json`'s `capture`) labelled its frames as they arrived:
/// at least three quarters of those that came while the controller's sequence still
/// ran were labelled before it ended (a labeller that waits for the sequence's end
/// labels none of them live, issue 61), at least 8 came then (enough to anchor the
/// clocks: a check on fewer proves nothing), and none was relabelled at the end.
/// Judged against the frames that had arrived, not against all of them: a camera that
/// falls behind its triggers on a loaded machine delivers the rest after the end,
/// however quick the labeller, and that is the camera's lateness, reported as such.
pub fn assert_labelled_live(capture: &serde_json::Value) {
    let labelled = capture["labelled"].as_u64().unwrap_or(0);
    let live = capture["labelled_live"].as_u64().unwrap_or(0);
    let arrived = capture["arrived_live"].as_u64().unwrap_or(0);
    eprintln!(
        "{live} of {labelled} frames labelled while the sequence ran, {arrived} arrived then; arrival → label p50 {} ms, p99 {} ms",
        capture["label_lag_p50_ms"], capture["label_lag_p99_ms"]
    );
    assert!(arrived >= 8 && 4 * live >= 3 * arrived, "{capture}");
    assert_eq!(capture["relabelled"], 0, "{capture}");
}

/// The real data sets vendored in the repository (`data/`, each with its source and
/// licence in its README).
pub fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data")
}

/// A scratch directory, made (uniquely, atomically) by the `tempfile` crate and
/// removed on drop; `.0` is its path.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// A new unique directory under the system temp dir, named after `tag`.
    pub fn new(tag: &str) -> Self {
        let dir = tempfile::Builder::new()
            .prefix(&format!("fpm-test-{tag}-"))
            .tempdir()
            .expect("creating a temp dir");
        Self(dir.keep())
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub use fpm_rig::process::{ChildProcess, Ready};

/// A child process (e.g. `fpm virtual-camera`), stopped with SIGTERM and reaped when
/// dropped.
pub fn child(command: Command, what: &str, ready: Ready<'_>) -> ChildProcess {
    ChildProcess::start(command, what, ready).unwrap_or_else(|e| panic!("{e:#}"))
}

/// `fpm emulator` running as a child process, its log kept in a file.
pub struct Emulator {
    process: fpm_rig::process::EmulatorProcess,
    /// The link path clients open.
    pub link: PathBuf,
    /// Where its log goes.
    pub log: PathBuf,
}

impl Emulator {
    /// Start an emulator linked at `link` with extra arguments; wait until it is ready.
    pub fn start_at(link: &Path, extra: &[&str]) -> Self {
        let log = link.with_extension("log");
        let log_file = std::fs::File::create(&log).expect("emulator log file");
        match fpm_rig::process::EmulatorProcess::start_at(fpm_bin(), link, extra, log_file.into()) {
            Ok(process) => Self {
                process,
                link: link.to_path_buf(),
                log,
            },
            Err(e) => panic!(
                "{e:#}\n{}",
                std::fs::read_to_string(&log).unwrap_or_default()
            ),
        }
    }

    /// The link path as a port name.
    pub fn port(&self) -> String {
        self.process.port()
    }

    /// Its log so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Its log once `ready` holds for it, or when `timeout` has passed (the caller's
    /// assertions then say what is missing). A controller logs what its chain shows
    /// after it has replied, so tests wait for the log instead of sleeping.
    pub fn log_when(&self, ready: impl Fn(&str) -> bool, timeout: std::time::Duration) -> String {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let log = self.log_text();
            if ready(&log) || std::time::Instant::now() >= deadline {
                return log;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Its exit status once it has ended by itself, waiting up to `timeout` (None: it
    /// still runs).
    pub fn exited_within(
        &mut self,
        timeout: std::time::Duration,
    ) -> Option<std::process::ExitStatus> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            if let Some(status) = self.process.process.try_wait() {
                return Some(status);
            }
            if std::time::Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Kill it without warning (SIGKILL): the link stays behind, as after a crash.
    pub fn kill(&mut self) {
        self.process.process.kill();
    }

    /// Stop it cleanly (SIGTERM) and return its exit status.
    pub fn stop(&mut self) -> Option<std::process::ExitStatus> {
        self.process.process.stop()
    }
}

/// Raw wire frames, for tests that speak to a device below the client.
pub mod wire {
    use postcard_rpc::header::{VarHeader, VarKey, VarSeq};
    use postcard_rpc::Key;

    /// A COBS frame (with its delimiter) carrying `body` under `key`.
    pub fn frame(key: Key, seq: u32, body: &[u8]) -> Vec<u8> {
        let hdr = VarHeader {
            key: VarKey::Key8(key),
            seq_no: VarSeq::Seq4(seq),
        };
        let mut raw = hdr.write_to_vec();
        raw.extend_from_slice(body);
        let mut out = cobs::encode_vec(&raw);
        out.push(0);
        out
    }

    /// Decode every complete frame in `bytes`.
    pub fn frames(bytes: &[u8]) -> Vec<(VarHeader, Vec<u8>)> {
        bytes
            .split(|&b| b == 0)
            .filter(|c| !c.is_empty())
            .filter_map(|c| cobs::decode_vec(c).ok())
            .filter_map(|raw| VarHeader::take_from_slice(&raw).map(|(h, b)| (h, b.to_vec())))
            .collect()
    }
}

/// LEDs whose frame's brightness contradicts the hidden array's bright-field disc
/// (LEDs right at the pupil edge, whose brightness is in between, are skipped).
pub fn contradicted_by_physics(
    ds: &fpm_host::dataset::Dataset,
    hidden: &fpm_physics::LedGeometry,
) -> Vec<(fpm_physics::LedIndex, f32)> {
    let system = fpm_physics::System::paper();
    let mut wrong = vec![];
    for (k, f) in ds.frames.iter().enumerate() {
        let rate = ds.corrected(k).mean().unwrap() / f.entry.exposure_ms as f32;
        let led = f.entry.led;
        let fr = hidden.illumination_frequency(led, 0.0, 0.0, system.wavelength_um);
        if (fr.0.hypot(fr.1) / system.cutoff() - 1.0).abs() < 0.08 {
            continue;
        }
        let bright = hidden.is_bright_field(led, 0.0, 0.0, &system);
        // A clear field gives ~electrons_per_ms · gain per ms; dark-field frames a few %.
        if bright != (rate > 0.3 * rate_of_clear_field()) {
            wrong.push((led, rate));
        }
    }
    wrong
}

/// The counts per ms of a clear field on the virtual camera.
pub fn rate_of_clear_field() -> f32 {
    let c = fpm_physics::simulate::Camera::realistic();
    (c.electrons_per_ms * c.gain_dn_per_e) as f32
}

/// Copy the dataset in `from` (its files and `frames/`) to `to`.
pub fn copy_dataset(from: &Path, to: &Path) {
    std::fs::create_dir_all(to.join("frames")).unwrap();
    for dir in [PathBuf::new(), PathBuf::from("frames")] {
        for entry in std::fs::read_dir(from.join(&dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.is_file() {
                std::fs::copy(&path, to.join(&dir).join(path.file_name().unwrap())).unwrap();
            }
        }
    }
}

pub use foreign::foreign_device;

/// Devices on the serial link that are not our firmware's current version.
pub mod foreign {
    use std::io::{Read, Write};
    use std::os::fd::AsFd;
    use std::time::{Duration, Instant};

    use fpm_protocol::{ProtocolVersion, VersionEndpoint, WireError};
    use postcard_rpc::header::VarSeq;
    use postcard_rpc::Endpoint;

    use crate::wire::{frame, frames};

    /// A stand-in for other firmware on a pseudo-terminal (a board flashed with another
    /// protocol version, or a device that is no fpm controller): answers the version
    /// request with `version`, or everything with `UnknownKey` when `version` is `None`,
    /// for a minute. Returns its thread, the port's path and the pair (keep it: the port
    /// closes with it).
    pub fn foreign_device(
        version: Option<ProtocolVersion>,
    ) -> (std::thread::JoinHandle<()>, String, nix::pty::OpenptyResult) {
        let pair = nix::pty::openpty(None, None).unwrap();
        let mut t = nix::sys::termios::tcgetattr(pair.slave.as_fd()).unwrap();
        nix::sys::termios::cfmakeraw(&mut t);
        nix::sys::termios::tcsetattr(pair.slave.as_fd(), nix::sys::termios::SetArg::TCSANOW, &t)
            .unwrap();
        let path = nix::unistd::ttyname(pair.slave.as_fd())
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let mut master = std::fs::File::from(pair.master.try_clone().unwrap());
        let handle = std::thread::spawn(move || {
            let mut buf = [0u8; 512];
            let mut acc = vec![];
            let deadline = Instant::now() + Duration::from_secs(60);
            while Instant::now() < deadline {
                let n = match master.read(&mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                acc.extend_from_slice(&buf[..n]);
                if !acc.contains(&0) {
                    continue;
                }
                for (hdr, _) in frames(&acc) {
                    let VarSeq::Seq4(seq) = hdr.seq_no else {
                        continue;
                    };
                    let reply = match version {
                        Some(v)
                            if hdr.key
                                == postcard_rpc::header::VarKey::Key8(VersionEndpoint::REQ_KEY) =>
                        {
                            frame(
                                VersionEndpoint::RESP_KEY,
                                seq,
                                &postcard::to_stdvec(&v).unwrap(),
                            )
                        }
                        _ => frame(
                            postcard_rpc::standard_icd::ERROR_KEY,
                            seq,
                            &postcard::to_stdvec(&WireError::UnknownKey).unwrap(),
                        ),
                    };
                    if master.write_all(&reply).is_err() {
                        return;
                    }
                }
                acc.clear();
            }
        });
        (handle, path, pair)
    }
}
