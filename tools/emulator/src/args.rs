//! The emulator's options, shared by its event loop and the firmware-in-rp2040js
//! runner (`fpm emulator` parses them).

use std::path::PathBuf;

/// How to run the emulated LED controller behind a pseudo-terminal (`fpm emulator`'s
/// flags).
#[derive(Debug, Clone)]
pub struct EmulatorOptions {
    /// Make this path a symlink to the pseudo-terminal (open it like /dev/ttyACM0).
    pub link: PathBuf,
    /// LED grid rows.
    pub rows: u8,
    /// LED grid columns.
    pub cols: u8,
    /// Parallel data lanes the chain is split into.
    pub lanes: u8,
    /// The LED supply's current rating, mA.
    pub max_current_ma: u32,
    /// Serial number reported by the device.
    pub serial: u64,
    /// Emulated camera: exposure time, µs.
    pub camera_exposure_us: u64,
    /// Emulated camera: trigger to exposure start, µs.
    pub camera_latency_us: u64,
    /// No camera on the trigger lines (trigger-in waits then time out).
    pub no_camera: bool,
    /// Publish every trigger pulse, with the LEDs lit at that moment, on the iceoryx2
    /// virtual rig of this name (for `fpm virtual-camera --rig NAME`).
    pub rig: Option<String>,
    /// Keep the controller's flash (the stored board calibration) in this file, so it
    /// survives restarts like a real board's; created if missing. Without it the
    /// flash starts erased and is forgotten at exit.
    pub flash: Option<PathBuf>,
    /// With `firmware`: cut the emulated board's power after this many flash bytes
    /// are erased or programmed (the flash image keeps what was written; for testing
    /// that a stored calibration survives a power cut).
    pub power_cut_after: Option<u64>,
    /// Run this firmware image (the UF2 users flash) in an emulated RP2040 instead of
    /// the host-compiled controller logic (needs Node and `npm ci` in tools/rp2040).
    pub firmware: Option<PathBuf>,
    /// With `firmware`: keep the emulated RP2040's clock from running ahead of the wall
    /// clock. Unpaced, the emulator jumps through the firmware's sleeps and runs a
    /// sequence of 40 ms steps about six times faster than a board would, so a camera
    /// it triggers falls behind it as it never would behind a real board; the emulated
    /// time stays exact either way.
    pub real_time: bool,
    /// Answer the version request with this protocol version instead of the
    /// firmware's: a board flashed with other firmware, as the host's handshake sees
    /// it (for testing that every command refuses it with the way out).
    pub report_protocol: Option<fpm_protocol::ProtocolVersion>,
}
