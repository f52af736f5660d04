//! `fpm` subcommands as child processes (the emulated controller, the virtual camera),
//! for the demo and benchmarks.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// An emulator child process, stopped on drop.
pub struct EmulatorProcess {
    _child: ChildProcess,
    /// Its link path.
    pub link: PathBuf,
}

impl EmulatorProcess {
    /// Start `fpm emulator --link <tmp>` and wait until its link appears.
    pub fn start(extra: &[&str]) -> Result<Self> {
        let link = std::env::temp_dir().join(format!("fpm-emulator-{}.tty", std::process::id()));
        // A link left by a crashed run of this pid is replaced by the emulator itself.
        let link_arg = link.to_string_lossy().into_owned();
        let mut args = vec!["emulator", "--link", link_arg.as_str()];
        args.extend_from_slice(extra);
        let child = ChildProcess::spawn("emulator", &args, Some((&link, Duration::from_secs(10))))?;
        Ok(Self {
            _child: child,
            link,
        })
    }
}

/// Another `fpm` subcommand as a child process (e.g. the virtual camera), stopped
/// (SIGTERM) on drop.
pub struct ChildProcess {
    child: Child,
}

impl ChildProcess {
    /// Start `fpm <args>`; when `ready` = (file, timeout) is given, wait until that file
    /// exists.
    pub fn spawn(
        what: &str,
        args: &[&str],
        ready: Option<(&std::path::Path, Duration)>,
    ) -> Result<Self> {
        let exe = std::env::current_exe().context("locating the fpm executable")?;
        let child = Command::new(exe)
            .args(args)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting the {what}"))?;
        let mut me = Self { child };
        if let Some((path, timeout)) = ready {
            let deadline = Instant::now() + timeout;
            while !path.exists() {
                if let Some(status) = me.child.try_wait()? {
                    bail!("the {what} exited at start-up: {status}");
                }
                if Instant::now() > deadline {
                    bail!("the {what} was not ready within {timeout:?}");
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        Ok(me)
    }
}

impl Drop for ChildProcess {
    fn drop(&mut self) {
        // SIGTERM lets the emulator remove its link and the camera leave iceoryx2 cleanly.
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        let _ = self.child.wait();
    }
}
