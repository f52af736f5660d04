//! The RP2040 boot ROM's PICOBOOT interface, emulated for `fpm device flash`: what a
//! board in BOOTSEL is to the host, for want of a board here. The host's flasher
//! reaches it through the same [`Transport`] as a real one, in process or over a Unix
//! socket ([`serve`]).
//!
//! Kept from the ROM (RP2040 datasheet §2.8.5): the 32-byte commands with their magic,
//! sizes and transfer lengths; 4 KiB erase sectors and 256-byte write pages inside the
//! 2 MiB flash, each fault its status code; a refused command stalling the endpoint
//! until INTERFACE_RESET; a zero-length packet ending each command; REBOOT taking the
//! device off the bus. Flash is NOR: a write only clears bits, so a page written
//! without its erase reads back wrong, as on the chip. Not emulated: RAM, EXEC and the
//! USB drive beside the interface.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::sync::{Arc, Mutex};

use fpm_flash::picoboot::{
    self, socket_op, Command, CommandId, CommandStatus, StatusCode, Transport, TransportError,
    COMMAND_LEN, FLASH, PAGE, SECTOR,
};

/// Faults to inject, each once.
#[derive(Debug, Clone, Copy, Default)]
pub struct Faults {
    /// The write of the page at this address is refused (`UNKNOWN_ERROR`), as a flash
    /// the ROM cannot program.
    pub refuse_write_at: Option<u32>,
    /// The page at this address is programmed with one bit wrong (a worn cell): it
    /// reads back different.
    pub corrupt_at: Option<u32>,
    /// The device goes off the bus half-way through its n-th write (0: the first):
    /// half that page programmed, nothing after.
    pub vanish_in_write: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    /// A WRITE's data still to come: where it goes, bytes so far.
    OutData {
        address: u32,
        len: u32,
        got: u32,
    },
    /// A READ's data to hand over.
    InData {
        address: u32,
        len: u32,
    },
    /// Waiting for the host's zero-length OUT packet (after IN data).
    OutAck,
    /// Waiting for the host to take the zero-length IN packet.
    InAck,
    /// Refused: every transfer stalls until INTERFACE_RESET.
    Stalled,
}

/// The emulated boot ROM with its flash.
#[derive(Debug, Clone)]
pub struct BootRom {
    flash: Vec<u8>,
    state: State,
    status: CommandStatus,
    faults: Faults,
    writes: usize,
    reboot_pending: bool,
    /// Exclusive access asked (0: none, 1, 2: and the drive ejected).
    pub exclusive: u8,
    /// The device restarted (REBOOT) or went away: off the bus.
    pub gone: bool,
    /// It restarted as asked (REBOOT), rather than vanishing.
    pub rebooted: bool,
}

impl BootRom {
    /// A boot ROM whose flash holds `pages` (an image already on the board), erased
    /// elsewhere.
    pub fn with_pages(pages: &[picoboot::Page], faults: Faults) -> Self {
        let mut flash = vec![0xff; (FLASH.end - FLASH.start) as usize];
        for (address, data) in pages {
            let at = (address - FLASH.start) as usize;
            flash[at..at + data.len()].copy_from_slice(data);
        }
        Self {
            flash,
            state: State::Idle,
            status: CommandStatus {
                token: 0,
                code: StatusCode::Ok,
                id: 0,
                in_progress: false,
            },
            faults,
            writes: 0,
            reboot_pending: false,
            exclusive: 0,
            gone: false,
            rebooted: false,
        }
    }

    /// The flash, from its first byte (mapped at [`FLASH`]`.start`).
    pub fn flash(&self) -> &[u8] {
        &self.flash
    }

    /// Whether the ROM would start from this flash: the boot loader's CRC holds.
    pub fn would_boot(&self) -> bool {
        picoboot::boots(&self.flash[..PAGE as usize])
    }

    /// Whether the flash holds exactly `pages`, every other byte of their sectors
    /// erased.
    pub fn holds(&self, pages: &[picoboot::Page]) -> bool {
        let mut expected = std::collections::BTreeMap::new();
        for (address, data) in pages {
            let sector = (address - FLASH.start) / SECTOR * SECTOR;
            expected
                .entry(sector)
                .or_insert_with(|| vec![0xffu8; SECTOR as usize]);
            let page = &mut expected.get_mut(&sector).expect("inserted")
                [((address - FLASH.start) % SECTOR) as usize..][..PAGE as usize];
            page.copy_from_slice(data);
        }
        expected.iter().all(|(&sector, bytes)| {
            &self.flash[sector as usize..(sector + SECTOR) as usize] == bytes.as_slice()
        })
    }

    /// The flash as a UF2 image (its pages that are not erased), to start a board from.
    pub fn flash_as_uf2(&self) -> Vec<u8> {
        let written: Vec<fpm_fwtool::Segment> = self
            .flash
            .chunks_exact(PAGE as usize)
            .enumerate()
            .filter(|(_, p)| p.iter().any(|&b| b != 0xff))
            .map(|(k, p)| {
                let address = u64::from(FLASH.start) + (k as u64) * u64::from(PAGE);
                fpm_fwtool::Segment {
                    load_addr: address,
                    run_addr: address,
                    data: p.to_vec(),
                    mem_size: p.len() as u64,
                }
            })
            .collect();
        fpm_fwtool::uf2::encode(&written, fpm_fwtool::uf2::RP2040_FAMILY)
    }

    fn refuse(&mut self, code: StatusCode) {
        self.status.code = code;
        self.status.in_progress = false;
        self.state = State::Stalled;
    }

    fn done(&mut self) {
        self.status.in_progress = false;
    }

    /// A command arrives: checked as the ROM checks it, run if it carries no data.
    fn command(&mut self, bytes: &[u8]) {
        let Some(c) = Command::decode(bytes) else {
            return self.refuse(StatusCode::UnknownCommand);
        };
        self.status = CommandStatus {
            token: c.token,
            code: StatusCode::Ok,
            id: c.id,
            in_progress: true,
        };
        let Some(id) = CommandId::from_byte(c.id) else {
            return self.refuse(StatusCode::UnknownCommand);
        };
        if c.args_len != id.args_len() {
            return self.refuse(StatusCode::InvalidCommandLength);
        }
        let (address, size) = (c.arg(0), c.arg(1));
        let carries = matches!(id, CommandId::Read | CommandId::Write);
        if (carries && c.transfer_len != size) || (!carries && c.transfer_len != 0) {
            return self.refuse(StatusCode::InvalidTransferLength);
        }
        let inside =
            |a: u32, n: u32| FLASH.contains(&a) && a.checked_add(n).is_some_and(|e| e <= FLASH.end);
        match id {
            CommandId::ExclusiveAccess => {
                self.exclusive = c.args[0];
                self.state = State::InAck;
            }
            CommandId::ExitXip => self.state = State::InAck,
            CommandId::Reboot => {
                self.reboot_pending = true;
                self.state = State::InAck;
            }
            CommandId::FlashErase => {
                if !inside(address, size) {
                    return self.refuse(StatusCode::InvalidAddress);
                }
                if address % SECTOR != 0 || size % SECTOR != 0 {
                    return self.refuse(StatusCode::BadAlignment);
                }
                let at = (address - FLASH.start) as usize;
                self.flash[at..at + size as usize].fill(0xff);
                self.state = State::InAck;
            }
            CommandId::Write => {
                if !inside(address, size) {
                    return self.refuse(StatusCode::InvalidAddress);
                }
                if address % PAGE != 0 || size % PAGE != 0 {
                    return self.refuse(StatusCode::BadAlignment);
                }
                if self.faults.refuse_write_at == Some(address) {
                    self.faults.refuse_write_at = None;
                    return self.refuse(StatusCode::UnknownError);
                }
                self.state = State::OutData {
                    address,
                    len: size,
                    got: 0,
                };
            }
            CommandId::Read => {
                if !inside(address, size) {
                    return self.refuse(StatusCode::InvalidAddress);
                }
                self.state = State::InData { address, len: size };
            }
        }
    }

    /// WRITE's data: programmed as NOR flash is (bits only cleared).
    fn program(&mut self, address: u32, data: &[u8]) {
        let at = (address - FLASH.start) as usize;
        for (cell, &b) in self.flash[at..at + data.len()].iter_mut().zip(data) {
            *cell &= b;
        }
    }
}

impl Transport for BootRom {
    fn bulk_out(&mut self, data: &[u8]) -> Result<(), TransportError> {
        if self.gone {
            return Err(TransportError::Gone("off the bus".into()));
        }
        match self.state {
            // The refused command's status stays readable until the reset.
            State::Stalled => Err(TransportError::Stall),
            State::Idle if data.len() == COMMAND_LEN => {
                self.command(data);
                Ok(())
            }
            State::Idle => {
                self.refuse(StatusCode::UnknownCommand);
                Err(TransportError::Stall)
            }
            State::OutData { address, len, got } => {
                if got as usize + data.len() > len as usize {
                    self.refuse(StatusCode::InvalidTransferLength);
                    return Err(TransportError::Stall);
                }
                let at = address + got;
                if self.faults.vanish_in_write == Some(self.writes) {
                    let half = data.len() / 2;
                    self.program(at, &data[..half]);
                    self.gone = true;
                    return Err(TransportError::Gone("went off the bus mid-write".into()));
                }
                let mut data = data.to_vec();
                let end = at + data.len() as u32;
                if let Some(c) = self.faults.corrupt_at.filter(|c| (at..end).contains(c)) {
                    self.faults.corrupt_at = None;
                    data[(c - at) as usize] ^= 1;
                }
                self.program(at, &data);
                let got = got + data.len() as u32;
                self.state = if got == len {
                    self.writes += 1;
                    State::InAck
                } else {
                    State::OutData { address, len, got }
                };
                Ok(())
            }
            State::OutAck if data.is_empty() => {
                self.state = State::Idle;
                self.done();
                Ok(())
            }
            _ => {
                self.refuse(StatusCode::UnknownError);
                Err(TransportError::Stall)
            }
        }
    }

    fn bulk_in(&mut self, len: usize) -> Result<Vec<u8>, TransportError> {
        if self.gone {
            return Err(TransportError::Gone("off the bus".into()));
        }
        match self.state {
            State::InData { address, len: n } if len == n as usize => {
                let at = (address - FLASH.start) as usize;
                self.state = State::OutAck;
                Ok(self.flash[at..at + len].to_vec())
            }
            State::InAck if len == 0 => {
                self.state = State::Idle;
                self.done();
                if self.reboot_pending {
                    self.gone = true;
                    self.rebooted = true;
                }
                Ok(vec![])
            }
            State::Stalled => Err(TransportError::Stall),
            _ => {
                self.refuse(StatusCode::UnknownError);
                Err(TransportError::Stall)
            }
        }
    }

    fn command_status(&mut self) -> Result<[u8; picoboot::STATUS_LEN], TransportError> {
        if self.gone {
            return Err(TransportError::Gone("off the bus".into()));
        }
        Ok(self.status.encode())
    }

    fn reset_interface(&mut self) -> Result<(), TransportError> {
        if self.gone {
            return Err(TransportError::Gone("off the bus".into()));
        }
        self.state = State::Idle;
        Ok(())
    }
}

/// Serve `rom` on a Unix socket at `path` ([`picoboot::SocketTransport`]'s framing),
/// one connection at a time, until it goes off the bus (restarted or vanished) or
/// `stop` says so: the socket is then removed, as a device leaves the bus. Returns
/// the boot ROM as it ended.
pub fn serve(path: &Path, rom: BootRom, stop: &dyn Fn() -> bool) -> std::io::Result<BootRom> {
    let _ = std::fs::remove_file(path);
    let listener = UnixListener::bind(path)?;
    listener.set_nonblocking(true)?;
    let rom = Arc::new(Mutex::new(rom));
    while !stop() {
        match listener.accept() {
            Ok((stream, _)) => {
                stream.set_nonblocking(false)?;
                if answer(stream, &rom) {
                    break;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            Err(e) => return Err(e),
        }
    }
    let _ = std::fs::remove_file(path);
    let rom = rom
        .lock()
        .map_err(|_| std::io::Error::other("boot ROM lock poisoned"))?;
    Ok(rom.clone())
}

/// Answer one connection's transfers; whether the device went off the bus.
fn answer(mut stream: UnixStream, rom: &Mutex<BootRom>) -> bool {
    loop {
        let mut head = [0u8; 5];
        if stream.read_exact(&mut head).is_err() {
            return rom.lock().map(|r| r.gone).unwrap_or(true);
        }
        let len = u32::from_le_bytes([head[1], head[2], head[3], head[4]]) as usize;
        let Ok(mut rom) = rom.lock() else { return true };
        let result = match head[0] {
            socket_op::BULK_OUT => {
                let mut data = vec![0u8; len];
                if stream.read_exact(&mut data).is_err() {
                    return rom.gone;
                }
                rom.bulk_out(&data).map(|()| vec![])
            }
            socket_op::BULK_IN => rom.bulk_in(len),
            socket_op::STATUS => rom.command_status().map(|s| s.to_vec()),
            socket_op::RESET => rom.reset_interface().map(|()| vec![]),
            _ => Err(TransportError::Stall),
        };
        let answer = match result {
            Ok(body) => [&[0u8][..], &(body.len() as u32).to_le_bytes(), &body].concat(),
            Err(TransportError::Stall) => vec![1, 0, 0, 0, 0],
            // Off the bus: the connection just ends.
            Err(TransportError::Gone(_)) => return true,
        };
        if stream.write_all(&answer).is_err() {
            return rom.gone;
        }
        if rom.gone {
            return true;
        }
    }
}
