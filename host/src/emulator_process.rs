//! The emulated controller as a child process, for the demo and benchmarks.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// An emulator child process, stopped on drop.
pub struct EmulatorProcess {
    child: Child,
    /// Its link path.
    pub link: PathBuf,
}

impl EmulatorProcess {
    /// Start `fpm emulator --link <tmp>` and wait until its link appears.
    pub fn start(extra: &[&str]) -> Result<Self> {
        let exe = std::env::current_exe().context("locating the fpm executable")?;
        let link = std::env::temp_dir().join(format!("fpm-emulator-{}.tty", std::process::id()));
        // A link left by a crashed run of this pid is replaced by the emulator itself.
        let child = Command::new(exe)
            .arg("emulator")
            .arg("--link")
            .arg(&link)
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .context("starting the emulator")?;
        let mut me = Self { child, link };
        let deadline = Instant::now() + Duration::from_secs(10);
        while !me.link.exists() {
            if let Some(status) = me.child.try_wait()? {
                bail!("the emulator exited at start-up: {status}");
            }
            if Instant::now() > deadline {
                bail!(
                    "the emulator did not create {} within 10 s",
                    me.link.display()
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(me)
    }
}

impl Drop for EmulatorProcess {
    fn drop(&mut self) {
        let _ = nix_kill(self.child.id());
        let _ = self.child.wait();
    }
}

/// Another `fpm` subcommand as a child process (e.g. the virtual camera), stopped
/// (SIGTERM) on drop.
pub struct ChildProcess {
    child: Child,
}

impl ChildProcess {
    /// Start `fpm <args>`; when `ready` is given, wait until that file exists.
    pub fn spawn(what: &str, args: &[&str], ready: Option<&std::path::Path>) -> Result<Self> {
        let exe = std::env::current_exe().context("locating the fpm executable")?;
        let child = Command::new(exe)
            .args(args)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting the {what}"))?;
        let mut me = Self { child };
        if let Some(path) = ready {
            let deadline = Instant::now() + Duration::from_secs(30);
            while !path.exists() {
                if let Some(status) = me.child.try_wait()? {
                    bail!("the {what} exited at start-up: {status}");
                }
                if Instant::now() > deadline {
                    bail!("the {what} was not ready within 30 s");
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        Ok(me)
    }
}

impl Drop for ChildProcess {
    fn drop(&mut self) {
        let _ = nix_kill(self.child.id());
        let _ = self.child.wait();
    }
}

fn nix_kill(pid: u32) -> std::io::Result<()> {
    // SIGTERM lets the emulator remove its link.
    let status = Command::new("kill")
        .arg("-TERM")
        .arg(pid.to_string())
        .status()?;
    if status.success() {
        Ok(())
    } else {
        Err(std::io::Error::other("kill failed"))
    }
}
