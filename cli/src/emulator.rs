//! `fpm emulator`: the emulated LED controller on a pseudo-terminal ([`fpm_emulator`]).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

/// Run the emulated LED controller behind a pseudo-terminal.
#[derive(Args, Debug, Clone)]
pub struct EmulatorArgs {
    /// Make this path a symlink to the pseudo-terminal (open it like /dev/ttyACM0).
    #[arg(long)]
    pub link: PathBuf,
    /// LED grid rows.
    #[arg(long, default_value_t = 21)]
    pub rows: u8,
    /// LED grid columns.
    #[arg(long, default_value_t = 21)]
    pub cols: u8,
    /// Parallel data lanes the chain is split into.
    #[arg(long, default_value_t = 1)]
    pub lanes: u8,
    /// The LED supply's current rating, mA.
    #[arg(long, default_value_t = 4000)]
    pub max_current_ma: u32,
    /// Serial number reported by the device.
    #[arg(long, default_value_t = 0x0E30_1A7E)]
    pub serial: u64,
    /// Emulated camera: exposure time, µs.
    #[arg(long, default_value_t = 10_000)]
    pub camera_exposure_us: u64,
    /// Emulated camera: trigger to exposure start, µs.
    #[arg(long, default_value_t = 20)]
    pub camera_latency_us: u64,
    /// No camera on the trigger lines (trigger-in waits then time out).
    #[arg(long)]
    pub no_camera: bool,
    /// Publish every trigger pulse, with the LEDs lit at that moment, on the iceoryx2
    /// virtual rig of this name (for `fpm virtual-camera --rig NAME`).
    #[arg(long)]
    pub rig: Option<String>,
    /// Keep the controller's flash (the stored board calibration) in this file, so it
    /// survives restarts like a real board's; created if missing. Without it the
    /// flash starts erased and is forgotten at exit.
    #[arg(long)]
    pub flash: Option<PathBuf>,
    /// With --firmware: cut the emulated board's power after this many flash bytes
    /// are erased or programmed (the flash image keeps what was written; for testing
    /// that a stored calibration survives a power cut).
    #[arg(long, requires = "firmware")]
    pub power_cut_after: Option<u64>,
    /// Run this firmware image (the UF2 users flash) in an emulated RP2040 instead of
    /// the host-compiled controller logic (needs Node and `npm ci` in tools/rp2040).
    #[arg(long)]
    pub firmware: Option<PathBuf>,
    /// With --firmware: keep the emulated RP2040's clock from running ahead of the wall
    /// clock, as a board's cannot (unpaced, it jumps through the firmware's sleeps and
    /// runs sequences several times faster than real time).
    #[arg(long, requires = "firmware")]
    pub real_time: bool,
    /// Answer the version request with this protocol version (MAJOR.MINOR) instead of
    /// the firmware's: a board flashed with other firmware, as the host's version
    /// handshake sees it (for trying what each command says to it).
    #[arg(long, value_name = "MAJOR.MINOR", value_parser = parse_protocol, conflicts_with = "firmware")]
    pub report_protocol: Option<fpm_protocol::ProtocolVersion>,
}

/// A protocol version written MAJOR.MINOR.
fn parse_protocol(text: &str) -> Result<fpm_protocol::ProtocolVersion, String> {
    let (major, minor) = text
        .split_once('.')
        .ok_or_else(|| format!("{text:?}: write it MAJOR.MINOR, e.g. 1.2"))?;
    let number = |s: &str| {
        s.parse::<u16>()
            .map_err(|e| format!("{text:?}: {s:?} is no version number ({e})"))
    };
    Ok(fpm_protocol::ProtocolVersion {
        major: number(major)?,
        minor: number(minor)?,
    })
}

/// Run it.
pub fn run(a: EmulatorArgs) -> Result<()> {
    fpm_emulator::run(fpm_emulator::EmulatorOptions {
        link: a.link,
        rows: a.rows,
        cols: a.cols,
        lanes: a.lanes,
        max_current_ma: a.max_current_ma,
        serial: a.serial,
        camera_exposure_us: a.camera_exposure_us,
        camera_latency_us: a.camera_latency_us,
        no_camera: a.no_camera,
        rig: a.rig,
        flash: a.flash,
        power_cut_after: a.power_cut_after,
        firmware: a.firmware,
        real_time: a.real_time,
        report_protocol: a.report_protocol,
    })
}
