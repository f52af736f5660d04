//! Helpers for tests that run the real programs: build and find the `fpm` binary,
//! start rig processes (through `fpm_rig::process`, as the demo does), stop or kill
//! them.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;

/// The `fpm` executable, built with the same profile as the running test.
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
            .unwrap_or("debug");
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args([
            "build",
            "--quiet",
            "-p",
            "fpm-cli",
            "--bin",
            "fpm",
            "--message-format=json",
        ]);
        if profile != "debug" {
            cmd.args([
                "--profile",
                if profile == "release" {
                    "release"
                } else {
                    profile
                },
            ]);
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
            .filter(|v| v["reason"] == "compiler-artifact" && v["target"]["name"] == "fpm")
            .filter_map(|v| v["executable"].as_str().map(PathBuf::from))
            .next_back()
            .expect("cargo reported the fpm executable")
    })
}

/// The real data sets vendored in the repository (`data/`, each with its source and
/// licence in its README).
pub fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data")
}

/// A scratch directory removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    /// A new unique directory under the system temp dir.
    pub fn new(tag: &str) -> Self {
        static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let dir = std::env::temp_dir().join(format!("fpm-test-{tag}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("creating a temp dir");
        Self(dir)
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
