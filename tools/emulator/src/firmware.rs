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

use fpm_firmware::{LedStrip, RGB8};

use crate::args::EmulatorOptions;
use crate::hardware::EmulatedStrip;
use crate::pty::{Link, Pty};

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
pub fn run_firmware(args: &EmulatorOptions, uf2: &Path) -> Result<()> {
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
    if args.lanes != 1 || args.rows != 21 || args.cols != 21 {
        tracing::warn!(
            "--lanes/--rows/--cols describe the host-compiled emulator; the firmware image has its own board"
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
    // The board's serial number is its flash chip's unique id.
    command.args(["--uid", &format!("{:016x}", args.serial)]);
    if let Some(image) = &args.flash {
        command.arg("--flash-image").arg(image);
    }
    if let Some(n) = args.power_cut_after {
        command.args(["--power-cut-after", &n.to_string()]);
    }
    if args.real_time {
        command.arg("--real-time");
    }
    let mut harness = Harness(
        command
            .spawn()
            .context("starting Node for the RP2040 emulator (is `node` installed?)")?,
    );
    let mut to_device = harness.0.stdin.take().context("harness stdin")?;
    let mut from_device = harness.0.stdout.take().context("harness stdout")?;
    let stderr = harness.0.stderr.take().context("harness stderr")?;
    // The harness's log, line by line; its "enumerated" line means the USB port is up,
    // its `event` lines are what the pins did.
    let (enumerated_tx, enumerated_rx) = mpsc::channel();
    let (events_tx, events) = mpsc::channel::<PinEvent>();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(json) = line.strip_prefix("event ") {
                match PinEvent::parse(json) {
                    Some(e) => {
                        let _ = events_tx.send(e);
                    }
                    None => tracing::warn!(target: "rp2040", "unreadable pin event: {json}"),
                }
                continue;
            }
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
    let rig = match &args.rig {
        Some(name) => Some(
            fpm_rig_bus::PulsePublisher::create(name)
                .with_context(|| format!("opening the virtual rig {name}"))?,
        ),
        None => None,
    };
    let mut pins = Pins::new(rig);
    let mut buf = [0u8; 4096];
    while !fpm_rig_bus::stop::requested() {
        pins.handle(events.try_iter());
        let mut fds = [
            PollFd::new(pty.controller(), PollFlags::POLLIN),
            PollFd::new(from_device.as_fd(), PollFlags::POLLIN),
        ];
        match nix::poll::poll(&mut fds, PollTimeout::from(5u16)) {
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
                return pins.emulator_ended(&events);
            }
            if !pty.write_frame(&buf[..n]) {
                tracing::warn!("no client is reading: dropped {n} byte(s) from the device");
            }
        }
    }
    // What the pins did just before the stop still counts (the log is read).
    std::thread::sleep(Duration::from_millis(100));
    pins.handle(events.try_iter());
    if let Some(line) = pins.round_trip_summary() {
        tracing::info!("{line}");
    }
    tracing::info!("RP2040 emulator stopped");
    Ok(())
}

/// The chain and the trigger line as seen at the pins, and where they are published.
struct Pins {
    strip: EmulatedStrip,
    rig: Option<fpm_rig_bus::PulsePublisher>,
    pulses: u64,
    /// When the trigger line last went high, µs.
    trigger_high_at: Option<u64>,
    /// Request round trips seen, emulated µs.
    round_trips_us: Vec<f64>,
    /// When the firmware handed over to the boot ROM's restart in BOOTSEL, emulated µs.
    bootsel_at_us: Option<f64>,
}

impl Pins {
    /// The reference board's chain, all off, publishing to `rig` if given.
    fn new(rig: Option<fpm_rig_bus::PulsePublisher>) -> Self {
        Self {
            strip: EmulatedStrip::new(fpm_firmware::BoardConfig::PICO_21X21.geometry),
            rig,
            pulses: 0,
            trigger_high_at: None,
            round_trips_us: vec![],
            bootsel_at_us: None,
        }
    }

    /// The harness ended (its output closed): as a board leaving its serial port for
    /// BOOTSEL when the firmware handed over to the boot ROM's restart there, else an
    /// error.
    fn emulator_ended(&mut self, events: &mpsc::Receiver<PinEvent>) -> Result<()> {
        // Its last events may still be on their way.
        std::thread::sleep(Duration::from_millis(100));
        self.handle(events.try_iter());
        match self.bootsel_at_us {
            Some(us) => {
                tracing::info!(
                    "the firmware restarted in BOOTSEL at {us:.0} µs (emulated), as asked: a board leaves its serial port here for the RP2040's boot device; the emulator stops"
                );
                Ok(())
            }
            None => bail!("the RP2040 emulator stopped"),
        }
    }

    /// One log line on the request round trips, for the end of a run.
    fn round_trip_summary(&self) -> Option<String> {
        let mut t = self.round_trips_us.clone();
        if t.is_empty() {
            return None;
        }
        t.sort_by(f64::total_cmp);
        let at = |q: f64| t[((t.len() - 1) as f64 * q).round() as usize];
        Some(format!(
            "USB request to reply, emulated: {} requests, p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
            t.len(),
            at(0.5),
            at(0.99),
            at(1.0)
        ))
    }

    /// A frame decoded at the data pins: logged per lane, then shown on the chain as
    /// the LEDs would show it (each lane's words from the start of its run of LEDs).
    fn latched(&mut self, lanes: &[LaneFrame]) {
        for lane in lanes {
            if lane.bad_pulses > 0 {
                tracing::warn!(
                    "WS2812 frame with {} malformed pulse(s) at GP{}",
                    lane.bad_pulses,
                    lane.pin
                );
            }
            if !lane.words.is_empty() {
                tracing::info!(
                    "WS2812 frame at GP{}: {} LEDs in {:.1} µs; {}",
                    lane.pin,
                    lane.words.len(),
                    lane.timing.shift_us,
                    lane.timing
                );
            }
        }
        let mut geometry = self.strip.geometry();
        geometry.lanes = lanes.len().clamp(1, fpm_firmware::chain::MAX_LANES) as u8;
        let lane_len = fpm_firmware::chain::lane_len(&geometry);
        let mut pixels = vec![RGB8::default(); self.strip.pixels().len()];
        let mut shift = vec![0u16; lanes.len()];
        for (k, lane) in lanes.iter().enumerate() {
            let start = (k * lane_len).min(pixels.len());
            let end = (start + lane_len).min(pixels.len());
            for (p, w) in pixels[start..end].iter_mut().zip(&lane.words) {
                // Shifted out green, red, blue.
                *p = RGB8::new((w >> 8) as u8, (w >> 16) as u8, *w as u8);
            }
            if lane.words.len() > lane_len {
                tracing::warn!(
                    "{} words at GP{} for a run of {lane_len} LEDs: the rest fell off the chain",
                    lane.words.len(),
                    lane.pin
                );
            }
            shift[k] = lane.words.len().min(lane_len) as u16;
        }
        LedStrip::write(&mut self.strip, &pixels, lane_len, &shift);
    }

    fn handle(&mut self, events: impl Iterator<Item = PinEvent>) {
        for event in events {
            match event {
                PinEvent::Latched(lanes) => self.latched(&lanes),
                PinEvent::Trigger { high: true, us } => {
                    self.trigger_high_at = Some(us);
                    if let Some(rig) = &self.rig {
                        let lit = self.strip.lit(fpm_rig_bus::MAX_LIT);
                        let pulse = fpm_rig_bus::TriggerPulse::new(
                            self.pulses,
                            us,
                            lit.into_iter()
                                .map(|(r, c, rgb)| (r, c, [rgb.r, rgb.g, rgb.b])),
                        );
                        if let Err(e) = rig.publish(&pulse) {
                            tracing::warn!("virtual rig: {e}");
                        }
                    }
                    self.pulses += 1;
                }
                PinEvent::Trigger { high: false, us } => {
                    // As measured at GP14, for comparison with the sequence's timing.
                    if let Some(at) = self.trigger_high_at.take() {
                        tracing::info!(
                            "trigger out at GP14: high at {at} µs for {} µs",
                            us.saturating_sub(at)
                        );
                    }
                }
                PinEvent::Flash => tracing::info!("the firmware wrote its flash"),
                PinEvent::RoundTrip(us) => self.round_trips_us.push(us),
                PinEvent::Bootsel { us, rom_entry } => {
                    tracing::info!(
                        "the firmware called the boot ROM's reset into BOOTSEL at {us:.0} µs: the ROM's reboot magic is in the watchdog, restart at ROM address {rom_entry:#x}"
                    );
                    self.bootsel_at_us = Some(us);
                }
                PinEvent::PowerCut => {
                    tracing::warn!("power cut during a flash write (--power-cut-after)")
                }
                PinEvent::Usb { vid, pid, strings } => {
                    let [manufacturer, product, serial] = strings.map(|s| s.unwrap_or_default());
                    tracing::info!(
                        "USB device {vid:04x}:{pid:04x}, manufacturer \"{manufacturer}\", product \"{product}\", serial \"{serial}\""
                    );
                }
            }
        }
    }
}

/// What the harness saw at the pins.
#[derive(Debug, Clone, PartialEq)]
enum PinEvent {
    /// A WS2812 frame latched: what each lane driven shifted out, in lane order.
    Latched(Vec<LaneFrame>),
    /// The device's USB identity, as a host reads it after enumeration.
    Usb {
        /// Vendor id.
        vid: u16,
        /// Product id.
        pid: u16,
        /// Strings: manufacturer, product, serial number.
        strings: [Option<String>; 3],
    },
    /// The firmware erased or programmed flash (the image file is up to date).
    Flash,
    /// A request's round trip, emulated µs: the USB packet ending its frame reaching
    /// the firmware → the first reply bytes leaving it.
    RoundTrip(f64),
    /// The board lost power mid-write (`--power-cut-after`); the harness has stopped.
    PowerCut,
    /// The firmware handed over to the boot ROM's restart in BOOTSEL (the reboot magic
    /// in the watchdog's scratch registers); the harness stops.
    Bootsel {
        /// When, emulated µs.
        us: f64,
        /// The ROM address the reboot restarts at (its USB boot).
        rom_entry: u64,
    },
    /// The camera trigger output changed, at emulated µs.
    Trigger {
        /// Its new level.
        high: bool,
        /// When, device clock, µs.
        us: u64,
    },
}

impl PinEvent {
    fn parse(json: &str) -> Option<Self> {
        let v: serde_json::Value = serde_json::from_str(json).ok()?;
        match v.get("type")?.as_str()? {
            "latched" => Some(PinEvent::Latched(
                v.get("lanes")?
                    .as_array()?
                    .iter()
                    .map(LaneFrame::parse)
                    .collect::<Option<_>>()?,
            )),
            "usb" => {
                let text = |k: &str| v.get(k).and_then(|s| s.as_str()).map(str::to_owned);
                Some(PinEvent::Usb {
                    vid: v.get("vid")?.as_u64()? as u16,
                    pid: v.get("pid")?.as_u64()? as u16,
                    strings: [text("manufacturer"), text("product"), text("serial")],
                })
            }
            "flash" => Some(PinEvent::Flash),
            "round-trip" => Some(PinEvent::RoundTrip(v.get("us")?.as_f64()?)),
            "power-cut" => Some(PinEvent::PowerCut),
            "bootsel" => Some(PinEvent::Bootsel {
                us: v.get("us")?.as_f64()?,
                rom_entry: v.get("rom_entry")?.as_u64()?,
            }),
            "trigger" => Some(PinEvent::Trigger {
                high: v.get("level")?.as_u64()? == 1,
                us: v.get("us")?.as_f64()?.round() as u64,
            }),
            _ => None,
        }
    }
}

/// One lane's part of a latched WS2812 frame, decoded at its pin.
#[derive(Debug, Clone, PartialEq)]
struct LaneFrame {
    /// The GPIO.
    pin: u8,
    /// The 24-bit GRB words shifted out, in chain order (none if the lane kept still).
    words: Vec<u32>,
    /// High pulses that were neither a 0 nor a 1 bit.
    bad_pulses: u64,
    /// The lane's timing as measured at its pin.
    timing: FrameTiming,
}

impl LaneFrame {
    fn parse(v: &serde_json::Value) -> Option<Self> {
        Some(Self {
            pin: u8::try_from(v.get("pin")?.as_u64()?).ok()?,
            words: v
                .get("words")?
                .as_array()?
                .iter()
                .map(|w| w.as_u64().and_then(|w| u32::try_from(w).ok()))
                .collect::<Option<_>>()?,
            bad_pulses: v.get("bad")?.as_u64()?,
            timing: FrameTiming::parse(v)?,
        })
    }
}

/// A WS2812 frame's timing at the pin, ns unless stated (ranges are shortest–longest).
#[derive(Debug, Clone, PartialEq)]
struct FrameTiming {
    /// First rise to last fall, µs.
    shift_us: f64,
    t0h_ns: Option<[u64; 2]>,
    t1h_ns: Option<[u64; 2]>,
    period_ns: Option<[u64; 2]>,
    /// Longest low between two bits of the frame.
    low_max_ns: u64,
    /// Low time since the previous frame, µs (the latch it had).
    gap_us: Option<f64>,
}

impl FrameTiming {
    fn parse(v: &serde_json::Value) -> Option<Self> {
        let range = |k: &str| -> Option<Option<[u64; 2]>> {
            match v.get(k)? {
                serde_json::Value::Null => Some(None),
                r => Some(Some([r.get(0)?.as_u64()?, r.get(1)?.as_u64()?])),
            }
        };
        Some(Self {
            shift_us: v.get("shift_us")?.as_f64()?,
            t0h_ns: range("t0h_ns")?,
            t1h_ns: range("t1h_ns")?,
            period_ns: range("period_ns")?,
            low_max_ns: v.get("low_max_ns")?.as_u64()?,
            gap_us: v.get("gap_us").and_then(|g| g.as_f64()),
        })
    }
}

impl std::fmt::Display for FrameTiming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let range = |r: Option<[u64; 2]>| match r {
            Some([a, b]) => format!("{a}-{b} ns"),
            None => "none".into(),
        };
        write!(
            f,
            "T0H {}, T1H {}, bit period {}, longest low inside {} ns, latch before it {}",
            range(self.t0h_ns),
            range(self.t1h_ns),
            range(self.period_ns),
            self.low_max_ns,
            match self.gap_us {
                Some(g) => format!("{g:.1} µs"),
                None => "n/a (first frame)".into(),
            }
        )
    }
}
