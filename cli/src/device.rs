//! `fpm device …`: one command per controller endpoint, human-readable or JSON.

use std::time::Duration;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use fpm_protocol::*;
use indicatif::{ProgressBar, ProgressStyle};

use fpm_acquire::board_geometry;
use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_acquire::controller::{discover, Controller, SequenceEvent};

/// Talk to an LED controller.
#[derive(Args, Debug)]
pub struct DeviceArgs {
    /// Serial port of the controller (e.g. /dev/ttyACM0, or an emulator's --link path).
    /// Omitted: the one board connected (see `fpm device list`).
    #[arg(long, env = "FPM_PORT")]
    port: Option<String>,
    /// Print machine-readable JSON instead of text.
    #[arg(long, global = true)]
    json: bool,
    /// Per-request timeout in milliseconds.
    #[arg(long, default_value_t = 1000, global = true)]
    timeout_ms: u64,
    #[command(subcommand)]
    command: DeviceCommand,
}

#[derive(Subcommand, Debug)]
enum DeviceCommand {
    /// Boards connected: USB serial ports with the controller's vendor and product id
    /// (1209:0001), plus the ports listed in FPM_EXTRA_PORTS (an emulator's link, an
    /// RS-232 adapter; separated by ':'), each with its serial number and protocol.
    List,
    /// Identity: firmware, protocol, board geometry, limits.
    Info,
    /// State: what is lit, current, budget, sequence, link counters.
    Status,
    /// Round-trip a few pings.
    Ping {
        /// How many.
        #[arg(long, default_value_t = 10)]
        count: u32,
    },
    /// Light one LED, everything else off.
    Led {
        /// Grid row (0-based).
        row: u8,
        /// Grid column (0-based).
        col: u8,
        /// Colour: white, red, green, blue, #rrggbb or r,g,b.
        #[arg(long, default_value = "white", value_parser = crate::color::parse)]
        color: Rgb,
    },
    /// Light several LEDs given as ROW,COL.
    Leds {
        /// LEDs as ROW,COL (e.g. 10,10 10,11).
        #[arg(required = true, value_parser = parse_led)]
        leds: Vec<LedIndex>,
        /// Colour.
        #[arg(long, default_value = "white", value_parser = crate::color::parse)]
        color: Rgb,
        /// Keep what is already lit.
        #[arg(long)]
        add: bool,
    },
    /// Light a pattern computed on the device from its geometry.
    Pattern {
        #[command(subcommand)]
        pattern: PatternArg,
        /// Colour.
        #[arg(long, default_value = "white", value_parser = crate::color::parse, global = true)]
        color: Rgb,
    },
    /// Everything off.
    Off,
    /// Set the global brightness (0-255).
    Brightness {
        /// Level.
        level: u8,
    },
    /// Gamma correction of the LED colours (smart-leds' table, for colours as the eye
    /// sees them): on, off, or show. Off (the default) keeps light proportional to the
    /// value, as quantitative imaging wants.
    Gamma {
        /// on or off; omit to show the setting.
        #[arg(value_parser = ["on", "off"])]
        state: Option<String>,
    },
    /// Set the current budget.
    Budget {
        /// Limit in mA (at most the board's rating).
        #[arg(long)]
        limit_ma: u32,
        /// Dim requests that exceed it instead of refusing them.
        #[arg(long)]
        scale: bool,
    },
    /// Upload and run an LED scan, printing every step as the device reports it.
    RunSequence(RunSequenceArgs),
    /// Abort the running sequence.
    Abort,
    /// State of the sequence engine.
    SequenceStatus,
    /// Flash a UF2 image (or the firmware's ELF; with none, this checkout's firmware,
    /// built now) onto the board in place: the image checked as the boot ROM
    /// reads it, the board restarted in BOOTSEL (protocol ≥ 1.3; a board already in
    /// BOOTSEL is flashed as it is), the image written over the boot ROM's PICOBOOT
    /// interface and read back (or copied onto its RPI-RP2 drive), and the board
    /// waited for until it answers in this host's protocol.
    Flash(FlashArgs),
    /// Restart the board in the RP2040 boot ROM's USB mode (BOOTSEL) without unplugging
    /// it: its RPI-RP2 drive appears, onto which a UF2 image is copied (a running
    /// sequence is aborted and every LED turned off first; protocol ≥ 1.3).
    Bootsel,
    /// The array geometry stored on the board (Δx, Δy, θ, h with their σ, the date and
    /// the fit residual of the calibration): show it, store one, or forget it.
    Geometry {
        /// Store the geometry of this calibration.json (from `fpm calibrate` or `fpm
        /// acquire --calibrate`, or the minimal four-key form).
        #[arg(long, value_name = "CALIBRATION_JSON")]
        set: Option<std::path::PathBuf>,
        /// Forget the stored geometry.
        #[arg(long, conflicts_with = "set")]
        clear: bool,
    },
}

/// `fpm device flash`'s arguments.
#[derive(clap::Args, Debug, Clone)]
pub struct FlashArgs {
    /// The image: a UF2 file, or the firmware's ELF (converted as `fpm-fwtool uf2`
    /// does). Omitted: the firmware of the checkout this fpm was built from, built now
    /// (`cargo build --release` in firmware/rp2040) for the board's data lanes.
    pub image: Option<std::path::PathBuf>,
    /// With no image: build the image for this many data lanes (1, 2 or 4) instead of
    /// the board's (a board that does not answer, as one in BOOTSEL, gets 1).
    #[arg(long, conflicts_with = "image")]
    pub lanes: Option<u8>,
    /// Where the board's boot drive is mounted (default: found among the mounted
    /// file systems by its INFO_UF2.TXT). Given, the image goes onto the drive.
    #[arg(long)]
    pub drive: Option<std::path::PathBuf>,
    /// An emulated boot ROM's PICOBOOT socket (the virtual rig's, `fpm_rig::boot_rom`),
    /// looked for as the board's boot device.
    #[arg(long, value_name = "SOCKET")]
    pub boot_rom_socket: Option<std::path::PathBuf>,
    /// How long to wait for the boot device, and for the board to come back, s.
    #[arg(long, default_value_t = 30)]
    pub wait_s: u64,
}

impl FlashArgs {
    /// Flashing `image` on the board at `port` (None: the one connected).
    fn options(&self, image: std::path::PathBuf, port: Option<String>) -> fpm_flash::Options {
        fpm_flash::Options {
            image,
            port,
            drive: self.drive.clone(),
            boot_rom_socket: self.boot_rom_socket.clone(),
            timeout: Duration::from_secs(self.wait_s),
        }
    }
}

#[derive(Subcommand, Debug, Clone, Copy)]
enum PatternArg {
    /// LEDs with illumination NA ≤ --na.
    Brightfield {
        /// Numerical aperture.
        #[arg(long)]
        na: f32,
    },
    /// LEDs with illumination NA > --na.
    Darkfield {
        /// Numerical aperture.
        #[arg(long)]
        na: f32,
    },
    /// LEDs with --inner < NA ≤ --outer.
    Annulus {
        /// Inner NA.
        #[arg(long)]
        inner: f32,
        /// Outer NA.
        #[arg(long)]
        outer: f32,
    },
    /// Half of the bright-field disc, for differential phase contrast.
    Dpc {
        /// Numerical aperture.
        #[arg(long)]
        na: f32,
        /// Which half.
        #[arg(long)]
        half: HalfArg,
    },
    /// Every LED.
    All,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum HalfArg {
    Top,
    Bottom,
    Left,
    Right,
}

impl From<PatternArg> for Pattern {
    fn from(p: PatternArg) -> Pattern {
        match p {
            PatternArg::Brightfield { na } => Pattern::BrightField { na },
            PatternArg::Darkfield { na } => Pattern::DarkField { na },
            PatternArg::Annulus { inner, outer } => Pattern::Annulus { inner, outer },
            PatternArg::Dpc { na, half } => Pattern::HalfCircle {
                na,
                half: match half {
                    HalfArg::Top => Half::Top,
                    HalfArg::Bottom => Half::Bottom,
                    HalfArg::Left => Half::Left,
                    HalfArg::Right => Half::Right,
                },
            },
            PatternArg::All => Pattern::All,
        }
    }
}

#[derive(ValueEnum, Debug, Clone, Copy, PartialEq)]
enum SelectArg {
    /// Every LED on the board.
    All,
    /// LEDs within --na.
    BrightField,
    /// LEDs beyond --na.
    DarkField,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum PolarityArg {
    High,
    Low,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
enum EdgeArg {
    Rising,
    Falling,
}

/// An LED scan as a capture sequence.
#[derive(Args, Debug)]
struct RunSequenceArgs {
    /// Which LEDs to visit.
    #[arg(long, value_enum, default_value_t = SelectArg::All)]
    select: SelectArg,
    /// NA bounding --select bright-field / dark-field.
    #[arg(long, default_value_t = 0.1)]
    na: f32,
    /// Visiting order.
    #[arg(long, value_enum, default_value_t = OrderArg::Nearest)]
    order: OrderArg,
    /// Colour of every LED.
    #[arg(long, default_value = "white", value_parser = crate::color::parse)]
    color: Rgb,
    /// LED settling time before the trigger, µs.
    #[arg(long, default_value_t = 500)]
    settle_us: u32,
    /// Light-on time after the trigger when not waiting for the camera, µs.
    #[arg(long, default_value_t = 10_000)]
    exposure_us: u32,
    /// Trigger-out pulse width, µs (0: no trigger pulse).
    #[arg(long, default_value_t = 100)]
    trigger_pulse_us: u32,
    /// Trigger-out delay after the settle time, µs.
    #[arg(long, default_value_t = 0)]
    trigger_delay_us: u32,
    /// Trigger-out polarity.
    #[arg(long, value_enum, default_value_t = PolarityArg::High)]
    trigger_polarity: PolarityArg,
    /// Wait for this edge on the trigger input (camera exposure signal) to end each step.
    #[arg(long, value_enum)]
    wait_trigger_in: Option<EdgeArg>,
    /// Longest wait for the camera's edge, ms.
    #[arg(long, default_value_t = 1000)]
    trigger_timeout_ms: u32,
    /// Leave the last LED lit at the end.
    #[arg(long)]
    keep_lit: bool,
    /// Sequence id echoed in every event (default: from the clock).
    #[arg(long)]
    id: Option<u32>,
}

fn parse_led(s: &str) -> Result<LedIndex, String> {
    let (r, c) = s
        .split_once(',')
        .ok_or_else(|| format!("'{s}' is not ROW,COL"))?;
    let row = r
        .trim()
        .parse()
        .map_err(|_| format!("'{r}' is not a row number (0-255)"))?;
    let col = c
        .trim()
        .parse()
        .map_err(|_| format!("'{c}' is not a column number (0-255)"))?;
    Ok(LedIndex::new(row, col))
}

/// Run one `fpm device` command.
pub fn run(args: DeviceArgs) -> Result<()> {
    let timeout = Duration::from_millis(args.timeout_ms);
    let port = match (&args.command, args.port) {
        (DeviceCommand::List, _) => return list(timeout, args.json),
        (DeviceCommand::Flash(f), port) => return flash_command(f, port, args.json),
        (_, Some(port)) => port,
        (_, None) => discover::the_only_board(timeout).map_err(anyhow::Error::msg)?,
    };
    let dev = Controller::open(&port, timeout)?;
    let json = args.json;
    if let DeviceCommand::Bootsel = args.command {
        let (board, serial) = (dev.info().board.to_string(), dev.info().serial);
        dev.reboot_to_bootsel()?;
        let said =
            serde_json::json!({"port": port, "board": board, "serial": serial, "bootsel": true});
        emit(&said, json, |_| {
            println!(
                "{board} (serial {serial:#x}) on {port} is restarting in BOOTSEL: its RPI-RP2 drive appears within seconds; copy fpm-led-controller.uf2 onto it (docs/hardware.md), and the board restarts with that firmware"
            )
        });
        return Ok(());
    }
    match args.command {
        // Answered above (without opening a port, or handing the port over).
        DeviceCommand::List | DeviceCommand::Bootsel | DeviceCommand::Flash(_) => {}
        DeviceCommand::Info => emit(dev.info(), json, print_info),
        DeviceCommand::Status => emit(&dev.status()?, json, print_status),
        DeviceCommand::Ping { count } => ping(&dev, count, json)?,
        DeviceCommand::Led { row, col, color } => emit(
            &dev.set_led(LedIndex::new(row, col), color)?,
            json,
            print_lit,
        ),
        DeviceCommand::Leds { leds, color, add } => {
            emit(&dev.set_leds(&leds, color, add)?, json, print_lit)
        }
        DeviceCommand::Pattern { pattern, color } => {
            emit(&dev.pattern(pattern.into(), color)?, json, print_lit)
        }
        DeviceCommand::Off => emit(&dev.clear()?, json, print_lit),
        DeviceCommand::Brightness { level } => emit(&dev.set_brightness(level)?, json, print_lit),
        DeviceCommand::Gamma { state } => {
            let on = dev.gamma(state.as_deref().map(|s| s == "on"))?;
            emit(&on, json, |on| {
                println!("gamma correction {}", if *on { "on" } else { "off" })
            });
        }
        DeviceCommand::Budget { limit_ma, scale } => {
            let policy = if scale {
                BudgetPolicy::Scale
            } else {
                BudgetPolicy::Refuse
            };
            let b = dev.set_budget(BudgetConfig { limit_ma, policy })?;
            emit(&b, json, |b| {
                println!("budget {} mA, {:?} above it", b.limit_ma, b.policy)
            });
        }
        DeviceCommand::RunSequence(seq) => run_sequence(&dev, seq, json)?,
        DeviceCommand::Abort => emit(&dev.abort_sequence()?, json, print_sequence_status),
        DeviceCommand::SequenceStatus => emit(&dev.sequence_status()?, json, print_sequence_status),
        DeviceCommand::Geometry { set, clear } => geometry(&dev, set.as_deref(), clear, json)?,
    }
    Ok(())
}

/// `fpm device geometry`: what the board stores, after storing or forgetting if asked.
fn geometry(
    dev: &Controller,
    set: Option<&std::path::Path>,
    clear: bool,
    json: bool,
) -> Result<()> {
    let stored = if let Some(path) = set {
        let nominal = fpm_acquire::pipeline::nominal_geometry(dev);
        let record = board_geometry::from_calibration_file(path, &nominal)?;
        dev.store_calibration(Some(record))?
    } else if clear {
        dev.store_calibration(None)?
    } else {
        dev.stored_calibration()?
    };
    #[derive(serde::Serialize)]
    struct Report<'a> {
        serial: u64,
        calibrated: bool,
        damaged: bool,
        calibration: Option<&'a BoardCalibration>,
        description: String,
    }
    let report = Report {
        serial: dev.info().serial,
        calibrated: matches!(stored, StoredCalibration::Calibrated(_)),
        damaged: matches!(stored, StoredCalibration::Damaged),
        calibration: match &stored {
            StoredCalibration::Calibrated(c) => Some(c),
            _ => None,
        },
        description: board_geometry::describe_stored(&stored),
    };
    emit(&report, json, |r| {
        let verb = if set.is_some() {
            "stored: "
        } else if clear {
            "forgotten: "
        } else {
            ""
        };
        println!("board {:#x}: {verb}{}", r.serial, r.description)
    });
    Ok(())
}

/// `fpm device flash`: the image given, or the firmware of this checkout built for
/// the board's data lanes (`--lanes` otherwise).
fn flash_command(f: &FlashArgs, port: Option<String>, json: bool) -> Result<()> {
    // A built or converted image's scratch directory lives until the flash is done.
    let (image, _scratch) = match &f.image {
        Some(image) if is_elf(image) => {
            let (dir, uf2) = uf2_of_elf(image)?;
            (uf2, Some(dir))
        }
        Some(image) => (image.clone(), None),
        None => {
            let (dir, image) = build_firmware(f.lanes, port.as_deref())?;
            (image, Some(dir))
        }
    };
    flash(&f.options(image, port), json)
}

/// Whether `path` starts as an ELF file does (a UF2 block starts otherwise).
fn is_elf(path: &std::path::Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok_and(|()| magic == *b"\x7fELF")
}

/// The UF2 of the ELF image at `elf` (as `fpm-fwtool uf2` writes it), in a scratch
/// directory.
fn uf2_of_elf(elf: &std::path::Path) -> Result<(tempfile::TempDir, std::path::PathBuf)> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let segments = fpm_fwtool::segments(&bytes).with_context(|| format!("{}", elf.display()))?;
    let dir = tempfile::tempdir()?;
    let name = elf.with_extension("uf2");
    let path = dir.path().join(
        name.file_name()
            .unwrap_or(std::ffi::OsStr::new("image.uf2")),
    );
    std::fs::write(
        &path,
        fpm_fwtool::uf2::encode(&segments, fpm_fwtool::uf2::RP2040_FAMILY),
    )?;
    Ok((dir, path))
}

/// The firmware of the checkout this fpm was built from, built for `lanes` data lanes
/// (None: the board's, asked on `port`), as a UF2 in a scratch directory.
fn build_firmware(
    lanes: Option<u8>,
    port: Option<&str>,
) -> Result<(tempfile::TempDir, std::path::PathBuf)> {
    let timeout = Duration::from_secs(2);
    let board = || -> Option<u8> {
        let port = match port {
            Some(p) => p.to_owned(),
            None => discover::the_only_board(timeout).ok()?,
        };
        Some(Controller::open(&port, timeout).ok()?.info().geometry.lanes)
    };
    let (lanes, whose) = match lanes {
        Some(n) => (n, "as asked"),
        None => match board() {
            Some(n) => (n, "the board's"),
            None => (1, "no board answers; --lanes for another"),
        },
    };
    let checkout = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    eprintln!(
        "no image given: building the firmware of {} for {lanes} data lane(s) ({whose})",
        checkout.display()
    );
    let uf2 = fpm_fwtool::build::build_uf2(&checkout, lanes)?;
    let name = fpm_fwtool::build::elf_path(&checkout, lanes)?
        .with_extension("uf2")
        .file_name()
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| "fpm-led-controller.uf2".into());
    let dir = tempfile::tempdir()?;
    let path = dir.path().join(name);
    std::fs::write(&path, uf2)?;
    Ok((dir, path))
}

/// Print `value` as one line of JSON, or as text.
/// `fpm device flash`: each step said as it is done (on stderr with --json), then what
/// was flashed.
fn flash(options: &fpm_flash::Options, json: bool) -> Result<()> {
    use fpm_flash::{BootDeviceKind as Via, Step};
    let mut bar: Option<indicatif::ProgressBar> = None;
    let mut said = |step: Step| {
        let line = match step {
            Step::Checked => "image checked (UF2 for the RP2040, inside its flash, its boot loader's CRC holding)",
            Step::Restarting => "board restarting in BOOTSEL",
            Step::BootDeviceFound(Via::Picoboot) => "boot ROM's PICOBOOT interface found",
            Step::BootDeviceFound(Via::Drive) => "boot drive found",
            Step::Writing(w) => {
                let bar = bar.get_or_insert_with(|| {
                    crate::progress::counter("[4/5] writing", "pages written and read back")
                });
                crate::progress::advance(bar, w.pages, w.of);
                return;
            }
            Step::Written(Via::Picoboot) => {
                if let Some(bar) = bar.take() {
                    bar.finish_and_clear();
                }
                "image written and read back, the boot loader's page last; board restarting"
            }
            Step::Written(Via::Drive) => {
                "image copied onto the boot drive; the boot ROM writes it and restarts"
            }
            Step::Back => "board answering with the new firmware",
        };
        eprintln!("[{}/5] {line}", step.number());
    };
    let done = fpm_flash::flash(options, &mut said)?;
    emit(&done, json, |d| {
        let before = d
            .before
            .as_ref()
            .map_or("a board in BOOTSEL".to_string(), |(f, p)| {
                format!("firmware {f} (protocol {p})")
            });
        let how = match d.via {
            Via::Picoboot => format!(
                "written over PICOBOOT ({}) and {} pages read back",
                d.boot_device, d.verified_pages
            ),
            Via::Drive => format!("copied onto {}", d.boot_device),
        };
        println!(
            "{}: {before} → firmware {} (protocol {}), {} blocks ({} KiB) {how}",
            d.port,
            d.after.0,
            d.after.1,
            d.image.blocks,
            d.image.flash_bytes / 1024,
        )
    });
    Ok(())
}

fn emit<T: serde::Serialize>(value: &T, json: bool, text: impl FnOnce(&T)) {
    if json {
        println!("{}", serde_json::to_string(value).unwrap_or_default());
    } else {
        text(value)
    }
}

fn print_info(i: &DeviceInfo) {
    let g = &i.geometry;
    println!("{} (serial {:#x})", i.board, i.serial);
    println!("  firmware {}, protocol {}", i.firmware, i.protocol);
    println!(
        "  LEDs     {} x {} ({}), pitch {:.3} mm, height {:.1} mm, centre ({}, {})",
        g.rows,
        g.cols,
        g.led_count(),
        g.pitch_um as f64 / 1000.0,
        g.height_um as f64 / 1000.0,
        g.center.row,
        g.center.col
    );
    println!(
        "  chain    from {:?}, along {:?}{}, {} lane(s)",
        g.chain.start,
        g.chain.major,
        if g.chain.serpentine {
            ", serpentine"
        } else {
            ""
        },
        g.lanes
    );
    println!(
        "  colours  red {} nm, green {} nm, blue {} nm",
        i.channels.red_nm, i.channels.green_nm, i.channels.blue_nm
    );
    println!(
        "  triggers {} out, {} in",
        i.triggers.outputs, i.triggers.inputs
    );
    let l = &i.limits;
    println!(
        "  current  {} mA max, {:.1} mA per channel at full value",
        l.max_current_ma,
        l.channel_current_ua as f64 / 1000.0
    );
    println!(
        "  limits   {}-byte frames, {} LEDs per list, {} steps per sequence ({} per chunk)",
        l.max_frame_len, l.max_leds_per_list, l.max_sequence_steps, l.max_steps_per_chunk
    );
    println!(
        "  timing   {:.1} µs per LED per lane, {} µs latch",
        l.led_shift_ns as f64 / 1000.0,
        l.latch_us
    );
}

fn print_status(s: &DeviceStatus) {
    println!("device time {:.6} s", s.now_us as f64 * 1e-6);
    println!(
        "  lit       {} LED(s), {} mA, brightness {}",
        s.leds_on, s.current_ma, s.brightness
    );
    println!(
        "  budget    {} mA ({:?} above it)",
        s.budget.limit_ma, s.budget.policy
    );
    let q = &s.sequence;
    println!(
        "  sequence  {:?}, id {}, {}/{} loaded, {} completed, last: {:?}",
        q.state, q.id, q.loaded, q.total, q.completed, q.last_outcome
    );
    let k = &s.link;
    println!(
        "  link      {} frames ok, {} dropped, {} unknown keys, {} decode errors",
        k.frames_ok, k.frames_dropped, k.unknown_keys, k.decode_errors
    );
}

fn print_lit(l: &Lit) {
    println!(
        "lit {} LED(s), {} mA, brightness {}{}, latched at {:.6} s",
        l.leds_on,
        l.current_ma,
        l.brightness,
        if l.scaled {
            " (dimmed to fit the current budget)"
        } else {
            ""
        },
        l.latched_us as f64 * 1e-6
    );
}

fn print_sequence_status(s: &SequenceStatus) {
    println!(
        "sequence {:?}: id {}, {}/{} steps loaded, {} completed, last outcome {:?}",
        s.state, s.id, s.loaded, s.total, s.completed, s.last_outcome
    );
}

fn ping(dev: &Controller, count: u32, json: bool) -> Result<()> {
    let stats = fpm_bench::Percentiles::of(&mut dev.ping_round_trips(0, count)?);
    if json {
        println!("{}", serde_json::to_string(&stats)?);
    } else {
        println!(
            "{count} pings to {}: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
            dev.port(),
            stats.p50_us,
            stats.p99_us,
            stats.max_us
        );
    }
    Ok(())
}

/// `--order`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum OrderArg {
    /// Increasing distance from the centre LED (the order EPRY updates in).
    Nearest,
    /// Row by row, left to right.
    Raster,
}

/// The sequence timing `a` asks for.
fn timing(a: &RunSequenceArgs) -> SequenceTiming {
    SequenceTiming {
        settle_us: a.settle_us,
        exposure_us: a.exposure_us,
        trigger_out: (a.trigger_pulse_us > 0).then_some(TriggerOut {
            delay_us: a.trigger_delay_us,
            pulse_us: a.trigger_pulse_us,
            polarity: match a.trigger_polarity {
                PolarityArg::High => Polarity::ActiveHigh,
                PolarityArg::Low => Polarity::ActiveLow,
            },
        }),
        trigger_in: a.wait_trigger_in.map(|e| TriggerIn {
            edge: match e {
                EdgeArg::Rising => Edge::Rising,
                EdgeArg::Falling => Edge::Falling,
            },
            timeout_us: a.trigger_timeout_ms.saturating_mul(1000),
        }),
        clear_at_end: !a.keep_lit,
    }
}

fn run_sequence(dev: &Controller, a: RunSequenceArgs, json: bool) -> Result<()> {
    let g = dev.info().geometry;
    let selection = match a.select {
        SelectArg::All => Selection::All,
        SelectArg::BrightField => Selection::Pattern(Pattern::BrightField { na: a.na }),
        SelectArg::DarkField => Selection::Pattern(Pattern::DarkField { na: a.na }),
    };
    let order = match a.order {
        OrderArg::Nearest => Order::Nearest,
        OrderArg::Raster => Order::Raster,
    };
    let steps = scan_steps(&g, selection, order, a.color);
    if steps.is_empty() {
        bail!(
            "the selection lights no LED on this {}x{} board",
            g.rows,
            g.cols
        );
    }
    let timing = timing(&a);
    let id = a.id.unwrap_or_else(|| {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs() as u32)
            .unwrap_or(1)
    });
    let bar = if json {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(steps.len() as u64).with_style(
            ProgressStyle::with_template(
                "{spinner} sequence {msg} [{bar:40}] {pos}/{len} steps ({eta} left)",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        )
    };
    bar.set_message(id.to_string());
    let run = dev
        .run_sequence(id, &steps, timing, |event| {
            if json {
                println!("{}", serde_json::to_string(event).unwrap_or_default());
            } else if matches!(event, SequenceEvent::Step(_)) {
                bar.inc(1);
            }
        })
        .inspect_err(|_| bar.abandon())?;
    bar.finish_and_clear();
    if !json {
        let secs = run.seconds();
        println!(
            "sequence {id}: {:?} after {}/{} steps, {secs:.3} s of device time ({:.2} ms per step)",
            run.end.outcome,
            run.end.completed,
            run.steps,
            secs * 1e3 / f64::from(run.end.completed.max(1))
        );
    }
    Ok(())
}

/// `fpm device list`.
fn list(timeout: Duration, json: bool) -> Result<()> {
    let found = discover::probe(discover::candidates(), timeout);
    if json {
        println!("{}", serde_json::to_string_pretty(&found)?);
        return Ok(());
    }
    if found.is_empty() {
        println!(
            "no LED controller found (USB {:04x}:{:04x}; ports named in {} are asked too)",
            USB_VID,
            USB_PID,
            discover::EXTRA_PORTS_ENV
        );
    }
    for f in &found {
        let usb = f
            .candidate
            .usb
            .as_ref()
            .map(|u| format!(" [USB {}]", u.vid_pid))
            .unwrap_or_default();
        match (&f.info, &f.error) {
            (Some(i), _) => println!(
                "{}{usb}: {} (serial {:016x}), firmware {}.{}.{}, protocol {}.{}",
                f.candidate.port,
                i.board.as_str(),
                i.serial,
                i.firmware.major,
                i.firmware.minor,
                i.firmware.patch,
                i.protocol.major,
                i.protocol.minor
            ),
            (None, e) => println!(
                "{}{usb}: no answer ({})",
                f.candidate.port,
                e.as_deref().unwrap_or("?")
            ),
        }
    }
    Ok(())
}
