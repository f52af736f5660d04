//! The emulated board's flash: the calibration store's two sectors, kept in a file so
//! that a stored calibration survives restarts as on a real board.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use fpm_firmware::RamNor;

/// Size of the emulated flash: the two sectors of the calibration store.
pub const FLASH_BYTES: usize = 2 * 4096;

/// The emulated flash chip.
pub type EmulatedFlash = RamNor<FLASH_BYTES>;

/// Where the flash image lives between runs (nowhere without `--flash`).
pub struct FlashFile {
    path: Option<PathBuf>,
    saved_ops: usize,
}

impl FlashFile {
    /// The image at `path` (`None`: in memory only).
    pub fn new(path: Option<&Path>) -> Self {
        Self {
            path: path.map(Path::to_path_buf),
            saved_ops: 0,
        }
    }

    /// The flash as the file holds it; erased if the file does not exist yet.
    pub fn load(&self) -> Result<EmulatedFlash> {
        let Some(path) = &self.path else {
            return Ok(EmulatedFlash::erased());
        };
        match std::fs::read(path) {
            Ok(bytes) if bytes.len() == FLASH_BYTES => Ok(EmulatedFlash::from_image(&bytes)),
            Ok(bytes) => bail!(
                "{}: a flash image of {} bytes, expected {FLASH_BYTES} (not an fpm emulator flash file?)",
                path.display(),
                bytes.len()
            ),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(EmulatedFlash::erased()),
            Err(e) => Err(e).with_context(|| format!("reading the flash image {}", path.display())),
        }
    }

    /// Write the image if the flash was erased or programmed since the last save
    /// (atomically: a killed emulator leaves the old file or the new one).
    pub fn save_if_changed(&mut self, flash: &EmulatedFlash) -> Result<()> {
        let Some(path) = &self.path else {
            return Ok(());
        };
        if flash.ops() == self.saved_ops {
            return Ok(());
        }
        let tmp = path.with_extension("tmp");
        std::fs::write(&tmp, flash.image())
            .and_then(|()| std::fs::rename(&tmp, path))
            .with_context(|| format!("saving the flash image {}", path.display()))?;
        self.saved_ops = flash.ops();
        Ok(())
    }
}
