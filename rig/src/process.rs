//! Rig processes (the controller emulator, the virtual camera, any `fpm` subcommand)
//! as children: started, waited for until ready, stopped with SIGTERM on drop (so the
//! emulator removes its link and the camera leaves iceoryx2 cleanly) or killed like a
//! crash. The demo, the benchmarks and the tests all start them through this.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// When a started process counts as ready.
#[derive(Debug, Clone, Copy)]
pub enum Ready<'a> {
    /// At once.
    Started,
    /// Once this file exists (a process writes it last when it is listening).
    FileExists(&'a Path, Duration),
    /// Once this symbolic link points to an existing file (the emulator creates its
    /// link, atomically, only once it serves the terminal).
    LinkServes(&'a Path, Duration),
}

/// A child process, stopped (SIGTERM, then SIGKILL after 5 s) and reaped on drop.
pub struct ChildProcess {
    child: Option<Child>,
    what: String,
}

impl ChildProcess {
    /// Start `command` (named `what` in errors) and wait until it is `ready`.
    pub fn start(mut command: Command, what: &str, ready: Ready<'_>) -> Result<Self> {
        // The child is told to stop when its parent dies, even by SIGKILL: a rig's
        // processes never outlive what started them.
        // SAFETY: prctl is async-signal-safe; nothing else runs between fork and exec.
        unsafe {
            use std::os::unix::process::CommandExt;
            command.pre_exec(|| {
                nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM)
                    .map_err(std::io::Error::from)
            });
        }
        let child = command
            .spawn()
            .with_context(|| format!("starting the {what}"))?;
        let mut me = Self {
            child: Some(child),
            what: what.into(),
        };
        let (path, timeout, is_ready): (&Path, Duration, fn(&Path) -> bool) = match ready {
            Ready::Started => return Ok(me),
            Ready::FileExists(p, t) => (p, t, |p| p.exists()),
            Ready::LinkServes(p, t) => (p, t, |p| {
                std::fs::read_link(p).is_ok_and(|target| target.exists())
            }),
        };
        let deadline = Instant::now() + timeout;
        while !is_ready(path) {
            if let Some(status) = me.try_wait() {
                bail!("the {what} exited at start-up: {status}");
            }
            if Instant::now() > deadline {
                bail!("the {what} was not ready within {timeout:?}");
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        if let Some(status) = me.try_wait() {
            bail!("the {what} exited at start-up: {status}");
        }
        Ok(me)
    }

    /// `fpm <args>` from the executable `fpm`, output discarded, logging at `warn`.
    pub fn fpm(fpm: &Path, args: &[&str], what: &str, ready: Ready<'_>) -> Result<Self> {
        let mut command = Command::new(fpm);
        command
            .args(args)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null());
        Self::start(command, what, ready)
    }

    /// Its process id.
    pub fn id(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    /// Its exit status, if it has exited.
    pub fn try_wait(&mut self) -> Option<ExitStatus> {
        self.child
            .as_mut()
            .and_then(|c| c.try_wait().ok().flatten())
    }

    /// Kill it without warning (SIGKILL), as a crash would: it leaves its link, shared
    /// memory and files behind.
    pub fn kill(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Stop it cleanly (SIGTERM; SIGKILL after 5 s) and return its exit status.
    pub fn stop(&mut self) -> Option<ExitStatus> {
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
                tracing::warn!("the {} did not stop on SIGTERM; killing it", self.what);
                let _ = c.kill();
                return c.wait().ok();
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for ChildProcess {
    fn drop(&mut self) {
        self.stop();
    }
}

/// `fpm emulator --link <link> <extra>` as a child process, ready once its link serves.
pub struct EmulatorProcess {
    /// The process.
    pub process: ChildProcess,
    /// Its link path (a serial port name for clients).
    pub link: PathBuf,
}

impl EmulatorProcess {
    /// Start the emulator of the executable `fpm` at `link`, its log to `stderr`.
    pub fn start_at(fpm: &Path, link: &Path, extra: &[&str], stderr: Stdio) -> Result<Self> {
        // A link left by a crashed emulator goes first (the new one would replace it
        // anyway): its pseudo-terminal's number is free for any process on the
        // machine to get, so the old link can point at someone else's live terminal
        // and look ready before this emulator has made its own.
        if std::fs::symlink_metadata(link).is_ok_and(|meta| meta.file_type().is_symlink()) {
            std::fs::remove_file(link)
                .with_context(|| format!("removing the stale link {}", link.display()))?;
        }
        let mut command = Command::new(fpm);
        command
            .arg("emulator")
            .arg("--link")
            .arg(link)
            .args(extra)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(stderr);
        let process = ChildProcess::start(
            command,
            "emulator",
            Ready::LinkServes(link, Duration::from_secs(20)),
        )?;
        Ok(Self {
            process,
            link: link.to_path_buf(),
        })
    }

    /// Start this executable's emulator at a link under the temp dir named by our pid
    /// (a link left by a crashed run of this pid is replaced by the emulator itself).
    pub fn start(extra: &[&str]) -> Result<Self> {
        let fpm = std::env::current_exe().context("locating the fpm executable")?;
        let link = std::env::temp_dir().join(format!("fpm-emulator-{}.tty", std::process::id()));
        Self::start_at(&fpm, &link, extra, Stdio::null())
    }

    /// The link path as a port name.
    pub fn port(&self) -> String {
        self.link.to_string_lossy().into_owned()
    }
}

/// `fpm virtual-camera` on a virtual rig as a child process, ready once it has written
/// the hidden truth (it does so last, once it listens to the rig).
pub struct VirtualCameraProcess {
    /// The process.
    pub process: ChildProcess,
    /// Where its truth.json (and the truth images) are.
    pub truth_dir: PathBuf,
}

impl VirtualCameraProcess {
    /// Start the virtual camera of the executable `fpm` on rig `rig`, publishing as
    /// camera `camera`, its truth written into `truth_dir`, with `extra` flags
    /// (`--size`, `--seed`, fault injection, …).
    pub fn start(
        fpm: &Path,
        rig: &str,
        camera: &str,
        truth_dir: &Path,
        extra: &[&str],
    ) -> Result<Self> {
        let mut command = Command::new(fpm);
        command
            .args([
                "virtual-camera",
                "--rig",
                rig,
                "--camera",
                camera,
                "--truth-dir",
            ])
            .arg(truth_dir)
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null());
        let ready = truth_dir.join("truth.json");
        let process = ChildProcess::start(
            command,
            "virtual camera",
            Ready::FileExists(&ready, Duration::from_secs(30)),
        )?;
        Ok(Self {
            process,
            truth_dir: truth_dir.to_path_buf(),
        })
    }
}

/// How to make the firmware image a virtual rig runs, for the error naming a missing one.
pub const BUILD_FIRMWARE_IMAGE: &str = "build the image with `cargo build --release` in firmware/rp2040, then `cargo run -p fpm-fwtool -- uf2 ELF UF2`; docs/hardware.md";

/// The whole virtual rig as children: the emulated controller and the virtual camera on
/// one rig bus (its stage is moved through that bus by whoever opens a
/// [`crate::stage::VirtualStage`] on it).
pub struct VirtualRig {
    /// The bus's name (the camera's too).
    pub name: String,
    /// The emulated controller.
    pub emulator: EmulatorProcess,
    /// The virtual camera.
    pub camera: VirtualCameraProcess,
    /// How they were started (to start them again).
    fpm: PathBuf,
    dir: PathBuf,
    emulator_args: Vec<String>,
    camera_args: Vec<String>,
}

impl VirtualRig {
    /// Start it from the executable `fpm`, its link and the camera's truth in `dir`, the
    /// camera with `camera_args` (`--size`, `--seed`, …).
    pub fn start(fpm: &Path, name: &str, dir: &Path, camera_args: &[&str]) -> Result<Self> {
        Self::start_with_firmware(fpm, name, dir, None, camera_args)
    }

    /// [`Self::start`], the controller the real firmware image `firmware` (a UF2) in an
    /// emulated RP2040 paced to the wall clock (`fpm emulator --firmware --real-time`)
    /// when given, else the host-compiled controller logic.
    pub fn start_with_firmware(
        fpm: &Path,
        name: &str,
        dir: &Path,
        firmware: Option<&Path>,
        camera_args: &[&str],
    ) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let mut emulator_args: Vec<String> = ["--rig", name, "--camera-exposure-us", "2000"]
            .map(String::from)
            .to_vec();
        if let Some(uf2) = firmware {
            if !uf2.is_file() {
                bail!(
                    "the firmware image {}: no such file ({BUILD_FIRMWARE_IMAGE})",
                    uf2.display()
                );
            }
            // Paced to the wall clock, as a board is: unpaced, the emulator runs the
            // sequence several times faster and the camera falls far behind it.
            emulator_args.extend([
                "--firmware".into(),
                uf2.to_string_lossy().into_owned(),
                "--real-time".into(),
            ]);
        }
        let emulator = Self::start_emulator(fpm, dir, &emulator_args)?;
        let camera = VirtualCameraProcess::start(fpm, name, name, &dir.join("truth"), camera_args)?;
        Ok(Self {
            name: name.into(),
            emulator,
            camera,
            fpm: fpm.to_path_buf(),
            dir: dir.to_path_buf(),
            emulator_args,
            camera_args: camera_args.iter().map(|a| a.to_string()).collect(),
        })
    }

    fn start_emulator(fpm: &Path, dir: &Path, args: &[String]) -> Result<EmulatorProcess> {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        EmulatorProcess::start_at(fpm, &dir.join("controller.tty"), &args, Stdio::null())
    }

    /// Start again whichever of its processes has exited (killed, crashed), as a board
    /// plugged back in or a camera driver restarted would come back; what was restarted,
    /// in words. The camera comes back with the same scene (its truth is written anew).
    pub fn revive(&mut self) -> Result<Vec<&'static str>> {
        let mut revived = vec![];
        if let Some(status) = self.emulator.process.try_wait() {
            tracing::warn!("the virtual rig's controller exited ({status}); starting it again");
            self.emulator = Self::start_emulator(&self.fpm, &self.dir, &self.emulator_args)?;
            revived.push("controller");
        }
        if let Some(status) = self.camera.process.try_wait() {
            tracing::warn!("the virtual rig's camera exited ({status}); starting it again");
            let truth = self.dir.join("truth");
            // Its readiness is the truth it writes last.
            let _ = std::fs::remove_file(truth.join("truth.json"));
            let args: Vec<&str> = self.camera_args.iter().map(String::as_str).collect();
            self.camera =
                VirtualCameraProcess::start(&self.fpm, &self.name, &self.name, &truth, &args)?;
            revived.push("camera");
        }
        Ok(revived)
    }
}
