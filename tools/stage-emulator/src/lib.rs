//! # fpm-stage-emulator: stage firmware without the stage
//!
//! Each emulator speaks one firmware's serial protocol on a pseudo-terminal, as the
//! board does over USB, so the drivers in `fpm-stage` (or a terminal program) talk to
//! it by path: [`Kind::Grbl`] (GRBL 1.1h: `ok`/`error:N`, `?` status reports, `$$`,
//! `$H`, soft limits as `ALARM:2`, the alarm lock at start-up, 0x18 reset),
//! [`Kind::Marlin`] (Marlin 2: `ok`, `M114`, `M211`, `M400`, `G28`, busy messages, soft
//! end stops that clamp silently, `kill()`), and [`Kind::Sangaboard`] (firmware v1:
//! `mr` blocking until `done.`, `p?`, `version`, `dt?`, `moving?`). The mechanics are
//! shared ([`motion::Axes`]): straight moves at a set speed and play in the drive.
//! The test hooks read the carriage's true position, the lines received, and inject
//! faults (a limit switch, a halt, the cable pulled).

mod grbl;
mod marlin;
pub mod motion;
mod sangaboard;

use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::Result;
use fpm_emulator::pty::{Link, Pty};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

/// Which firmware to emulate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Grbl,
    Marlin,
    Sangaboard,
}

impl std::str::FromStr for Kind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "grbl" => Ok(Kind::Grbl),
            "marlin" => Ok(Kind::Marlin),
            "sangaboard" => Ok(Kind::Sangaboard),
            _ => Err(format!("`{s}`: give grbl, marlin or sangaboard")),
        }
    }
}

/// The emulated stage.
#[derive(Debug, Clone)]
pub struct Config {
    pub kind: Kind,
    /// Top speed per axis, µm/s (GRBL's `$110`–`$112`; a Sangaboard's follows from its
    /// step delay and step size instead).
    pub speed_um_s: [f64; 3],
    /// Travel per axis, µm (GRBL: [−travel, 0] after homing; Marlin: [0, travel]).
    pub travel_um: [f64; 3],
    /// Play in each axis's drive, µm.
    pub backlash_um: [f64; 3],
    /// Soft limits on (GRBL `$20`, Marlin `M211`).
    pub soft_limits: bool,
    /// Homing on (GRBL `$22`): GRBL then starts locked in its alarm state until homed.
    pub homing: bool,
    /// The motors' count at power-on, µm.
    pub start_um: [f64; 3],
    /// Sangaboard: µm per motor step on each axis.
    pub um_per_step: [f64; 3],
    /// Sangaboard: µs per step.
    pub step_delay_us: f64,
}

impl Config {
    /// A small stage of `kind`: 20 × 20 × 5 mm of travel, 10 mm/s in X and Y and
    /// 2 mm/s in Z, no play, soft limits and homing on, switched on mid-travel.
    pub fn new(kind: Kind) -> Self {
        let start_um = match kind {
            Kind::Grbl => [-10_000.0, -10_000.0, -2_500.0],
            Kind::Marlin => [10_000.0, 10_000.0, 2_500.0],
            Kind::Sangaboard => [0.0; 3],
        };
        Self {
            kind,
            speed_um_s: [10_000.0, 10_000.0, 2_000.0],
            travel_um: [20_000.0, 20_000.0, 5_000.0],
            backlash_um: [0.0; 3],
            soft_limits: true,
            homing: true,
            start_um,
            um_per_step: [0.5, 0.5, 0.1],
            step_delay_us: 50.0,
        }
    }
}

/// Faults to inject.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// A limit switch closes: motion stops (GRBL `ALARM:1`, Marlin `endstops hit`).
    LimitSwitch,
    /// The firmware halts (Marlin `kill()`; GRBL as a limit switch) and answers no more.
    Halt,
}

/// What every emulated firmware does with time and bytes (sans-IO: the runner owns the
/// terminal and the clock).
pub(crate) trait Firmware: Send {
    /// Bytes from the host, at `now` s.
    fn receive(&mut self, now: f64, bytes: &[u8], out: &mut Vec<u8>);
    /// Time passes: finish moves, send what is due.
    fn tick(&mut self, now: f64, out: &mut Vec<u8>);
    /// The mechanics.
    fn axes(&self) -> &motion::Axes;
    /// A fault happens.
    fn fault(&mut self, now: f64, fault: Fault, out: &mut Vec<u8>);
}

/// Split received bytes into lines (`\n` ends one, `\r` ignored).
#[derive(Debug, Default)]
pub(crate) struct Lines {
    partial: Vec<u8>,
}

impl Lines {
    pub(crate) fn push(&mut self, b: u8) -> Option<String> {
        match b {
            b'\n' => Some(String::from_utf8_lossy(&std::mem::take(&mut self.partial)).into_owned()),
            b'\r' => None,
            _ => {
                // Boards have small line buffers; an endless line must not grow forever.
                if self.partial.len() < 256 {
                    self.partial.push(b);
                }
                None
            }
        }
    }
}

struct Shared {
    firmware: Box<dyn Firmware>,
    received: Vec<String>,
    log: Lines,
    out: Vec<u8>,
    started: Instant,
}

impl Shared {
    fn now(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

/// A running emulator: a thread serving a pseudo-terminal.
pub struct Emulator {
    path: PathBuf,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _link: Option<Link>,
}

impl Emulator {
    /// Start emulating `config` on a new pseudo-terminal; with `link`, a symlink to it.
    pub fn start(config: Config, link: Option<&Path>) -> Result<Self> {
        let pty = Pty::open()?;
        let path = pty.device_path().to_path_buf();
        let link = link.map(|l| Link::create(l, &path)).transpose()?;
        let firmware: Box<dyn Firmware> = match config.kind {
            Kind::Grbl => Box::new(grbl::Grbl::new(&config)),
            Kind::Marlin => Box::new(marlin::Marlin::new(&config)),
            Kind::Sangaboard => Box::new(sangaboard::Sangaboard::new(&config)),
        };
        let shared = Arc::new(Mutex::new(Shared {
            firmware,
            received: Vec::new(),
            log: Lines::default(),
            out: Vec::new(),
            started: Instant::now(),
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("stage-emulator".into())
                .spawn(move || serve(pty, shared, stop))?
        };
        Ok(Self {
            path,
            shared,
            stop,
            thread: Some(thread),
            _link: link,
        })
    }

    /// The terminal's path, for the driver.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Where the carriage really is, µm (the motors' count plus the play).
    pub fn mechanical_um(&self) -> [f64; 3] {
        self.with(|s| s.firmware.axes().mechanical)
    }

    /// Where the motors are, µm (what the firmware reports).
    pub fn motor_um(&self) -> [f64; 3] {
        self.with(|s| s.firmware.axes().motor)
    }

    /// Whether a move is under way.
    pub fn moving(&self) -> bool {
        self.with(|s| s.firmware.axes().moving())
    }

    /// Every line received so far.
    pub fn received(&self) -> Vec<String> {
        self.with(|s| s.received.clone())
    }

    /// Make `fault` happen now.
    pub fn inject(&self, fault: Fault) {
        self.with(|s| {
            let now = s.now();
            let mut out = std::mem::take(&mut s.out);
            s.firmware.fault(now, fault, &mut out);
            s.out = out;
        })
    }

    /// Pull the cable: the terminal goes away under the driver.
    pub fn unplug(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }

    fn with<T>(&self, f: impl FnOnce(&mut Shared) -> T) -> T {
        let mut guard = match self.shared.lock() {
            Ok(g) => g,
            Err(poisoned) => poisoned.into_inner(),
        };
        f(&mut guard)
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.unplug();
    }
}

fn serve(pty: Pty, shared: Arc<Mutex<Shared>>, stop: Arc<AtomicBool>) {
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::SeqCst) {
        let fd = pty.controller();
        let mut fds = [PollFd::new(fd.as_fd(), PollFlags::POLLIN)];
        let _ = poll(&mut fds, PollTimeout::from(2u8));
        let n = pty.read(&mut buf).unwrap_or(0);
        let out = {
            let mut s = match shared.lock() {
                Ok(g) => g,
                Err(poisoned) => poisoned.into_inner(),
            };
            let now = s.now();
            let mut out = std::mem::take(&mut s.out);
            if n > 0 {
                // Keep a log of whole lines for the tests.
                for &b in &buf[..n] {
                    if let Some(l) = s.log.push(b) {
                        s.received.push(l);
                    }
                }
                s.firmware.receive(now, &buf[..n], &mut out);
            }
            s.firmware.tick(now, &mut out);
            out
        };
        if !out.is_empty() {
            pty.write_frame(&out);
        }
    }
}
