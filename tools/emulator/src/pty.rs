//! The pseudo-terminal the emulator serves, and the symlink that names it.

use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

/// A pseudo-terminal pair. The emulator reads and writes the controller side; clients
/// open the device side by path. The emulator keeps its own handle on the device side
/// open, so clients can come and go without the controller side seeing a hang-up.
pub struct Pty {
    controller: OwnedFd,
    _device_side: OwnedFd,
    device_path: PathBuf,
}

impl Pty {
    /// Open a new pseudo-terminal in raw mode (no echo, no line discipline), with a
    /// non-blocking controller side.
    pub fn open() -> Result<Self> {
        let pair = nix::pty::openpty(None, None).context("opening a pseudo-terminal")?;
        let device_path =
            nix::unistd::ttyname(pair.slave.as_fd()).context("naming the pseudo-terminal")?;
        // A fresh terminal is in cooked mode: it would echo requests back and translate
        // CR/LF inside binary frames. Make it a clean byte pipe for every client.
        let mut t = tcgetattr(pair.slave.as_fd()).context("reading terminal attributes")?;
        cfmakeraw(&mut t);
        tcsetattr(pair.slave.as_fd(), SetArg::TCSANOW, &t).context("setting raw mode")?;
        let flags = OFlag::from_bits_truncate(fcntl(pair.master.as_raw_fd(), FcntlArg::F_GETFL)?);
        fcntl(
            pair.master.as_raw_fd(),
            FcntlArg::F_SETFL(flags | OFlag::O_NONBLOCK),
        )?;
        Ok(Self {
            controller: pair.master,
            _device_side: pair.slave,
            device_path,
        })
    }

    /// The device-side path (e.g. `/dev/pts/5`).
    pub fn device_path(&self) -> &Path {
        &self.device_path
    }

    /// The controller side, for polling.
    pub fn controller(&self) -> BorrowedFd<'_> {
        self.controller.as_fd()
    }

    /// Read what is available (0 bytes if nothing).
    pub fn read(&self, buf: &mut [u8]) -> Result<usize> {
        match nix::unistd::read(self.controller.as_raw_fd(), buf) {
            Ok(n) => Ok(n),
            Err(nix::errno::Errno::EAGAIN) | Err(nix::errno::Errno::EINTR) => Ok(0),
            Err(e) => Err(e).context("reading the pseudo-terminal"),
        }
    }

    /// Write a whole frame, or drop it if no client drains the terminal (as a USB
    /// device's transmit buffer overflows when the host does not read). Returns whether
    /// it went out.
    pub fn write_frame(&self, mut bytes: &[u8]) -> bool {
        let deadline = std::time::Instant::now() + std::time::Duration::from_millis(50);
        while !bytes.is_empty() {
            match nix::unistd::write(self.controller.as_fd(), bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(nix::errno::Errno::EAGAIN) | Err(nix::errno::Errno::EINTR) => {
                    if std::time::Instant::now() > deadline {
                        return false;
                    }
                    std::thread::sleep(std::time::Duration::from_micros(200));
                }
                Err(_) => return false,
            }
        }
        true
    }
}

/// A symlink at `link` pointing to `target`, removed again on drop. A stale symlink
/// from a crashed run is replaced; anything else at `link` is an error.
pub struct Link {
    path: PathBuf,
}

impl Link {
    pub fn create(link: &Path, target: &Path) -> Result<Self> {
        if let Ok(meta) = std::fs::symlink_metadata(link) {
            if !meta.file_type().is_symlink() {
                bail!(
                    "{} exists and is not a symlink; refusing to replace it",
                    link.display()
                );
            }
            std::fs::remove_file(link)
                .with_context(|| format!("removing stale link {}", link.display()))?;
        }
        // Create under a temporary name and rename, so a client never sees a half-made link.
        let tmp = link.with_extension(format!("tmp{}", std::process::id()));
        let _ = std::fs::remove_file(&tmp);
        std::os::unix::fs::symlink(target, &tmp)
            .with_context(|| format!("creating link {}", tmp.display()))?;
        std::fs::rename(&tmp, link).with_context(|| format!("creating link {}", link.display()))?;
        Ok(Self {
            path: link.to_path_buf(),
        })
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}
