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
//! 3. its boot device is waited for: the boot ROM's PICOBOOT interface ([`picoboot`])
//!    where it can be reached, else its boot drive (`RPI-RP2`, with `INFO_UF2.TXT`)
//!    among the mounted file systems, or where the caller says it is mounted;
//! 4. over PICOBOOT the image is written page by page and each page read back, the
//!    boot loader's page last, so that a failure leaves a board the ROM does not boot
//!    rather than half of two images; onto the drive it is copied and synced, and the
//!    boot ROM writes it and restarts;
//! 5. the board is waited for on its serial port and must answer in this host's
//!    protocol.

pub mod picoboot;
mod usb;

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
use picoboot::FLASH;
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
    /// Its flash pages, by address (a page given twice: the later block's).
    #[serde(skip)]
    pub pages: Vec<picoboot::Page>,
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
    #[error("waiting for the board's boot device: no PICOBOOT interface could be opened{picoboot} and no RPI-RP2 drive was mounted within {waited_s} s; mount the drive (desktops do so by themselves; else `sudo mount /dev/disk/by-label/RPI-RP2 /mnt`) and give --drive")]
    NoBootDrive {
        /// How long it was waited for, s.
        waited_s: u64,
        /// Why a boot ROM on USB could not be opened (empty: none was there).
        picoboot: String,
    },
    /// Writing over PICOBOOT failed; the flash is left unbootable, not mixed.
    #[error("writing over PICOBOOT ({device}): {source}; the board stays in BOOTSEL with no image the boot ROM would start: run this again (or copy the UF2 onto its RPI-RP2 drive)")]
    Picoboot {
        /// Which boot ROM.
        device: String,
        /// The command that failed.
        source: picoboot::PicobootError,
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
    let blocks = bytes.len() / 512;
    let mut pages = std::collections::BTreeMap::new();
    for (n, block) in bytes.chunks_exact(512).enumerate() {
        if let Some((address, page)) = read_block(n, block, blocks).map_err(&bad)? {
            pages.insert(address, page);
        }
    }
    let flash_bytes = pages.len() * picoboot::PAGE as usize;
    let (Some(first), Some(last)) = (pages.keys().next(), pages.keys().last()) else {
        return Err(bad("no block writes flash".into()));
    };
    let range = (*first, last + picoboot::PAGE);
    check_boot_page(&bytes, pages.get(&FLASH.start)).map_err(bad)?;
    Ok(Image {
        path: path.to_owned(),
        blocks,
        flash_bytes,
        range,
        pages: pages.into_iter().collect(),
    })
}

/// Block `n` of a UF2 file of `blocks` blocks as the boot ROM reads it: its flash page,
/// or None for a block that is not for the main flash; what is wrong, naming the block.
fn read_block(
    n: usize,
    block: &[u8],
    blocks: usize,
) -> Result<Option<(u32, [u8; picoboot::PAGE as usize])>, String> {
    let word = |k: usize| u32::from_le_bytes([block[k], block[k + 1], block[k + 2], block[k + 3]]);
    let at = n * 512;
    if word(0) != MAGIC_START0 || word(4) != MAGIC_START1 || word(508) != MAGIC_END {
        return Err(format!(
            "block {n} (byte {at}): not a UF2 block (its magic numbers are wrong)"
        ));
    }
    let (flags, address, size, total) = (word(8), word(12), word(16), word(24));
    if flags & FLAG_NOT_MAIN_FLASH != 0 {
        return Ok(None);
    }
    if flags & FLAG_FAMILY_ID == 0 || word(28) != RP2040_FAMILY {
        return Err(format!(
            "block {n} (byte {at}): family {:#010x}, not the RP2040's ({RP2040_FAMILY:#010x}): an image for another chip",
            word(28)
        ));
    }
    if size != picoboot::PAGE {
        return Err(format!(
            "block {n} (byte {at}): {size} payload bytes; the RP2040's boot ROM takes 256"
        ));
    }
    if !FLASH.contains(&address) || address.saturating_add(size) > FLASH.end {
        return Err(format!(
            "block {n} (byte {at}): address {address:#010x} outside the Pico's 2 MiB flash ({:#010x}–{:#010x}): the image is too large or not for flash",
            FLASH.start, FLASH.end
        ));
    }
    if total as usize != blocks {
        return Err(format!(
            "block {n} (byte {at}): says {total} blocks, the file has {blocks}"
        ));
    }
    if !(address - FLASH.start).is_multiple_of(picoboot::PAGE) {
        return Err(format!(
            "block {n} (byte {at}): address {address:#010x} is not on a 256-byte page"
        ));
    }
    let mut page = [0u8; picoboot::PAGE as usize];
    page.copy_from_slice(&block[32..32 + picoboot::PAGE as usize]);
    Ok(Some((address, page)))
}

/// The boot ROM starts from flash only through the second-stage loader in the first
/// page, whose CRC it checks: an image (the UF2 file `bytes`) without it, or with a
/// wrong one, would leave the board in BOOTSEL.
fn check_boot_page(
    bytes: &[u8],
    page: Option<&[u8; picoboot::PAGE as usize]>,
) -> Result<(), String> {
    match page {
        None => Err(format!(
            "no block writes the boot loader's page at {:#010x}: the boot ROM would not start it",
            FLASH.start
        )),
        Some(page) if !picoboot::boots(page) => {
            let n = bytes
                .chunks_exact(512)
                .position(|b| b[12..16] == FLASH.start.to_le_bytes())
                .unwrap_or(0);
            Err(format!(
                "block {n} (byte {}): the boot loader's CRC (its page's last 4 bytes) does not hold: the boot ROM would not start it",
                n * 512 + 32 + 252
            ))
        }
        Some(_) => Ok(()),
    }
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
    /// Where the boot drive is mounted (None: found among the mounts). Given, the
    /// drive is used even where PICOBOOT could be.
    pub drive: Option<PathBuf>,
    /// An emulated boot ROM's PICOBOOT socket (`fpm_rig::boot_rom`), looked for as the
    /// board's boot device.
    pub boot_rom_socket: Option<PathBuf>,
    /// How long each wait (the boot device, the board's return) may take.
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
    /// Its boot device is there.
    BootDeviceFound(BootDeviceKind),
    /// Over PICOBOOT: this many pages of the image written and read back equal.
    Writing(picoboot::Written),
    /// The image is on the board (written and read back, or copied onto the drive).
    Written(BootDeviceKind),
    /// The board answered with the new firmware.
    Back,
}

impl Step {
    /// Its number among the five.
    pub fn number(self) -> usize {
        match self {
            Step::Checked => 1,
            Step::Restarting => 2,
            Step::BootDeviceFound(_) => 3,
            Step::Writing(_) | Step::Written(_) => 4,
            Step::Back => 5,
        }
    }
}

/// How the image reaches the flash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BootDeviceKind {
    /// The boot ROM's vendor interface: written, then read back.
    Picoboot,
    /// The boot ROM's USB drive: copied, the ROM writing it.
    Drive,
}

/// The boot device an image goes through.
enum BootDevice {
    /// An emulated boot ROM's PICOBOOT socket.
    Socket(PathBuf),
    /// The boot ROM's PICOBOOT interface on USB, opened, and its name.
    Usb(Box<usb::UsbTransport>, String),
    /// The boot drive's mount point.
    Drive(PathBuf),
}

/// What a flash did.
#[derive(Debug, Clone, Serialize)]
pub struct Flashed {
    /// The image written.
    pub image: Image,
    /// How: over PICOBOOT (each page read back) or onto the boot drive.
    pub via: BootDeviceKind,
    /// The boot device: the PICOBOOT interface (its USB bus and address, or an
    /// emulated one's socket), or the drive's mount point.
    pub boot_device: String,
    /// Pages read back equal to the image's (0 through the drive, which cannot).
    pub verified_pages: usize,
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
    let device = wait_for_boot_device(options)?;
    let (via, boot_device, verified_pages) = match device {
        BootDevice::Socket(socket) => {
            progress(Step::BootDeviceFound(BootDeviceKind::Picoboot));
            let name = socket.display().to_string();
            let transport = picoboot::SocketTransport::connect(&socket).map_err(|e| {
                picoboot_failed(&name)(picoboot::PicobootError::Transport {
                    command: "connecting".into(),
                    source: picoboot::TransportError::Gone(e.to_string()),
                })
            })?;
            write_over_picoboot(transport, &name, &image, progress)?;
            (BootDeviceKind::Picoboot, name, image.pages.len())
        }
        BootDevice::Usb(transport, name) => {
            progress(Step::BootDeviceFound(BootDeviceKind::Picoboot));
            write_over_picoboot(*transport, &name, &image, progress)?;
            (BootDeviceKind::Picoboot, name, image.pages.len())
        }
        BootDevice::Drive(drive) => {
            progress(Step::BootDeviceFound(BootDeviceKind::Drive));
            copy_onto(&image.path, &drive)?;
            (BootDeviceKind::Drive, drive.display().to_string(), 0)
        }
    };
    progress(Step::Written(via));
    let port = match port {
        Some(p) => p,
        None => wait_for_port(options.timeout)?,
    };
    let dev = wait_for_board(&port, options.timeout)?;
    let info = dev.info();
    progress(Step::Back);
    Ok(Flashed {
        image,
        via,
        boot_device,
        verified_pages,
        after: (info.firmware.to_string(), info.protocol.to_string()),
        port,
        before,
    })
}

/// The board's port, and its firmware and protocol before (None when no board
/// answered but a boot device was there already: a new Pico, or one left in BOOTSEL).
type Restarted = (Option<String>, Option<(String, String)>);

/// Ask the board to restart in BOOTSEL, or find one there already.
fn restart_in_bootsel(options: &Options) -> Result<Restarted, FlashError> {
    let timeout = Duration::from_secs(2);
    let port = match &options.port {
        Some(p) => p.clone(),
        None => match discover::the_only_board(timeout) {
            Ok(p) => p,
            Err(e) if boot_device_now(options, &mut None).is_some() => {
                tracing::info!("no board answers ({e}); a board waits in BOOTSEL: flashing it");
                return Ok((None, None));
            }
            Err(e) => return Err(FlashError::NoBoard(e)),
        },
    };
    let dev = match Controller::open(&port, timeout) {
        Ok(dev) => dev,
        // Older firmware still restarts by hand; a version mismatch is what flashing
        // is for, but this firmware cannot be asked.
        Err(e) if boot_device_now(options, &mut None).is_some() => {
            tracing::info!("{port}: {e}; a board waits in BOOTSEL: flashing it");
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

/// The board's boot device, if it is there now: the drive where one is given; an
/// emulated boot ROM where its socket is given (the bus is then left alone); else
/// the boot ROM's PICOBOOT interface on USB, or a mounted boot drive. A boot ROM on
/// USB that cannot be opened is said in `unreachable`.
fn boot_device_now(options: &Options, unreachable: &mut Option<String>) -> Option<BootDevice> {
    if let Some(d) = &options.drive {
        return is_boot_drive(d).then(|| BootDevice::Drive(d.clone()));
    }
    if let Some(socket) = &options.boot_rom_socket {
        return picoboot::SocketTransport::connect(socket)
            .is_ok()
            .then(|| BootDevice::Socket(socket.clone()));
    }
    match usb::open_boot_rom() {
        Ok(Some((transport, name))) => return Some(BootDevice::Usb(Box::new(transport), name)),
        Ok(None) => {}
        Err(why) => *unreachable = Some(why),
    }
    mounted_boot_drive().map(BootDevice::Drive)
}

fn wait_for_boot_device(options: &Options) -> Result<BootDevice, FlashError> {
    let deadline = Instant::now() + options.timeout;
    let mut unreachable = None;
    loop {
        if let Some(d) = boot_device_now(options, &mut unreachable) {
            return Ok(d);
        }
        if Instant::now() >= deadline {
            return Err(FlashError::NoBootDrive {
                waited_s: options.timeout.as_secs(),
                picoboot: unreachable.map_or(String::new(), |why| format!(" ({why})")),
            });
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn picoboot_failed(device: &str) -> impl Fn(picoboot::PicobootError) -> FlashError + '_ {
    move |source| FlashError::Picoboot {
        device: device.to_owned(),
        source,
    }
}

/// Write `image` over PICOBOOT on `transport` (the boot ROM `name`), each page read
/// back, and restart the board ([`picoboot::write_image`]).
fn write_over_picoboot<T: picoboot::Transport>(
    transport: T,
    name: &str,
    image: &Image,
    progress: &mut dyn FnMut(Step),
) -> Result<(), FlashError> {
    let mut boot = picoboot::Picoboot::new(transport).map_err(picoboot_failed(name))?;
    picoboot::write_image(&mut boot, &image.pages, &mut |w| progress(Step::Writing(w)))
        .map_err(picoboot_failed(name))
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
