//! # fpm-flash
//!
//! `fpm device flash IMAGE.uf2`: the LED controller's firmware updated without taking
//! the board out of the rig. The steps, each its own error with the way out:
//!
//! 1. the image is checked as the RP2040's boot ROM will read it (UF2 blocks, the
//!    RP2040's family id, every block inside the 2 MiB flash), so a wrong file fails
//!    before the board goes dark;
//! 2. the board (the one connected, or `port`) is asked to restart in BOOTSEL
//!    (protocol 1.3), or a board already in BOOTSEL (a new Pico) is used as it is;
//! 3. its boot drive (`RPI-RP2`, with `INFO_UF2.TXT`) is waited for among the mounted
//!    file systems, or taken where the caller says it is mounted;
//! 4. the image is copied onto it and synced, which the boot ROM writes to flash and
//!    restarts from;
//! 5. the board is waited for on its serial port and must answer in this host's
//!    protocol.
//!
//! What cannot be done here: PICOBOOT (the boot ROM's vendor interface, for writing and
//! reading back without a mounted drive) is not spoken yet, so the image is not read
//! back; the boot ROM checks each block as it writes it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use fpm_acquire::controller::{discover, Controller, ControllerError};
use serde::Serialize;

/// The RP2040's UF2 family id.
pub const RP2040_FAMILY: u32 = 0xE48B_FF56;
const MAGIC_START0: u32 = 0x0A32_4655;
const MAGIC_START1: u32 = 0x9E5D_5157;
const MAGIC_END: u32 = 0x0AB1_6F30;
const FLAG_NOT_MAIN_FLASH: u32 = 0x0000_0001;
const FLAG_FAMILY_ID: u32 = 0x0000_2000;
/// Where the RP2040 maps its flash, and the Pico's 2 MiB of it.
const FLASH: std::ops::Range<u32> = 0x1000_0000..0x1020_0000;
/// The file the boot drive carries that names it.
const INFO: &str = "INFO_UF2.TXT";

/// A UF2 image as the boot ROM will take it.
#[derive(Debug, Clone, Serialize)]
pub struct Image {
    /// Where it was read from.
    pub path: PathBuf,
    /// Its blocks.
    pub blocks: usize,
    /// Flash bytes it writes.
    pub flash_bytes: usize,
    /// Its lowest and highest flash addresses.
    pub range: (u32, u32),
}

/// A step that failed, and what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum FlashError {
    /// The image is not one the RP2040's boot ROM takes.
    #[error("{path}: {why}; build the image with `cargo run -p fpm-fwtool -- uf2 ELF OUT.uf2` (docs/hardware.md)")]
    Image {
        /// The file.
        path: PathBuf,
        /// What is wrong with it, naming the byte or block.
        why: String,
    },
    /// No board to restart, and none waiting in BOOTSEL.
    #[error(
        "finding the board: {0}; or hold BOOTSEL while plugging the Pico in and run this again"
    )]
    NoBoard(String),
    /// The board would not restart in BOOTSEL.
    #[error("restarting the board in BOOTSEL: {0}")]
    Bootsel(ControllerError),
    /// No boot drive appeared.
    #[error("waiting for the board's boot drive (RPI-RP2): none mounted within {waited_s} s; mount it (desktops do so by themselves; else `sudo mount /dev/disk/by-label/RPI-RP2 /mnt`) and give --drive")]
    NoBootDrive {
        /// How long it was waited for, s.
        waited_s: u64,
    },
    /// The image could not be written onto the drive.
    #[error("copying the image onto {drive}: {source}; check that the drive is mounted writable, then run this again (the board stays in BOOTSEL)")]
    Copy {
        /// The drive's mount point.
        drive: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The board did not come back on its serial port.
    #[error("waiting for the board to restart with the new firmware on {port}: {why} after {waited_s} s; if its RPI-RP2 drive is still there, the boot ROM refused the image: unplug and replug the board, and check the image")]
    NotBack {
        /// The port waited on.
        port: String,
        /// The last error opening it.
        why: String,
        /// How long, s.
        waited_s: u64,
    },
}

/// Check `path` as the RP2040's boot ROM would read it: whole 512-byte UF2 blocks,
/// both start magics and the end magic in each, the RP2040's family id, 256-byte
/// payloads inside its 2 MiB flash, and the blocks' count.
pub fn check_image(path: &Path) -> Result<Image, FlashError> {
    let bad = |why: String| FlashError::Image {
        path: path.to_owned(),
        why,
    };
    let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot be read ({e})")))?;
    if bytes.is_empty() || !bytes.len().is_multiple_of(512) {
        return Err(bad(format!(
            "{} bytes is not a whole number of 512-byte UF2 blocks",
            bytes.len()
        )));
    }
    let mut range = (u32::MAX, 0u32);
    let mut flash_bytes = 0;
    let blocks = bytes.len() / 512;
    for (n, block) in bytes.chunks_exact(512).enumerate() {
        let word =
            |k: usize| u32::from_le_bytes([block[k], block[k + 1], block[k + 2], block[k + 3]]);
        let at = n * 512;
        if word(0) != MAGIC_START0 || word(4) != MAGIC_START1 || word(508) != MAGIC_END {
            return Err(bad(format!(
                "block {n} (byte {at}): not a UF2 block (its magic numbers are wrong)"
            )));
        }
        let (flags, address, size, total) = (word(8), word(12), word(16), word(24));
        if flags & FLAG_NOT_MAIN_FLASH != 0 {
            continue;
        }
        if flags & FLAG_FAMILY_ID == 0 || word(28) != RP2040_FAMILY {
            return Err(bad(format!(
                "block {n} (byte {at}): family {:#010x}, not the RP2040's ({RP2040_FAMILY:#010x}): an image for another chip",
                word(28)
            )));
        }
        if size != 256 {
            return Err(bad(format!(
                "block {n} (byte {at}): {size} payload bytes; the RP2040's boot ROM takes 256"
            )));
        }
        let end = address.saturating_add(size);
        if !FLASH.contains(&address) || end > FLASH.end {
            return Err(bad(format!(
                "block {n} (byte {at}): address {address:#010x} outside the Pico's 2 MiB flash ({:#010x}–{:#010x}): the image is too large or not for flash",
                FLASH.start, FLASH.end
            )));
        }
        if total as usize != blocks {
            return Err(bad(format!(
                "block {n} (byte {at}): says {total} blocks, the file has {blocks}"
            )));
        }
        range = (range.0.min(address), range.1.max(end));
        flash_bytes += size as usize;
    }
    if flash_bytes == 0 {
        return Err(bad("no block writes flash".into()));
    }
    Ok(Image {
        path: path.to_owned(),
        blocks,
        flash_bytes,
        range,
    })
}

/// Whether `dir` is an RP2040's boot drive: it carries `INFO_UF2.TXT` naming the
/// board `RPI-RP2`.
pub fn is_boot_drive(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join(INFO)).is_ok_and(|t| t.contains("Board-ID: RPI-RP2"))
}

/// A mounted RP2040 boot drive, if one is (read from /proc/self/mounts).
pub fn mounted_boot_drive() -> Option<PathBuf> {
    let mounts = std::fs::read_to_string("/proc/self/mounts").ok()?;
    mounts
        .lines()
        .filter_map(|l| l.split_whitespace().nth(1))
        // Spaces in mount points are written as \040.
        .map(|p| PathBuf::from(p.replace("\\040", " ")))
        .find(|p| is_boot_drive(p))
}

/// What to flash and where.
#[derive(Debug, Clone)]
pub struct Options {
    /// The UF2 image.
    pub image: PathBuf,
    /// The board's serial port (None: the one board connected).
    pub port: Option<String>,
    /// Where the boot drive is mounted (None: found among the mounts).
    pub drive: Option<PathBuf>,
    /// How long each wait (the drive, the board's return) may take.
    pub timeout: Duration,
}

/// The steps, as they happen, for a progress display.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    /// The image is checked.
    Checked,
    /// The board was asked to restart in BOOTSEL.
    Restarting,
    /// Its boot drive is there.
    DriveFound,
    /// The image is on the drive.
    Copied,
    /// The board answered with the new firmware.
    Back,
}

/// What a flash did.
#[derive(Debug, Clone, Serialize)]
pub struct Flashed {
    /// The image written.
    pub image: Image,
    /// The boot drive it was copied onto.
    pub drive: PathBuf,
    /// The board's port.
    pub port: String,
    /// Its firmware and protocol before (None: it was found in BOOTSEL already).
    pub before: Option<(String, String)>,
    /// Its firmware and protocol now.
    pub after: (String, String),
}

/// Flash as `options` say, telling `progress` each step as it is done.
pub fn flash(options: &Options, progress: &mut dyn FnMut(Step)) -> Result<Flashed, FlashError> {
    let image = check_image(&options.image)?;
    progress(Step::Checked);
    let (port, before) = restart_in_bootsel(options)?;
    progress(Step::Restarting);
    let drive = wait_for_drive(options)?;
    progress(Step::DriveFound);
    copy_onto(&image.path, &drive)?;
    progress(Step::Copied);
    let port = match port {
        Some(p) => p,
        None => wait_for_port(options.timeout)?,
    };
    let dev = wait_for_board(&port, options.timeout)?;
    let info = dev.info();
    progress(Step::Back);
    Ok(Flashed {
        image,
        drive,
        after: (info.firmware.to_string(), info.protocol.to_string()),
        port,
        before,
    })
}

/// The board's port, and its firmware and protocol before (None when no board
/// answered but a boot drive was there already: a new Pico, or one left in BOOTSEL).
type Restarted = (Option<String>, Option<(String, String)>);

/// Ask the board to restart in BOOTSEL, or find one there already.
fn restart_in_bootsel(options: &Options) -> Result<Restarted, FlashError> {
    let timeout = Duration::from_secs(2);
    let port = match &options.port {
        Some(p) => p.clone(),
        None => match discover::the_only_board(timeout) {
            Ok(p) => p,
            Err(e) if boot_drive_now(options).is_some() => {
                tracing::info!("no board answers ({e}); a boot drive is there: flashing it");
                return Ok((None, None));
            }
            Err(e) => return Err(FlashError::NoBoard(e)),
        },
    };
    let dev = match Controller::open(&port, timeout) {
        Ok(dev) => dev,
        // Older firmware still restarts by hand; a version mismatch is what flashing
        // is for, but this firmware cannot be asked.
        Err(e) if boot_drive_now(options).is_some() => {
            tracing::info!("{port}: {e}; a boot drive is there: flashing it");
            return Ok((Some(port), None));
        }
        Err(e) => return Err(FlashError::Bootsel(e)),
    };
    let before = (
        dev.info().firmware.to_string(),
        dev.info().protocol.to_string(),
    );
    dev.reboot_to_bootsel().map_err(FlashError::Bootsel)?;
    Ok((Some(port), Some(before)))
}

fn boot_drive_now(options: &Options) -> Option<PathBuf> {
    match &options.drive {
        Some(d) => is_boot_drive(d).then(|| d.clone()),
        None => mounted_boot_drive(),
    }
}

fn wait_for_drive(options: &Options) -> Result<PathBuf, FlashError> {
    let deadline = Instant::now() + options.timeout;
    loop {
        if let Some(d) = boot_drive_now(options) {
            return Ok(d);
        }
        if Instant::now() >= deadline {
            return Err(FlashError::NoBootDrive {
                waited_s: options.timeout.as_secs(),
            });
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Copy `image` onto `drive` as one file, synced: the boot ROM writes each block to
/// flash as it arrives and restarts after the last.
fn copy_onto(image: &Path, drive: &Path) -> Result<(), FlashError> {
    let copy = || -> std::io::Result<()> {
        let name = image
            .file_name()
            .unwrap_or(std::ffi::OsStr::new("fpm-led-controller.uf2"));
        let mut out = std::fs::File::create(drive.join(name))?;
        std::io::copy(&mut std::fs::File::open(image)?, &mut out)?;
        out.sync_all()
    };
    copy().map_err(|source| FlashError::Copy {
        drive: drive.to_owned(),
        source,
    })
}

/// The port of the one board connected, for a board that was flashed from BOOTSEL
/// with no port known: it enumerates only once the boot ROM has restarted it.
fn wait_for_port(timeout: Duration) -> Result<String, FlashError> {
    let deadline = Instant::now() + timeout;
    loop {
        match discover::the_only_board(Duration::from_secs(2)) {
            Ok(port) => return Ok(port),
            Err(why) if Instant::now() >= deadline => {
                return Err(FlashError::NotBack {
                    port: "(the board's USB serial port)".into(),
                    why,
                    waited_s: timeout.as_secs(),
                })
            }
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
}

/// The board on `port` once it answers again, in this host's protocol.
fn wait_for_board(port: &str, timeout: Duration) -> Result<Controller, FlashError> {
    let deadline = Instant::now() + timeout;
    loop {
        match Controller::open(port, Duration::from_secs(2)) {
            Ok(dev) => return Ok(dev),
            // The new firmware speaks another protocol: flashed, but not usable here.
            Err(e @ ControllerError::VersionMismatch { .. }) => {
                return Err(FlashError::NotBack {
                    port: port.to_owned(),
                    why: e.to_string(),
                    waited_s: 0,
                })
            }
            Err(e) if Instant::now() >= deadline => {
                return Err(FlashError::NotBack {
                    port: port.to_owned(),
                    why: e.to_string(),
                    waited_s: timeout.as_secs(),
                })
            }
            Err(_) => std::thread::sleep(Duration::from_millis(200)),
        }
    }
}
