//! The capture's frames written as they are labelled, each named by a line of
//! `frames/journal.jsonl`, so that an acquisition killed mid-capture (`kill -9`, a
//! crash, the power) leaves what it took on disk, and [`recover`] makes that a valid
//! partial dataset. The run's own `dataset.toml` is written as before when the capture
//! ends (it is authoritative: the final pairing may relabel a frame); a frame the
//! journal already wrote with the same pixels is not written again, and the journal is
//! removed once the dataset is saved.
//!
//! A frame's file is written under a temporary name and renamed, then its line is
//! appended in one write: a line always names a complete file, and a line cut short by
//! a kill is ignored.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use fpm_host::dataset::{frame_file_name, image_io, Dataset, FrameEntry, Manifest, Pixels};
use serde::{Deserialize, Serialize};

use crate::capture::ShotView;

/// The journal's path in an acquisition's output directory.
pub const JOURNAL: &str = "frames/journal.jsonl";

/// A line of the journal.
#[derive(Serialize, Deserialize)]
#[serde(tag = "line", rename_all = "snake_case")]
enum Line {
    /// The first: the dataset's manifest, without frames.
    Start { manifest: Box<Manifest> },
    /// A frame written: its entry, its bit depth, and its pixels' checksum.
    Frame {
        entry: FrameEntry,
        bit_depth: u32,
        checksum: u64,
    },
}

/// A checksum of 16-bit pixels (to know a file already holds them; not cryptographic).
pub fn checksum<'a>(pixels: impl Iterator<Item = &'a u16>) -> u64 {
    pixels.fold(0xcbf2_9ce4_8422_2325u64, |h, &p| {
        (h ^ u64::from(p)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The journal of one acquisition's capture.
pub struct Journal {
    out: PathBuf,
    file: std::fs::File,
    /// Checksum of the pixels in each file written, by path.
    written: HashMap<PathBuf, u64>,
}

impl Journal {
    /// Start the journal in `out` for a dataset described by `manifest` (its frames are
    /// ignored).
    pub fn start(out: &Path, manifest: &Manifest) -> Result<Self> {
        let path = out.join(JOURNAL);
        std::fs::create_dir_all(out.join("frames"))
            .with_context(|| format!("creating {}", out.join("frames").display()))?;
        let mut file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let manifest = Box::new(Manifest {
            frames: vec![],
            ..manifest.clone()
        });
        let mut line = serde_json::to_string(&Line::Start { manifest })?;
        line.push('\n');
        file.write_all(line.as_bytes())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(Self {
            out: out.to_path_buf(),
            file,
            written: HashMap::new(),
        })
    }

    /// Write a labelled frame of the capture and its line.
    pub fn frame(&mut self, shot: &ShotView<'_>) -> Result<()> {
        let entry = FrameEntry {
            also: vec![],
            file: String::new(),
            led: shot.led,
            defocus_um: 0.0,
            exposure_ms: shot.header.exposure_us as f64 / 1e3,
        };
        let name = frame_file_name(&entry);
        let path = self.out.join(&name);
        let partial = path.with_extension("tif.partial");
        image_io::write_tiff_u16(&partial, shot.pixels)
            .map_err(|e| anyhow::anyhow!("{}: {}", partial.display(), e.reason()))?;
        std::fs::rename(&partial, &path)
            .with_context(|| format!("renaming {} to {}", partial.display(), path.display()))?;
        let sum = checksum(shot.pixels.iter());
        let mut line = serde_json::to_string(&Line::Frame {
            entry: FrameEntry {
                file: name,
                ..entry
            },
            bit_depth: shot.header.bit_depth,
            checksum: sum,
        })?;
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .with_context(|| format!("writing {}", self.out.join(JOURNAL).display()))?;
        self.written.insert(path, sum);
        Ok(())
    }

    /// Carry on a frame an earlier run wrote (a resumed acquisition): its line names its
    /// file, already on disk.
    pub fn adopt(
        &mut self,
        led: fpm_protocol::LedIndex,
        exposure_us: u32,
        bit_depth: u32,
        checksum: u64,
    ) -> Result<()> {
        let entry = FrameEntry {
            also: vec![],
            file: String::new(),
            led,
            defocus_um: 0.0,
            exposure_ms: exposure_us as f64 / 1e3,
        };
        let name = frame_file_name(&entry);
        let path = self.out.join(&name);
        if !path.is_file() {
            bail!("{}: the frame to carry on is not there", path.display());
        }
        self.line(&Line::Frame {
            entry: FrameEntry {
                file: name,
                ..entry
            },
            bit_depth,
            checksum,
        })?;
        self.written.insert(path, checksum);
        Ok(())
    }

    fn line(&mut self, line: &Line) -> Result<()> {
        let mut text = serde_json::to_string(line)?;
        text.push('\n');
        self.file
            .write_all(text.as_bytes())
            .with_context(|| format!("writing {}", self.out.join(JOURNAL).display()))
    }

    /// Whether the file at `path` was written by the journal with these pixels.
    pub fn holds(&self, path: &Path, pixels: &Pixels) -> bool {
        let Pixels::U16(a) = pixels else {
            return false;
        };
        self.written
            .get(path)
            .is_some_and(|&sum| sum == checksum(a.iter()))
    }

    /// The run's dataset is saved: the journal has served.
    pub fn finish(self) {
        let _ = std::fs::remove_file(self.out.join(JOURNAL));
    }
}

/// Make the frames an acquisition killed mid-capture left in `out` a dataset: its
/// `dataset.toml` from the journal (each LED's last complete frame), checked by
/// loading it. `None` when there is nothing to recover (no journal, or the run wrote
/// its dataset); the number of frames otherwise.
pub fn recover(out: &Path) -> Result<Option<usize>> {
    let path = out.join(JOURNAL);
    if out.join("dataset.toml").exists() || !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut manifest = None;
    let mut frames: Vec<FrameEntry> = vec![];
    let mut bit_depth = None;
    for (k, line) in text.lines().enumerate() {
        match serde_json::from_str::<Line>(line) {
            Ok(Line::Start { manifest: m }) if k == 0 => manifest = Some(*m),
            Ok(Line::Frame {
                entry,
                bit_depth: b,
                ..
            }) if out.join(&entry.file).is_file() => {
                bit_depth.get_or_insert(b);
                frames.retain(|f| f.led != entry.led);
                frames.push(entry);
            }
            Ok(_) => {}
            // The line a kill cut short.
            Err(e) if k + 1 == text.lines().count() => {
                tracing::info!(
                    "{}: its last line is incomplete ({e}); ignored",
                    path.display()
                );
            }
            Err(e) => bail!("{} line {}: {e}", path.display(), k + 1),
        }
    }
    let Some(mut manifest) = manifest else {
        bail!("{}: no start line", path.display());
    };
    if frames.is_empty() {
        return Ok(Some(0));
    }
    manifest.frames = frames;
    manifest.camera.bit_depth = bit_depth;
    manifest.write(out)?;
    let n = Dataset::load(out)
        .with_context(|| format!("the dataset recovered in {}", out.display()))?
        .frames
        .len();
    Ok(Some(n))
}
