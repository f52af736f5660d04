//! The board's calibration, kept in two flash sectors so that a power cut at any
//! moment of a write leaves the previous record or the new one, never garbage.
//!
//! Records are appended to the active sector; each carries a sequence number and a
//! CRC-32, and the valid record with the highest number wins. When the active sector
//! is full (or holds a torn record), the next record goes to the start of the other
//! sector, which is erased first: the active sector, with the previous record, is
//! left untouched until a later rotation. Works over any [`NorFlash`] (embassy-rp's
//! flash on the board, [`RamNor`] in the emulator and the tests).

mod nor;
mod record;

pub use nor::RamNor;

use embedded_storage::nor_flash::NorFlash;
use fpm_protocol::{BoardCalibration, StorageError, StoredCalibration};

use record::{Record, RECORD_MAX};

/// Sectors used: the active one and the one the next rotation writes.
const SECTORS: u32 = 2;

/// The calibration store on `F`, in the two sectors from `base`.
pub struct CalibrationStore<F: NorFlash> {
    flash: F,
    base: u32,
    usable: bool,
}

/// What a scan of one sector found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SectorState {
    /// Valid records, then erased space from this offset to the end.
    Clean { free_at: u32 },
    /// Something that is neither a valid record nor erased space: no more appends.
    Dirty,
}

/// The newest valid record of the whole store.
#[derive(Debug, Clone, Copy)]
struct Latest {
    seq: u32,
    sector: u32,
    record: Record,
}

impl<F: NorFlash> CalibrationStore<F> {
    /// The store in the sectors `[base, base + 2 × ERASE_SIZE)` of `flash`. A region
    /// that is misaligned or does not fit gives a store that answers
    /// [`StorageError::NoStorage`].
    pub fn new(flash: F, base: u32) -> Self {
        let sector = F::ERASE_SIZE as u64;
        let end = base as u64 + SECTORS as u64 * sector;
        let usable = sector >= RECORD_MAX as u64
            && F::WRITE_SIZE <= 16
            && (base as u64).is_multiple_of(sector)
            && end <= flash.capacity() as u64;
        Self {
            flash,
            base,
            usable,
        }
    }

    /// The flash underneath (the emulator saves its image from it).
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// What is stored now.
    pub fn load(&mut self) -> StoredCalibration {
        if !self.usable {
            return StoredCalibration::NotCalibrated;
        }
        let (latest, states) = self.scan();
        match latest {
            Some(l) => l.record.calibration(),
            None if states.contains(&SectorState::Dirty) => StoredCalibration::Damaged,
            None => StoredCalibration::NotCalibrated,
        }
    }

    /// Store `calibration` (`None`: forget it). Returns what reads back.
    pub fn save(
        &mut self,
        calibration: Option<&BoardCalibration>,
    ) -> Result<StoredCalibration, StorageError> {
        if !self.usable {
            return Err(StorageError::NoStorage);
        }
        if calibration.is_some_and(|c| !c.is_valid()) {
            return Err(StorageError::Invalid);
        }
        let (latest, states) = self.scan();
        let seq = latest.map_or(1, |l| l.seq.wrapping_add(1).max(1));
        let record = Record::new(seq, calibration).ok_or(StorageError::Invalid)?;
        let mut bytes = [0xFFu8; RECORD_MAX];
        let len = record.encode::<F>(&mut bytes);

        let active = latest.map_or(0, |l| l.sector);
        let sector_size = F::ERASE_SIZE as u32;
        let offset = match states[active as usize] {
            SectorState::Clean { free_at } if free_at + len as u32 <= sector_size => {
                self.sector_start(active) + free_at
            }
            // Full or torn: start the other sector (the first record of a store
            // that has none goes to sector 0, erased first).
            _ => {
                let target = if latest.is_some() { 1 - active } else { 0 };
                let start = self.sector_start(target);
                self.flash
                    .erase(start, start + sector_size)
                    .map_err(|_| StorageError::Flash)?;
                start
            }
        };
        self.flash
            .write(offset, &bytes[..len])
            .map_err(|_| StorageError::Flash)?;

        let mut back = [0u8; RECORD_MAX];
        self.flash
            .read(offset, &mut back[..len])
            .map_err(|_| StorageError::Flash)?;
        match Record::decode(&back[..len]) {
            Ok(r) if r == record => Ok(r.calibration()),
            _ => Err(StorageError::Flash),
        }
    }

    fn sector_start(&self, sector: u32) -> u32 {
        self.base + sector * F::ERASE_SIZE as u32
    }

    /// The newest valid record and the state of each sector. A read error makes a
    /// sector dirty (so the next write moves away from it).
    fn scan(&mut self) -> (Option<Latest>, [SectorState; SECTORS as usize]) {
        let mut latest: Option<Latest> = None;
        let mut states = [SectorState::Dirty; SECTORS as usize];
        for sector in 0..SECTORS {
            let start = self.sector_start(sector);
            let size = F::ERASE_SIZE as u32;
            let mut pos = 0u32;
            states[sector as usize] = loop {
                let mut buf = [0u8; RECORD_MAX];
                let n = (size - pos).min(RECORD_MAX as u32) as usize;
                if n == 0 {
                    break SectorState::Clean { free_at: size };
                }
                if self.flash.read(start + pos, &mut buf[..n]).is_err() {
                    break SectorState::Dirty;
                }
                match Record::decode(&buf[..n]) {
                    Ok(record) => {
                        if latest.is_none_or(|l| record.seq > l.seq) {
                            latest = Some(Latest {
                                seq: record.seq,
                                sector,
                                record,
                            });
                        }
                        pos += record.stored_len::<F>() as u32;
                    }
                    // Free space must be erased to the end of the sector, or a torn
                    // write that left its header blank would be written over.
                    Err(_) if self.erased_from(start + pos, start + size) => {
                        break SectorState::Clean { free_at: pos }
                    }
                    Err(_) => break SectorState::Dirty,
                }
            };
        }
        (latest, states)
    }

    fn erased_from(&mut self, from: u32, to: u32) -> bool {
        let mut buf = [0u8; 64];
        let mut at = from;
        while at < to {
            let n = ((to - at) as usize).min(buf.len());
            if self.flash.read(at, &mut buf[..n]).is_err() || buf[..n].iter().any(|&b| b != 0xFF) {
                return false;
            }
            at += n as u32;
        }
        true
    }
}

#[cfg(test)]
mod tests;
