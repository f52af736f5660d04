//! Helpers for tests that run the real programs: build and find the `fpm` binary,
//! start an emulated controller as a separate process, stop or kill it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

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
            "fpm-host",
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

/// `shared/data`: beside the repository (as CI has it), or where `FPM_SHARED` points.
pub fn shared_data() -> PathBuf {
    let candidates = [
        std::env::var("FPM_SHARED")
            .map(PathBuf::from)
            .unwrap_or_default(),
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"),
    ];
    candidates
        .into_iter()
        .find(|p| p.join("data").is_dir())
        .expect(
            "shared/ (with data/) must sit beside the repository, or FPM_SHARED must point to it",
        )
        .join("data")
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

/// A child process (e.g. `fpm virtual-camera`) stopped with SIGTERM, and reaped, when
/// dropped.
pub struct ChildGuard(pub Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.0.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let _ = self.0.wait();
    }
}

/// `fpm emulator` running as a child process.
pub struct Emulator {
    child: Option<Child>,
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
        let child = Command::new(fpm_bin())
            .arg("emulator")
            .arg("--link")
            .arg(link)
            .args(extra)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log_file)
            .spawn()
            .expect("starting the emulator");
        let mut me = Self {
            child: Some(child),
            link: link.to_path_buf(),
            log,
        };
        me.wait_ready(link);
        me
    }

    fn wait_ready(&mut self, link: &Path) {
        let deadline = Instant::now() + Duration::from_secs(20);
        // The emulator creates the link (atomically) only once it serves the terminal.
        loop {
            if let Ok(target) = std::fs::read_link(link) {
                if target.exists()
                    && self
                        .child
                        .as_mut()
                        .is_some_and(|c| c.try_wait().ok().flatten().is_none())
                {
                    return;
                }
            }
            if let Some(status) = self
                .child
                .as_mut()
                .and_then(|c| c.try_wait().ok().flatten())
            {
                panic!("emulator exited at start: {status}\n{}", self.log_text());
            }
            assert!(Instant::now() < deadline, "emulator did not become ready");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The link path as a port name.
    pub fn port(&self) -> String {
        self.link.to_string_lossy().into_owned()
    }

    /// Its log so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Kill it without warning (SIGKILL): the link stays behind, as after a crash.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Stop it cleanly (SIGTERM) and return its exit status.
    pub fn stop(&mut self) -> Option<std::process::ExitStatus> {
        let mut c = self.child.take()?;
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(c.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            if let Ok(Some(status)) = c.try_wait() {
                return Some(status);
            }
            if Instant::now() > deadline {
                let _ = c.kill();
                return c.wait().ok();
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.stop();
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
