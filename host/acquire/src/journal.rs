//! The capture's frames written as they arrive, each named by a line of
//! `frames/journal.jsonl`, so that an acquisition killed mid-capture (`kill -9`, a
//! crash, the power) leaves what it took on disk, and [`recover`] makes that a valid
//! partial dataset. The run's own `dataset.toml` is written as before when the capture
//! ends (it is authoritative: the final pairing may relabel a frame); a frame the
//! journal already wrote with the same pixels is not written again, and the journal is
//! removed once the dataset is saved.
//!
//! A frame is written when it arrives, before the labeller knows its LED (under
//! `frames/arrived/`), beside the controller's step reports and the frames' times:
//! what [`recover`] replays into the capture's own [`Labeller`] for the frames a kill
//! left unlabelled. A frame labelled while the capture runs is renamed to its LED's
//! file. A file is written under a temporary name and renamed, then its line is
//! appended in one write: a line always names a complete file, and a line cut short
//! by a kill is ignored.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use fpm_frames::FrameHeader;
use fpm_host::dataset::{frame_file_name, image_io, Dataset, FrameEntry, Manifest, Pixels};
use fpm_protocol::LedIndex;
use ndarray::ArrayView2;
use serde::{Deserialize, Serialize};

use crate::capture::{News, ShotView};
use crate::label::{FrameTime, StepTime};
use crate::labeller::Labeller;

/// The journal's path in an acquisition's output directory.
pub const JOURNAL: &str = "frames/journal.jsonl";

/// Where frames wait for their labels, in an acquisition's output directory.
const ARRIVED: &str = "frames/arrived";

/// A line of the journal.
#[derive(Serialize, Deserialize)]
#[serde(tag = "line", rename_all = "snake_case")]
enum Line {
    /// The first: the dataset's manifest, without frames.
    Start { manifest: Box<Manifest> },
    /// A capture sequence started: the LED of each step, and its labeller's tolerance.
    Sequence {
        leds: Vec<LedIndex>,
        tolerance_ns: u64,
    },
    /// The controller reported a step of the latest sequence (as the labeller took it).
    Step {
        step: usize,
        trigger_ns: u64,
        arrived_ns: i64,
    },
    /// A frame of the latest sequence arrived, written to `file` before any label.
    Arrived {
        index: usize,
        frame_number: u64,
        timestamp_ns: u64,
        arrived_ns: i64,
        file: String,
        exposure_us: u32,
        bit_depth: u32,
    },
    /// A frame labelled: its entry, its bit depth, and its pixels' checksum; `arrival`
    /// names its [`Line::Arrived`] in the latest sequence (None: carried on from a
    /// resumed run).
    Frame {
        entry: FrameEntry,
        bit_depth: u32,
        checksum: u64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        arrival: Option<usize>,
    },
}

/// A checksum of 16-bit pixels (to know a file already holds them; not cryptographic).
pub fn checksum<'a>(pixels: impl Iterator<Item = &'a u16>) -> u64 {
    pixels.fold(0xcbf2_9ce4_8422_2325u64, |h, &p| {
        (h ^ u64::from(p)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// A frame as the camera gave it, for the dataset: a frame's entry without its file.
fn entry_for(led: LedIndex, exposure_us: u32) -> FrameEntry {
    let entry = FrameEntry {
        also: vec![],
        file: String::new(),
        led,
        defocus_um: 0.0,
        exposure_ms: exposure_us as f64 / 1e3,
    };
    FrameEntry {
        file: frame_file_name(&entry),
        ..entry
    }
}

/// Write `pixels` to `path` under a temporary name, then rename: a file the journal
/// names is always whole.
fn write_whole(path: &Path, pixels: ArrayView2<'_, u16>) -> Result<()> {
    let partial = path.with_extension("tif.partial");
    image_io::write_tiff_u16(&partial, pixels)
        .map_err(|e| anyhow::anyhow!("{}: {}", partial.display(), e.reason()))?;
    std::fs::rename(&partial, path)
        .with_context(|| format!("renaming {} to {}", partial.display(), path.display()))
}

/// The journal of one acquisition's capture.
pub struct Journal {
    out: PathBuf,
    file: std::fs::File,
    /// Checksum of the pixels in each file written, by path.
    written: HashMap<PathBuf, u64>,
    /// Sequences started (names the files of their arrivals).
    sequences: usize,
    /// The latest sequence's frames waiting under `frames/arrived`, by arrival index:
    /// the file and its pixels' checksum.
    waiting: HashMap<usize, (PathBuf, u64)>,
}

impl Journal {
    /// Start the journal in `out` for a dataset described by `manifest` (its frames are
    /// ignored).
    pub fn start(out: &Path, manifest: &Manifest) -> Result<Self> {
        let path = out.join(JOURNAL);
        std::fs::create_dir_all(out.join(ARRIVED))
            .with_context(|| format!("creating {}", out.join(ARRIVED).display()))?;
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut journal = Self {
            out: out.to_path_buf(),
            file,
            written: HashMap::new(),
            sequences: 0,
            waiting: HashMap::new(),
        };
        let manifest = Box::new(Manifest {
            frames: vec![],
            ..manifest.clone()
        });
        journal.line(&Line::Start { manifest })?;
        Ok(journal)
    }

    /// What the capture of `leds` told, as it happened (see [`News`]): the sequence's
    /// start, its step reports and its frames as they arrive, each label as it is
    /// given.
    pub fn record(&mut self, news: &News<'_>, leds: &[LedIndex]) -> Result<()> {
        match *news {
            News::Started { tolerance_ns } => self.sequence(leds, tolerance_ns),
            News::Step { step, arrived_ns } => self.step(step, arrived_ns),
            News::Arrived {
                index,
                arrived_ns,
                header,
                pixels,
            } => self.arrived(index, arrived_ns, header, pixels),
            News::Labelled { index, .. } => match news.shot(leds) {
                Some(shot) => self.frame(&shot, Some(index)),
                None => Ok(()),
            },
            News::Labelling(_) | News::Steps(_) => Ok(()),
        }
    }

    /// A capture sequence lighting `leds` started, its labeller taking `tolerance_ns`.
    fn sequence(&mut self, leds: &[LedIndex], tolerance_ns: u64) -> Result<()> {
        self.sequences += 1;
        self.waiting.clear();
        self.line(&Line::Sequence {
            leds: leds.to_vec(),
            tolerance_ns,
        })
    }

    /// The controller reported a step of the latest sequence.
    fn step(&mut self, step: StepTime, arrived_ns: i64) -> Result<()> {
        self.line(&Line::Step {
            step: step.step,
            trigger_ns: step.trigger_ns,
            arrived_ns,
        })
    }

    /// A frame of the latest sequence arrived (`index`: as the capture names it): its
    /// pixels written, then its line.
    fn arrived(
        &mut self,
        index: usize,
        arrived_ns: i64,
        header: &FrameHeader,
        pixels: ArrayView2<'_, u16>,
    ) -> Result<()> {
        let file = format!("{ARRIVED}/s{:02}-{index:05}.tif", self.sequences);
        let path = self.out.join(&file);
        write_whole(&path, pixels)?;
        self.line(&Line::Arrived {
            index,
            frame_number: header.frame_number,
            timestamp_ns: header.timestamp_ns,
            arrived_ns,
            file,
            exposure_us: header.exposure_us,
            bit_depth: header.bit_depth,
        })?;
        self.waiting.insert(index, (path, checksum(pixels.iter())));
        Ok(())
    }

    /// A frame of the capture labelled (`arrival`: its index in the latest sequence):
    /// the file it arrived in becomes its LED's (written now if it has none), then its
    /// line.
    fn frame(&mut self, shot: &ShotView<'_>, arrival: Option<usize>) -> Result<()> {
        let entry = entry_for(shot.led, shot.header.exposure_us);
        let path = self.out.join(&entry.file);
        let sum = match arrival.and_then(|k| self.waiting.remove(&k)) {
            Some((raw, sum)) => {
                std::fs::rename(&raw, &path)
                    .with_context(|| format!("renaming {} to {}", raw.display(), path.display()))?;
                sum
            }
            None => {
                write_whole(&path, shot.pixels)?;
                checksum(shot.pixels.iter())
            }
        };
        self.line(&Line::Frame {
            entry,
            bit_depth: shot.header.bit_depth,
            checksum: sum,
            arrival,
        })?;
        self.written.insert(path, sum);
        Ok(())
    }

    /// Carry on a frame an earlier run wrote (a resumed acquisition): its line names its
    /// file, already on disk.
    pub fn adopt(
        &mut self,
        led: LedIndex,
        exposure_us: u32,
        bit_depth: u32,
        checksum: u64,
    ) -> Result<()> {
        let entry = entry_for(led, exposure_us);
        let path = self.out.join(&entry.file);
        if !path.is_file() {
            bail!("{}: the frame to carry on is not there", path.display());
        }
        self.line(&Line::Frame {
            entry,
            bit_depth,
            checksum,
            arrival: None,
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

    /// The run's dataset is saved: the journal has served, and so have the frames that
    /// waited for a label and got none (extra frames, which no step lit).
    pub fn finish(self) {
        let _ = std::fs::remove_file(self.out.join(JOURNAL));
        let _ = std::fs::remove_dir_all(self.out.join(ARRIVED));
    }
}

/// One capture sequence of a journal, replayed: its labeller fed what the capture fed
/// its own, the files its frames arrived in, and the frames labelled while it ran.
struct Replay {
    leds: Vec<LedIndex>,
    labeller: Labeller,
    /// By arrival index: the file, the exposure and the bit depth.
    arrived: HashMap<usize, (String, u32, u32)>,
    /// Arrival indices labelled while the capture ran (their lines say with what).
    labelled: Vec<usize>,
}

/// A frame the dataset may take: from which sequence (0: before any), whether the
/// capture labelled it itself, its entry and bit depth, and the file to rename to the
/// entry's (a frame labelled by the replay).
struct Candidate {
    sequence: usize,
    online: bool,
    entry: FrameEntry,
    bit_depth: u32,
    from: Option<String>,
}

/// Make the frames an acquisition killed mid-capture left in `out` a dataset: its
/// `dataset.toml` from the journal, checked by loading it. Each LED keeps the frame of
/// the latest sequence that has one: the frame the capture labelled, else the one the
/// capture's own pairing, replayed over the step reports and frames the journal holds
/// (as if the capture had been cancelled at the kill), gives it. `None` when there is
/// nothing to recover (no journal, or the run wrote its dataset); the number of frames
/// otherwise.
pub fn recover(out: &Path) -> Result<Option<usize>> {
    let path = out.join(JOURNAL);
    if out.join("dataset.toml").exists() || !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut manifest = None;
    let mut replays: Vec<Replay> = vec![];
    let mut candidates: Vec<Candidate> = vec![];
    let lines = text.lines().count();
    for (k, line) in text.lines().enumerate() {
        let at = || format!("{} line {}", path.display(), k + 1);
        let line = match serde_json::from_str::<Line>(line) {
            Ok(line) => line,
            // The line a kill cut short.
            Err(e) if k + 1 == lines => {
                tracing::info!("{}: its last line is incomplete ({e}); ignored", at());
                continue;
            }
            Err(e) => bail!("{}: {e}", at()),
        };
        match line {
            Line::Start { manifest: m } if k == 0 => manifest = Some(*m),
            Line::Start { .. } => bail!("{}: a second start line", at()),
            Line::Sequence { leds, tolerance_ns } => replays.push(Replay {
                labeller: Labeller::new(leds.len(), tolerance_ns),
                leds,
                arrived: HashMap::new(),
                labelled: vec![],
            }),
            Line::Step {
                step,
                trigger_ns,
                arrived_ns,
            } => {
                let replay = replays
                    .last_mut()
                    .with_context(|| format!("{}: a step before any sequence", at()))?;
                replay
                    .labeller
                    .step(StepTime { step, trigger_ns }, arrived_ns);
            }
            Line::Arrived {
                index,
                frame_number,
                timestamp_ns,
                arrived_ns,
                file,
                exposure_us,
                bit_depth,
            } => {
                let replay = replays
                    .last_mut()
                    .with_context(|| format!("{}: a frame before any sequence", at()))?;
                let time = FrameTime {
                    frame_number,
                    timestamp_ns,
                };
                let replayed = replay.labeller.frame(time, arrived_ns);
                if replayed != index {
                    bail!("{}: frame {index} arrived as the replay's {replayed}", at());
                }
                replay.arrived.insert(index, (file, exposure_us, bit_depth));
            }
            Line::Frame {
                entry,
                bit_depth,
                arrival,
                ..
            } => {
                if let (Some(replay), Some(index)) = (replays.last_mut(), arrival) {
                    replay.labelled.push(index);
                }
                if out.join(&entry.file).is_file() {
                    candidates.push(Candidate {
                        sequence: replays.len(),
                        online: true,
                        entry,
                        bit_depth,
                        from: None,
                    });
                }
            }
        }
    }
    let Some(mut manifest) = manifest else {
        bail!("{}: no start line", path.display());
    };
    for (k, replay) in replays.into_iter().enumerate() {
        let done = replay.labeller.finish();
        for (step, index) in done.matched {
            let (Some(&led), Some((file, exposure_us, bit_depth))) =
                (replay.leds.get(step), replay.arrived.get(&index))
            else {
                continue;
            };
            if replay.labelled.contains(&index) || !out.join(file).is_file() {
                continue;
            }
            candidates.push(Candidate {
                sequence: k + 1,
                online: false,
                entry: entry_for(led, *exposure_us),
                bit_depth: *bit_depth,
                from: Some(file.clone()),
            });
        }
    }
    // Each LED's frame from its latest sequence; within one, the capture's own label.
    let mut chosen: Vec<Candidate> = vec![];
    for c in candidates {
        match chosen.iter_mut().find(|k| k.entry.led == c.entry.led) {
            Some(k) if (c.sequence, c.online) >= (k.sequence, k.online) => *k = c,
            Some(_) => {}
            None => chosen.push(c),
        }
    }
    if chosen.is_empty() {
        return Ok(Some(0));
    }
    let replayed = chosen.iter().filter(|c| c.from.is_some()).count();
    for c in &chosen {
        if let Some(from) = &c.from {
            let (from, to) = (out.join(from), out.join(&c.entry.file));
            std::fs::rename(&from, &to)
                .with_context(|| format!("renaming {} to {}", from.display(), to.display()))?;
        }
    }
    if replayed > 0 {
        tracing::info!(
            "{}: {replayed} frames that arrived unlabelled labelled by the capture's pairing, replayed",
            out.display()
        );
    }
    manifest.camera.bit_depth = chosen.first().map(|c| c.bit_depth);
    manifest.frames = chosen.into_iter().map(|c| c.entry).collect();
    manifest.write(out)?;
    let n = Dataset::load(out)
        .with_context(|| format!("the dataset recovered in {}", out.display()))?
        .frames
        .len();
    Ok(Some(n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fpm_physics::{LedGeometry, System};
    use ndarray::Array2;

    /// A fresh directory under the system's temporary one.
    fn scratch(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("fpm-journal-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// A capture of `leds` as a triggered camera gives it: steps 40 ms apart plus the
    /// controller's dither, a camera clock far from the controller's, each frame
    /// arriving 6 ms after its trigger and each step report at the step's end, and
    /// each frame's pixels all the value of its step (so a file says which step lit
    /// it). Journalled as the capture tells it; the frames of `labelled_online` are
    /// labelled while it runs; the journal is then dropped, as a kill leaves it.
    fn killed_capture(out: &Path, leds: &[LedIndex], labelled_online: &[usize]) {
        let manifest = Manifest::new(
            &System::paper(),
            &LedGeometry::paper(),
            Default::default(),
            vec![],
        );
        let mut journal = Journal::start(out, &manifest).unwrap();
        let tolerance_ns = 13_000_000;
        journal.sequence(leds, tolerance_ns).unwrap();
        let trigger = |k: usize| 1_000_000 + k as u64 * 40_000_000 + (k as u64 * 7919 % 997) * 1000;
        let mut news: Vec<(i64, bool, usize)> = vec![];
        for k in 0..leds.len() {
            news.push((trigger(k) as i64 + 6_000_000, true, k));
            news.push((trigger(k) as i64 + 40_000_000, false, k));
        }
        news.sort();
        for (at, is_frame, k) in news {
            if !is_frame {
                let step = StepTime {
                    step: k,
                    trigger_ns: trigger(k),
                };
                journal.step(step, trigger(k) as i64).unwrap();
                continue;
            }
            let header = FrameHeader {
                frame_number: k as u64,
                timestamp_ns: 5_000_000_000_000 + trigger(k),
                exposure_us: 40_000,
                width: 4,
                height: 3,
                bit_depth: 12,
                pixel_count: 12,
                ..Default::default()
            };
            let pixels = Array2::from_elem((3, 4), 100 + k as u16);
            journal.arrived(k, at, &header, pixels.view()).unwrap();
            if labelled_online.contains(&k) {
                let shot = ShotView {
                    led: leds[k],
                    header: &header,
                    pixels: pixels.view(),
                };
                journal.frame(&shot, Some(k)).unwrap();
            }
        }
    }

    fn leds(n: usize) -> Vec<LedIndex> {
        (0..n as u8).map(|k| LedIndex::new(k / 5, k % 5)).collect()
    }

    /// Each frame of the recovered dataset holds the pixels of the step that lit its
    /// LED.
    fn assert_true_labels(out: &Path, leds: &[LedIndex]) -> usize {
        let ds = Dataset::load(out).unwrap();
        for f in &ds.frames {
            let step = leds.iter().position(|&l| l == f.entry.led).unwrap();
            let Pixels::U16(p) = image_io::read(&out.join(&f.entry.file)).unwrap() else {
                panic!("16-bit pixels expected")
            };
            assert!(
                p.iter().all(|&v| v == 100 + step as u16),
                "{} holds another step's frame",
                f.entry.file
            );
        }
        ds.frames.len()
    }

    #[test]
    fn frames_killed_before_their_labels_are_labelled_by_the_replayed_pairing() {
        let out = scratch("unlabelled");
        let leds = leds(12);
        killed_capture(&out, &leds, &[]);
        assert_eq!(recover(&out).unwrap(), Some(12));
        assert_eq!(assert_true_labels(&out, &leds), 12);
        let _ = std::fs::remove_dir_all(&out);
    }

    #[test]
    fn frames_labelled_online_keep_their_label_and_the_rest_are_replayed() {
        let out = scratch("some-online");
        let leds = leds(20);
        killed_capture(&out, &leds, &[0, 1, 2, 3, 4, 5, 6, 7]);
        // The kill cut the last line short.
        let journal = out.join(JOURNAL);
        let mut text = std::fs::read_to_string(&journal).unwrap();
        text.push_str("{\"line\":\"arrived\",\"ind");
        std::fs::write(&journal, text).unwrap();
        assert_eq!(recover(&out).unwrap(), Some(20));
        assert_eq!(assert_true_labels(&out, &leds), 20);
        let _ = std::fs::remove_dir_all(&out);
    }

    /// Without the steps' reports (the controller's port lost before any), the frames
    /// cannot be told apart: nothing is labelled, nothing is guessed.
    #[test]
    fn frames_without_step_reports_are_not_guessed() {
        let out = scratch("no-steps");
        let leds = leds(6);
        killed_capture(&out, &leds, &[]);
        let journal = out.join(JOURNAL);
        let text: String = std::fs::read_to_string(&journal)
            .unwrap()
            .lines()
            .filter(|l| !l.contains("\"line\":\"step\""))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(&journal, text).unwrap();
        assert_eq!(recover(&out).unwrap(), Some(0));
        let _ = std::fs::remove_dir_all(&out);
    }
}
