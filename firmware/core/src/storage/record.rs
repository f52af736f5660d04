//! One stored record: header, postcard payload, CRC-32.
//!
//! ```text
//! "FPMG" | format u8 | payload length u8 | sequence u32 LE | payload | CRC-32 LE
//! ```
//! The CRC (IEEE, as in zip and Ethernet) covers everything before it. A payload of
//! length 0 is a tombstone: the calibration was forgotten.

use embedded_storage::nor_flash::NorFlash;
use fpm_protocol::{BoardCalibration, StoredCalibration};

const MAGIC: [u8; 4] = *b"FPMG";
const FORMAT: u8 = 1;
const HEADER: usize = 4 + 1 + 1 + 4;
const CRC_LEN: usize = 4;
const PAYLOAD_MAX: usize = 64;
/// Longest record, padding included.
pub(super) const RECORD_MAX: usize = 96;

const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// A decoded, CRC-checked record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Record {
    pub seq: u32,
    payload_len: u8,
    payload: [u8; PAYLOAD_MAX],
}

/// Why bytes are not a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Invalid {
    /// The header is all 0xFF: erased space (or a write torn before its first byte).
    Erased,
    /// Anything else: a torn or foreign write.
    Garbage,
}

impl Record {
    /// Record `seq` holding `calibration` (`None`: a tombstone).
    pub fn new(seq: u32, calibration: Option<&BoardCalibration>) -> Option<Self> {
        let mut payload = [0u8; PAYLOAD_MAX];
        let payload_len = match calibration {
            Some(c) => postcard::to_slice(c, &mut payload).ok()?.len(),
            None => 0,
        };
        Some(Self {
            seq,
            payload_len: payload_len as u8,
            payload,
        })
    }

    /// What the record says.
    pub fn calibration(&self) -> StoredCalibration {
        if self.payload_len == 0 {
            return StoredCalibration::NotCalibrated;
        }
        match postcard::from_bytes(&self.payload[..self.payload_len as usize]) {
            Ok(c) => StoredCalibration::Calibrated(c),
            Err(_) => StoredCalibration::Damaged,
        }
    }

    fn len(&self) -> usize {
        HEADER + self.payload_len as usize + CRC_LEN
    }

    /// Bytes taken in flash: the record padded to `F`'s write size.
    pub fn stored_len<F: NorFlash>(&self) -> usize {
        self.len().div_ceil(F::WRITE_SIZE) * F::WRITE_SIZE
    }

    /// Write the record into `out` (which holds 0xFF for padding); returns
    /// [`Self::stored_len`].
    pub fn encode<F: NorFlash>(&self, out: &mut [u8; RECORD_MAX]) -> usize {
        let n = self.payload_len as usize;
        out[..4].copy_from_slice(&MAGIC);
        out[4] = FORMAT;
        out[5] = self.payload_len;
        out[6..HEADER].copy_from_slice(&self.seq.to_le_bytes());
        out[HEADER..HEADER + n].copy_from_slice(&self.payload[..n]);
        let crc = CRC.checksum(&out[..HEADER + n]);
        out[HEADER + n..HEADER + n + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
        self.stored_len::<F>().min(RECORD_MAX)
    }

    /// The record at the start of `bytes`, if it is one.
    pub fn decode(bytes: &[u8]) -> Result<Self, Invalid> {
        let header = bytes.get(..HEADER).ok_or(Invalid::Garbage)?;
        if header.iter().all(|&b| b == 0xFF) {
            return Err(Invalid::Erased);
        }
        if header[..4] != MAGIC || header[4] != FORMAT {
            return Err(Invalid::Garbage);
        }
        let n = header[5] as usize;
        if n > PAYLOAD_MAX {
            return Err(Invalid::Garbage);
        }
        let body = bytes.get(..HEADER + n + CRC_LEN).ok_or(Invalid::Garbage)?;
        let mut crc = [0u8; CRC_LEN];
        crc.copy_from_slice(&body[HEADER + n..]);
        if CRC.checksum(&body[..HEADER + n]) != u32::from_le_bytes(crc) {
            return Err(Invalid::Garbage);
        }
        let mut seq = [0u8; 4];
        seq.copy_from_slice(&header[6..HEADER]);
        let mut payload = [0u8; PAYLOAD_MAX];
        payload[..n].copy_from_slice(&body[HEADER..HEADER + n]);
        Ok(Self {
            seq: u32::from_le_bytes(seq),
            payload_len: n as u8,
            payload,
        })
    }
}
