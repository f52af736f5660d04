//! A dataset read from disk a frame, or a band of rows, at a time, for acquisitions
//! too large to hold (441 frames of 20 MP are 17.6 GB as 16-bit counts). The frames
//! come out exactly as [`Dataset::load`](super::Dataset::load) gives them: checked the
//! same way, in the sample-plane orientation, a colour sensor's channel taken out.

use std::ops::Range;
use std::path::{Path, PathBuf};

use fpm_physics::frame::Measured;
use ndarray::{s, Axis};

use super::{
    as_in_memory, frame_error, image_io, read_frame, read_manifest, DatasetError, Manifest, Pixels,
};

/// A dataset whose frames stay on disk until asked for.
#[derive(Debug, Clone)]
pub struct DatasetOnDisk {
    /// Where it is.
    pub dir: PathBuf,
    /// Its manifest, as a dataset in memory has it (see [`Self::stored`]).
    pub manifest: Manifest,
    /// The manifest as stored: how the files are oriented and coloured.
    stored: Manifest,
    /// `dataset.toml`.
    path: PathBuf,
    /// Every frame's (rows, cols) in the sample-plane orientation.
    dim: (usize, usize),
    /// Bytes per sample in memory.
    sample_bytes: usize,
}

impl DatasetOnDisk {
    /// Read and check the manifest, and the first frame for the frames' size.
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let (path, stored) = read_manifest(dir)?;
        let first = read_frame(dir, &path, &stored, 0, None)?;
        for (index, entry) in stored.frames.iter().enumerate() {
            let file = dir.join(&entry.file);
            if !file.is_file() {
                let reason = format!("file {} does not exist", file.display());
                return Err(frame_error(&path, &stored, index, reason));
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest: as_in_memory(stored.clone()),
            stored,
            path,
            dim: first.dim(),
            sample_bytes: (first.bits() / 8) as usize,
        })
    }

    /// Every frame's (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        self.dim
    }

    /// The in-focus frames (defocus 0), by index: what a reconstruction uses.
    pub fn in_focus(&self) -> Vec<usize> {
        (0..self.manifest.frames.len())
            .filter(|&k| self.manifest.frames[k].defocus_um == 0.0)
            .collect()
    }

    /// Bits per sample as stored in memory (8, 16 or 32).
    pub fn sample_bits(&self) -> u32 {
        (self.sample_bytes * 8) as u32
    }

    /// Bytes the in-focus frames take in memory, as stored.
    pub fn in_focus_bytes(&self) -> u64 {
        (self.in_focus().len() * self.dim.0 * self.dim.1 * self.sample_bytes) as u64
    }

    /// Frame `k`, whole, checked as [`Dataset::load`](super::Dataset::load) checks it.
    pub fn frame(&self, k: usize) -> Result<Pixels, DatasetError> {
        read_frame(&self.dir, &self.path, &self.stored, k, Some(self.dim))
    }

    /// Rows `rows` of frame `k` (sample-plane orientation). A TIFF in strips is read
    /// only where those rows are; other files (PNG, tiled TIFF, transposed or colour
    /// frames) are read whole and cut.
    pub fn rows(&self, k: usize, rows: Range<usize>) -> Result<Pixels, DatasetError> {
        let bad = |reason: String| frame_error(&self.path, &self.stored, k, reason);
        let (h, w) = self.dim;
        if rows.start >= rows.end || rows.end > h {
            return Err(bad(format!(
                "rows {}..{} are not within its {h} rows",
                rows.start, rows.end
            )));
        }
        let camera = &self.stored.camera;
        let entry = self
            .stored
            .frames
            .get(k)
            .ok_or_else(|| bad("no such [[frame]] entry".into()))?;
        if camera.transpose || camera.bayer.is_some() {
            return Ok(cut(self.frame(k)?, rows, false, false));
        }
        let file_rows = if camera.flip_y {
            h - rows.end..h - rows.start
        } else {
            rows.clone()
        };
        let file = self.dir.join(&entry.file);
        match image_io::read_rows(&file, file_rows) {
            Ok(Some((pixels, whole))) if whole == (h, w) => {
                Ok(cut(pixels, 0..rows.len(), camera.flip_x, camera.flip_y))
            }
            Ok(Some((_, whole))) => Err(bad(format!(
                "size {}x{} differs from frame 0 ({w}x{h})",
                whole.1, whole.0
            ))),
            // A file whose rows cannot be read (shorter than frame 0, a damaged strip)
            // is read whole, which names what is wrong with it as a whole read would.
            Ok(None) | Err(_) => Ok(cut(self.frame(k)?, rows, false, false)),
        }
    }

    /// Frame `k`'s `pixels` (the whole frame or some of its rows) as measured: the dark
    /// level and its exposure.
    pub fn measured<'a>(&self, k: usize, pixels: &'a Pixels) -> Measured<'a> {
        Measured {
            counts: pixels.view(),
            response: self.manifest.camera.response(),
            dark_level: self.manifest.camera.dark_light(),
            exposure_ms: self.manifest.frames[k].exposure_ms as f32,
            floor: 0.0,
            soft_floor: false,
            band: 0.0,
        }
    }
}

/// Rows `rows` of `pixels`, columns and rows reversed as asked.
fn cut(pixels: Pixels, rows: Range<usize>, flip_x: bool, flip_y: bool) -> Pixels {
    fn one<T: Clone>(
        a: ndarray::Array2<T>,
        rows: Range<usize>,
        flip_x: bool,
        flip_y: bool,
    ) -> ndarray::Array2<T> {
        let mut v = a.slice(s![rows, ..]);
        if flip_x {
            v.invert_axis(Axis(1));
        }
        if flip_y {
            v.invert_axis(Axis(0));
        }
        v.as_standard_layout().into_owned()
    }
    match pixels {
        Pixels::U8(a) => Pixels::U8(one(a, rows, flip_x, flip_y)),
        Pixels::U16(a) => Pixels::U16(one(a, rows, flip_x, flip_y)),
        Pixels::F32(a) => Pixels::F32(one(a, rows, flip_x, flip_y)),
    }
}
