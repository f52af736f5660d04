//! A NOR flash in RAM with the rules of the real chip, and power cuts on demand.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Why a [`RamNor`] operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RamNorError {
    /// Outside the flash or misaligned.
    OutOfBounds,
    /// A write that would turn a 0 bit back into 1 (only an erase can).
    NotErased,
    /// The power was cut part-way through.
    PowerCut,
}

impl NorFlashError for RamNorError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            Self::NotErased | Self::PowerCut => NorFlashErrorKind::Other,
        }
    }
}

/// `N` bytes of NOR flash: erase sets whole 4 KiB sectors to 0xFF, a write can only
/// clear bits (programming a byte that is not erased is an error here, where the real
/// chip would silently AND). Every erased or programmed byte is one operation; after
/// [`Self::cut_power_after`] `n` operations the flash stops mid-operation, leaving
/// the bytes done so far changed and the rest as they were, as a power cut would.
pub struct RamNor<const N: usize> {
    bytes: [u8; N],
    power_left: Option<usize>,
    ops: usize,
}

impl<const N: usize> Default for RamNor<N> {
    fn default() -> Self {
        Self::erased()
    }
}

impl<const N: usize> RamNor<N> {
    /// A chip straight from the factory: all 0xFF.
    pub const fn erased() -> Self {
        Self {
            bytes: [0xFF; N],
            power_left: None,
            ops: 0,
        }
    }

    /// A chip holding `image` (shorter images leave the rest erased, longer ones are
    /// cut).
    pub fn from_image(image: &[u8]) -> Self {
        let mut me = Self::erased();
        let n = image.len().min(N);
        me.bytes[..n].copy_from_slice(&image[..n]);
        me
    }

    /// The whole contents.
    pub fn image(&self) -> &[u8; N] {
        &self.bytes
    }

    /// Bytes erased or programmed so far.
    pub fn ops(&self) -> usize {
        self.ops
    }

    /// Cut the power after `n` more byte operations.
    pub fn cut_power_after(&mut self, n: usize) {
        self.power_left = Some(n);
    }

    /// Power back on.
    pub fn restore_power(&mut self) {
        self.power_left = None;
    }

    /// Spend one operation, or fail if the power is gone.
    fn spend(&mut self) -> Result<(), RamNorError> {
        match &mut self.power_left {
            Some(0) => return Err(RamNorError::PowerCut),
            Some(n) => *n -= 1,
            None => {}
        }
        self.ops += 1;
        Ok(())
    }

    fn range(&self, offset: u32, len: usize) -> Result<core::ops::Range<usize>, RamNorError> {
        let start = offset as usize;
        let end = start.checked_add(len).ok_or(RamNorError::OutOfBounds)?;
        if end > N {
            return Err(RamNorError::OutOfBounds);
        }
        Ok(start..end)
    }
}

impl<const N: usize> ErrorType for RamNor<N> {
    type Error = RamNorError;
}

impl<const N: usize> ReadNorFlash for RamNor<N> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let range = self.range(offset, bytes.len())?;
        bytes.copy_from_slice(&self.bytes[range]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize> NorFlash for RamNor<N> {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 4096;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        if from > to
            || !(from as usize).is_multiple_of(Self::ERASE_SIZE)
            || !(to as usize).is_multiple_of(Self::ERASE_SIZE)
        {
            return Err(RamNorError::OutOfBounds);
        }
        let range = self.range(from, (to - from) as usize)?;
        for i in range {
            self.spend()?;
            self.bytes[i] = 0xFF;
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let range = self.range(offset, bytes.len())?;
        if self.bytes[range.clone()]
            .iter()
            .zip(bytes)
            .any(|(&old, &new)| old & new != new)
        {
            return Err(RamNorError::NotErased);
        }
        for (i, &b) in range.zip(bytes) {
            self.spend()?;
            self.bytes[i] = b;
        }
        Ok(())
    }
}
