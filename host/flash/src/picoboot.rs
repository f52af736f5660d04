//! PICOBOOT, the RP2040 boot ROM's vendor USB interface (RP2040 datasheet §2.8.5):
//! the image written page by page and read back, with no drive to mount.
//!
//! Each command is 32 bytes on the bulk OUT endpoint, then its data (OUT for a write,
//! IN for a read), then a zero-length packet the other way to end it. A command the
//! ROM refuses stalls the endpoints; the host reads why with the GET_COMMAND_STATUS
//! control request and clears the stall with INTERFACE_RESET.
//!
//! The USB side is a [`Transport`]: over a Unix socket to an emulated boot ROM
//! (`fpm_rig::boot_rom`, tests), or over USB. [`write_image`] writes so that the ROM
//! never boots a mix of two images: the first page (the second-stage boot loader, which
//! the ROM checks by its CRC before booting anything) is erased first and written last,
//! after everything else has been read back equal.

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The magic that starts every command.
pub const MAGIC: u32 = 0x431f_d10b;
/// A command's length on the wire, bytes.
pub const COMMAND_LEN: usize = 32;
/// GET_COMMAND_STATUS's answer, bytes.
pub const STATUS_LEN: usize = 16;
/// Flash erases whole sectors of this many bytes.
pub const SECTOR: u32 = 4096;
/// Flash is written in pages of this many bytes.
pub const PAGE: u32 = 256;
/// Where the RP2040 maps its flash, and the Pico's 2 MiB of it.
pub const FLASH: std::ops::Range<u32> = 0x1000_0000..0x1020_0000;
/// The USB ids the boot ROM enumerates with.
pub const USB_ID: (u16, u16) = (0x2e8a, 0x0003);
/// The control requests (vendor, to the interface).
pub const REQUEST_INTERFACE_RESET: u8 = 0x41;
/// See [`REQUEST_INTERFACE_RESET`].
pub const REQUEST_GET_COMMAND_STATUS: u8 = 0x42;

/// The boot ROM's commands (`bCmdId`; bit 7 set: data comes IN).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CommandId {
    /// Take the flash from the USB drive (1: exclusive, 2: and eject the drive).
    ExclusiveAccess = 0x01,
    /// Restart (pc, sp, delay in ms; pc 0: boot normally).
    Reboot = 0x02,
    /// Erase whole sectors (address, size).
    FlashErase = 0x03,
    /// Read memory (address, size).
    Read = 0x84,
    /// Write memory (address, size; flash in whole pages).
    Write = 0x05,
    /// Leave execute-in-place mode before touching flash.
    ExitXip = 0x06,
}

impl CommandId {
    /// The id from its byte.
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            0x01 => Self::ExclusiveAccess,
            0x02 => Self::Reboot,
            0x03 => Self::FlashErase,
            0x84 => Self::Read,
            0x05 => Self::Write,
            0x06 => Self::ExitXip,
            _ => return None,
        })
    }

    /// `bCmdSize`: the argument bytes this command carries.
    pub fn args_len(self) -> u8 {
        match self {
            Self::ExclusiveAccess => 1,
            Self::Reboot => 12,
            Self::FlashErase | Self::Read | Self::Write => 8,
            Self::ExitXip => 0,
        }
    }
}

/// One command as the wire carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Command {
    /// Echoed in the status, to tell commands apart.
    pub token: u32,
    /// The command (its byte, as sent: an unknown one is the ROM's to refuse).
    pub id: u8,
    /// `bCmdSize`.
    pub args_len: u8,
    /// Data bytes that follow.
    pub transfer_len: u32,
    /// Arguments, little-endian words.
    pub args: [u8; 16],
}

impl Command {
    /// `id` with `words` as its arguments and `transfer_len` data bytes.
    pub fn new(token: u32, id: CommandId, words: &[u32], transfer_len: u32) -> Self {
        let mut args = [0u8; 16];
        for (k, w) in words.iter().take(4).enumerate() {
            args[4 * k..4 * k + 4].copy_from_slice(&w.to_le_bytes());
        }
        Self {
            token,
            id: id as u8,
            args_len: id.args_len(),
            transfer_len,
            args,
        }
    }

    /// The 32 bytes.
    pub fn encode(&self) -> [u8; COMMAND_LEN] {
        let mut out = [0u8; COMMAND_LEN];
        out[0..4].copy_from_slice(&MAGIC.to_le_bytes());
        out[4..8].copy_from_slice(&self.token.to_le_bytes());
        out[8] = self.id;
        out[9] = self.args_len;
        out[12..16].copy_from_slice(&self.transfer_len.to_le_bytes());
        out[16..32].copy_from_slice(&self.args);
        out
    }

    /// A command from its bytes, None unless 32 bytes with the magic.
    pub fn decode(bytes: &[u8]) -> Option<Self> {
        let word =
            |k: usize| u32::from_le_bytes([bytes[k], bytes[k + 1], bytes[k + 2], bytes[k + 3]]);
        if bytes.len() != COMMAND_LEN || word(0) != MAGIC {
            return None;
        }
        let mut args = [0u8; 16];
        args.copy_from_slice(&bytes[16..32]);
        Some(Self {
            token: word(4),
            id: bytes[8],
            args_len: bytes[9],
            transfer_len: word(12),
            args,
        })
    }

    /// Argument word `k`.
    pub fn arg(&self, k: usize) -> u32 {
        u32::from_le_bytes([
            self.args[4 * k],
            self.args[4 * k + 1],
            self.args[4 * k + 2],
            self.args[4 * k + 3],
        ])
    }
}

/// The boot ROM's status codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum StatusCode {
    /// Done.
    Ok = 0,
    /// No such command.
    UnknownCommand = 1,
    /// `bCmdSize` wrong for the command.
    InvalidCommandLength = 2,
    /// `dTransferLength` wrong for the command.
    InvalidTransferLength = 3,
    /// Outside what the command may touch.
    InvalidAddress = 4,
    /// Not on a page or sector boundary.
    BadAlignment = 5,
    /// The USB drive wrote meanwhile.
    InterleavedWrite = 6,
    /// Restarting.
    Rebooting = 7,
    /// Anything else.
    UnknownError = 8,
}

impl StatusCode {
    /// The code from its number (unknown numbers are [`StatusCode::UnknownError`]).
    pub fn from_u32(v: u32) -> Self {
        match v {
            0 => Self::Ok,
            1 => Self::UnknownCommand,
            2 => Self::InvalidCommandLength,
            3 => Self::InvalidTransferLength,
            4 => Self::InvalidAddress,
            5 => Self::BadAlignment,
            6 => Self::InterleavedWrite,
            7 => Self::Rebooting,
            _ => Self::UnknownError,
        }
    }
}

/// GET_COMMAND_STATUS's answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandStatus {
    /// The last command's token.
    pub token: u32,
    /// How it ended.
    pub code: StatusCode,
    /// The last command's id.
    pub id: u8,
    /// Whether it still runs.
    pub in_progress: bool,
}

impl CommandStatus {
    /// The 16 bytes.
    pub fn encode(&self) -> [u8; STATUS_LEN] {
        let mut out = [0u8; STATUS_LEN];
        out[0..4].copy_from_slice(&self.token.to_le_bytes());
        out[4..8].copy_from_slice(&(self.code as u32).to_le_bytes());
        out[8] = self.id;
        out[9] = u8::from(self.in_progress);
        out
    }

    /// From its bytes (16).
    pub fn decode(b: &[u8; STATUS_LEN]) -> Self {
        Self {
            token: u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            code: StatusCode::from_u32(u32::from_le_bytes([b[4], b[5], b[6], b[7]])),
            id: b[8],
            in_progress: b[9] != 0,
        }
    }
}

/// What a USB transfer can end in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TransportError {
    /// The device refused the command and halted the endpoint (read the status).
    #[error("the endpoint stalled")]
    Stall,
    /// The device is gone (unplugged, restarted).
    #[error("the device is gone: {0}")]
    Gone(String),
}

/// The USB operations PICOBOOT needs, on one boot ROM's vendor interface.
pub trait Transport {
    /// Send `data` on the bulk OUT endpoint (empty: a zero-length packet).
    fn bulk_out(&mut self, data: &[u8]) -> Result<(), TransportError>;
    /// Receive `len` bytes on the bulk IN endpoint (0: a zero-length packet).
    fn bulk_in(&mut self, len: usize) -> Result<Vec<u8>, TransportError>;
    /// GET_COMMAND_STATUS.
    fn command_status(&mut self) -> Result<[u8; STATUS_LEN], TransportError>;
    /// INTERFACE_RESET: clears a stall.
    fn reset_interface(&mut self) -> Result<(), TransportError>;
}

/// A command that failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PicobootError {
    /// The boot ROM refused it.
    #[error("the boot ROM refused {command} ({code:?})")]
    Refused {
        /// What was asked, with its address.
        command: String,
        /// Its status code.
        code: StatusCode,
    },
    /// The USB side failed.
    #[error("{command}: {source}")]
    Transport {
        /// What was asked.
        command: String,
        /// How it failed.
        source: TransportError,
    },
    /// What was read back is not what was written.
    #[error("reading back {address:#010x}: byte {byte} of the page is {read:#04x}, {wrote:#04x} was written")]
    Verify {
        /// The page.
        address: u32,
        /// The first byte that differs.
        byte: usize,
        /// What the flash holds.
        read: u8,
        /// What the image has.
        wrote: u8,
    },
}

/// A PICOBOOT session on `transport`.
pub struct Picoboot<T: Transport> {
    transport: T,
    token: u32,
}

impl<T: Transport> Picoboot<T> {
    /// Talk over `transport`: a stall left by an earlier session is cleared first.
    pub fn new(mut transport: T) -> Result<Self, PicobootError> {
        transport
            .reset_interface()
            .map_err(|source| PicobootError::Transport {
                command: "resetting the interface".into(),
                source,
            })?;
        Ok(Self {
            transport,
            token: 1,
        })
    }

    /// Run one command: its data out (`data`) or in (`read_len`), then the ending
    /// zero-length packet; a stall is read back as the ROM's status code.
    fn run(
        &mut self,
        what: &str,
        id: CommandId,
        words: &[u32],
        data: &[u8],
        read_len: usize,
    ) -> Result<Vec<u8>, PicobootError> {
        let command = Command::new(self.token, id, words, (data.len() + read_len) as u32);
        self.token = self.token.wrapping_add(1);
        let t = &mut self.transport;
        let result = (|| {
            t.bulk_out(&command.encode())?;
            if read_len > 0 {
                let got = t.bulk_in(read_len)?;
                t.bulk_out(&[])?;
                Ok(got)
            } else {
                if !data.is_empty() {
                    t.bulk_out(data)?;
                }
                t.bulk_in(0)?;
                Ok(vec![])
            }
        })();
        match result {
            Ok(got) => Ok(got),
            Err(TransportError::Stall) => {
                let status = t.command_status().map(|s| CommandStatus::decode(&s));
                let _ = t.reset_interface();
                match status {
                    Ok(s) => Err(PicobootError::Refused {
                        command: what.into(),
                        code: s.code,
                    }),
                    Err(source) => Err(PicobootError::Transport {
                        command: what.into(),
                        source,
                    }),
                }
            }
            Err(source) => Err(PicobootError::Transport {
                command: what.into(),
                source,
            }),
        }
    }

    /// Take the flash from the USB drive and eject it, so that nothing else writes.
    pub fn exclusive(&mut self) -> Result<(), PicobootError> {
        self.run(
            "taking exclusive access",
            CommandId::ExclusiveAccess,
            &[2],
            &[],
            0,
        )
        .map(drop)
    }

    /// Leave execute-in-place, as flash commands need.
    pub fn exit_xip(&mut self) -> Result<(), PicobootError> {
        self.run("leaving XIP", CommandId::ExitXip, &[], &[], 0)
            .map(drop)
    }

    /// Erase `len` bytes (whole sectors) from `address`.
    pub fn erase(&mut self, address: u32, len: u32) -> Result<(), PicobootError> {
        self.run(
            &format!("erasing {len} bytes at {address:#010x}"),
            CommandId::FlashErase,
            &[address, len],
            &[],
            0,
        )
        .map(drop)
    }

    /// Write `data` (whole pages) at `address`.
    pub fn write(&mut self, address: u32, data: &[u8]) -> Result<(), PicobootError> {
        self.run(
            &format!("writing {} bytes at {address:#010x}", data.len()),
            CommandId::Write,
            &[address, data.len() as u32],
            data,
            0,
        )
        .map(drop)
    }

    /// Read `len` bytes at `address`.
    pub fn read(&mut self, address: u32, len: usize) -> Result<Vec<u8>, PicobootError> {
        self.run(
            &format!("reading {len} bytes at {address:#010x}"),
            CommandId::Read,
            &[address, len as u32],
            &[],
            len,
        )
    }

    /// Restart into flash after `delay_ms`.
    pub fn reboot(&mut self, delay_ms: u32) -> Result<(), PicobootError> {
        self.run("restarting", CommandId::Reboot, &[0, 0, delay_ms], &[], 0)
            .map(drop)
    }
}

/// One flash page of an image.
pub type Page = (u32, [u8; PAGE as usize]);

/// How far [`write_image`] is, for a progress bar.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Written {
    /// Pages written and read back equal.
    pub pages: usize,
    /// Of the image's.
    pub of: usize,
}

/// Write `pages` (sorted by address, each inside [`FLASH`]) and read each back, then
/// restart the board. The ROM boots only a first page whose CRC holds, so that page
/// is erased before anything else is touched and written last: a write that fails,
/// a page read back wrong or a device that goes away leaves a flash the ROM does not
/// boot (the board stays in BOOTSEL, to be flashed again), never half of each image.
pub fn write_image<T: Transport>(
    boot: &mut Picoboot<T>,
    pages: &[Page],
    progress: &mut dyn FnMut(Written),
) -> Result<(), PicobootError> {
    boot.exclusive()?;
    boot.exit_xip()?;
    let first_sector = FLASH.start;
    boot.erase(first_sector, SECTOR)?;
    let (boot_page, rest): (Vec<&Page>, Vec<&Page>) =
        pages.iter().partition(|(a, _)| *a == FLASH.start);
    let mut erased = std::collections::BTreeSet::from([first_sector]);
    let of = pages.len();
    for (done, (address, data)) in rest.into_iter().chain(boot_page).enumerate() {
        let sector = address - (address - FLASH.start) % SECTOR;
        if erased.insert(sector) {
            boot.erase(sector, SECTOR)?;
        }
        boot.write(*address, data)?;
        let read = boot.read(*address, data.len())?;
        if let Some(byte) = (0..data.len()).find(|&k| read.get(k) != Some(&data[k])) {
            // The first page may be half right: erased again, so the ROM boots nothing.
            if *address == FLASH.start {
                let _ = boot.erase(first_sector, SECTOR);
            }
            return Err(PicobootError::Verify {
                address: *address,
                byte,
                read: read.get(byte).copied().unwrap_or(0),
                wrote: data[byte],
            });
        }
        progress(Written {
            pages: done + 1,
            of,
        });
    }
    boot.reboot(500)
}

/// A boot ROM reached over a Unix socket: an emulated one (`fpm_rig::boot_rom`).
/// Each transfer is one request and one answer. Request: an operation byte (1 bulk
/// OUT, 2 bulk IN, 3 GET_COMMAND_STATUS, 4 INTERFACE_RESET) and a little-endian u32
/// (OUT: the data's length, the data following; IN: the length asked). Answer: 0 (done)
/// or 1 (stalled), a u32 length and that many bytes.
pub struct SocketTransport {
    stream: UnixStream,
    path: PathBuf,
}

/// The operations of [`SocketTransport`]'s requests.
pub mod socket_op {
    /// Bulk OUT.
    pub const BULK_OUT: u8 = 1;
    /// Bulk IN.
    pub const BULK_IN: u8 = 2;
    /// GET_COMMAND_STATUS.
    pub const STATUS: u8 = 3;
    /// INTERFACE_RESET.
    pub const RESET: u8 = 4;
}

impl SocketTransport {
    /// Connect to the boot ROM at `path`.
    pub fn connect(path: &Path) -> std::io::Result<Self> {
        let stream = UnixStream::connect(path)?;
        stream.set_read_timeout(Some(Duration::from_secs(10)))?;
        Ok(Self {
            stream,
            path: path.to_owned(),
        })
    }

    fn transfer(&mut self, op: u8, len: u32, data: &[u8]) -> Result<Vec<u8>, TransportError> {
        let gone =
            |e: std::io::Error| TransportError::Gone(format!("{}: {e}", self.path.display()));
        let mut request = vec![op];
        request.extend_from_slice(&len.to_le_bytes());
        request.extend_from_slice(data);
        self.stream.write_all(&request).map_err(gone)?;
        let mut head = [0u8; 5];
        self.stream.read_exact(&mut head).map_err(gone)?;
        let n = u32::from_le_bytes([head[1], head[2], head[3], head[4]]) as usize;
        let mut body = vec![0u8; n];
        self.stream.read_exact(&mut body).map_err(gone)?;
        match head[0] {
            0 => Ok(body),
            _ => Err(TransportError::Stall),
        }
    }
}

impl Transport for SocketTransport {
    fn bulk_out(&mut self, data: &[u8]) -> Result<(), TransportError> {
        self.transfer(socket_op::BULK_OUT, data.len() as u32, data)
            .map(drop)
    }

    fn bulk_in(&mut self, len: usize) -> Result<Vec<u8>, TransportError> {
        self.transfer(socket_op::BULK_IN, len as u32, &[])
    }

    fn command_status(&mut self) -> Result<[u8; STATUS_LEN], TransportError> {
        let got = self.transfer(socket_op::STATUS, STATUS_LEN as u32, &[])?;
        got.try_into()
            .map_err(|_| TransportError::Gone("a status of the wrong length".into()))
    }

    fn reset_interface(&mut self) -> Result<(), TransportError> {
        self.transfer(socket_op::RESET, 0, &[]).map(drop)
    }
}

/// CRC-32/MPEG-2 (polynomial 0x04c11db7, initial all ones, not reflected, no final
/// inversion): what the boot ROM checks the second-stage loader's first 252 bytes
/// against its last word with, before it boots from flash.
pub fn boot2_crc(bytes: &[u8]) -> u32 {
    let mut crc = 0xffff_ffffu32;
    for &b in bytes {
        crc ^= u32::from(b) << 24;
        for _ in 0..8 {
            crc = if crc & 0x8000_0000 != 0 {
                (crc << 1) ^ 0x04c1_1db7
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Whether the boot ROM boots a flash whose first page is `page`: its CRC holds.
pub fn boots(page: &[u8]) -> bool {
    page.len() >= 256
        && boot2_crc(&page[..252])
            == u32::from_le_bytes([page[252], page[253], page[254], page[255]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_command_goes_out_as_the_datasheet_lays_it_and_comes_back() {
        let c = Command::new(7, CommandId::Write, &[0x1000_0100, 256], 256);
        let b = c.encode();
        assert_eq!(&b[0..4], &[0x0b, 0xd1, 0x1f, 0x43]);
        assert_eq!((b[8], b[9]), (0x05, 8));
        assert_eq!(Command::decode(&b), Some(c));
        assert_eq!((c.arg(0), c.arg(1)), (0x1000_0100, 256));
        let mut bad = b;
        bad[0] ^= 1;
        assert_eq!(Command::decode(&bad), None);
    }

    #[test]
    fn the_crc_is_mpeg2s() {
        // CRC-32/MPEG-2's check value.
        assert_eq!(boot2_crc(b"123456789"), 0x0376_e6e7);
    }
}
