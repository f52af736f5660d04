//! `fpm emulator --firmware FILE.uf2`: the real firmware binary, the UF2 image users
//! drag onto their Pico, in an emulated RP2040 (rp2040js, driven by
//! `tools/rp2040/harness.mjs` under Node), behind the same pseudo-terminal as the
//! host-compiled emulator. The harness carries the firmware's USB CDC-ACM port on its
//! stdin/stdout; this relays it to the terminal, byte for byte, so the unchanged host
//! client talks to the real firmware as to a board.

use std::io::{BufRead, BufReader, Write};
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use nix::poll::{PollFd, PollFlags, PollTimeout};

use crate::pty::{Link, Pty};
use crate::run::EmulatorArgs;

/// The harness directory (its `package.json`, `harness.mjs`, `bootrom/`), in this
/// source tree; `FPM_RP2040_HARNESS` points elsewhere.
pub fn harness_dir() -> PathBuf {
    std::env::var_os("FPM_RP2040_HARNESS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../rp2040"))
}

/// How long the firmware may take to boot and enumerate on USB (emulated at a few
/// tenths of real time).
const ENUMERATION_TIMEOUT: Duration = Duration::from_secs(60);

/// The harness as a child process, killed on drop.
struct Harness(Child);

impl Drop for Harness {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Run the firmware in `uf2` until SIGINT/SIGTERM/SIGHUP.
pub fn run_firmware(args: &EmulatorArgs, uf2: &Path) -> Result<()> {
    let dir = harness_dir();
    let script = dir.join("harness.mjs");
    let bootrom = dir.join("bootrom/bootrom-b1.bin");
    if !dir.join("node_modules/rp2040js").is_dir() {
        bail!(
            "the RP2040 emulator is not installed: run `npm ci` in {} (Node >= 18)",
            dir.display()
        );
    }
    if !uf2.is_file() {
        bail!(
            "{}: no such firmware image (build it: cd firmware/rp2040 && cargo build --release, then fpm-fwtool uf2)",
            uf2.display()
        );
    }
    if args.lanes != 1 || args.rows != 21 || args.cols != 21 || args.rig.is_some() {
        tracing::warn!(
            "--lanes/--rows/--cols/--rig describe the host-compiled emulator; the firmware image has its own board"
        );
    }
    fpm_rig_bus::stop::install().context("installing signal handlers")?;
    let mut command = Command::new(std::env::var_os("FPM_NODE").unwrap_or_else(|| "node".into()));
    command
        .arg(&script)
        .arg("--uf2")
        .arg(uf2)
        .arg("--bootrom")
        .arg(&bootrom)
        .args(["--camera-latency-us", &args.camera_latency_us.to_string()])
        .args(["--camera-exposure-us", &args.camera_exposure_us.to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if args.no_camera {
        command.arg("--no-camera");
    }
    let mut harness = Harness(
        command
            .spawn()
            .context("starting Node for the RP2040 emulator (is `node` installed?)")?,
    );
    let mut to_device = harness.0.stdin.take().context("harness stdin")?;
    let mut from_device = harness.0.stdout.take().context("harness stdout")?;
    let stderr = harness.0.stderr.take().context("harness stderr")?;
    // The harness's log, line by line; its "enumerated" line means the USB port is up.
    let (enumerated_tx, enumerated_rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if line.contains("USB CDC-ACM enumerated") {
                let _ = enumerated_tx.send(());
            }
            tracing::info!(target: "rp2040", "{line}");
        }
    });
    let started = Instant::now();
    loop {
        if enumerated_rx
            .recv_timeout(Duration::from_millis(50))
            .is_ok()
        {
            break;
        }
        if let Some(status) = harness.0.try_wait()? {
            bail!("the RP2040 emulator exited before the firmware enumerated on USB: {status}");
        }
        if started.elapsed() > ENUMERATION_TIMEOUT || fpm_rig_bus::stop::requested() {
            bail!(
                "the firmware did not enumerate on USB within {ENUMERATION_TIMEOUT:?} of emulation"
            );
        }
    }
    let pty = Pty::open()?;
    let _link = Link::create(&args.link, pty.device_path())?;
    tracing::info!(
        "real firmware {} running in the RP2040 emulator, USB CDC-ACM on {} (linked at {}), enumerated after {:.1} s",
        uf2.display(),
        pty.device_path().display(),
        args.link.display(),
        started.elapsed().as_secs_f64()
    );
    let mut buf = [0u8; 4096];
    while !fpm_rig_bus::stop::requested() {
        let mut fds = [
            PollFd::new(pty.controller(), PollFlags::POLLIN),
            PollFd::new(from_device.as_fd(), PollFlags::POLLIN),
        ];
        match nix::poll::poll(&mut fds, PollTimeout::from(100u16)) {
            Ok(_) | Err(nix::errno::Errno::EINTR) => {}
            Err(e) => return Err(e).context("waiting for the terminal or the emulator"),
        }
        let host_ready = fds[0]
            .revents()
            .is_some_and(|r| r.contains(PollFlags::POLLIN));
        let device_ready = fds[1]
            .revents()
            .is_some_and(|r| r.intersects(PollFlags::POLLIN | PollFlags::POLLHUP));
        if host_ready {
            let n = pty.read(&mut buf)?;
            if n > 0 {
                to_device
                    .write_all(&buf[..n])
                    .context("writing to the RP2040 emulator")?;
            }
        }
        if device_ready {
            let n = std::io::Read::read(&mut from_device, &mut buf)
                .context("reading from the RP2040 emulator")?;
            if n == 0 {
                bail!("the RP2040 emulator stopped");
            }
            if !pty.write_frame(&buf[..n]) {
                tracing::warn!("no client is reading: dropped {n} byte(s) from the device");
            }
        }
    }
    tracing::info!("RP2040 emulator stopped");
    Ok(())
}
