//! `fpm bench memory`: the peak memory of a large reconstruction. A dataset of 441
//! 16-bit frames of the size asked (20 MP by default) is made by repeating a simulated
//! field across the sensor, then `fpm reconstruct` runs on it in a child process and
//! the kernel's peak resident set of that child is read (`getrusage`). The repeated
//! field is not one sample (the copies meet at seams), which does not matter here:
//! memory depends on the sizes, not on the picture.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_host::dataset::{image_io, Pixels};
use fpm_host::simulation::{self, AcquisitionSet, Noise, Scene};
use ndarray::Array2;
use serde::Serialize;

/// `fpm bench memory`.
#[derive(Debug, Clone)]
pub struct MemoryOptions {
    /// Frame width, pixels (default: a 20 MP sensor).
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Side of the simulated field that is repeated across the frame, pixels.
    pub field: usize,
    /// Where the dataset and the reconstruction go (needs the frames' size on disk:
    /// 17.6 GB for 441 frames of 20 MP). Removed at the end unless --keep.
    pub scratch: PathBuf,
    /// EPRY passes (the peak does not depend on them).
    pub passes: usize,
    /// HR pixels per camera pixel.
    pub upsample: usize,
    /// Passed to `fpm reconstruct` (frames above it are read from disk band by band);
    /// its default when not given.
    pub frame_memory_gb: Option<f64>,
    /// Keep the dataset and the reconstruction.
    pub keep: bool,
    /// Print JSON.
    pub json: bool,
}

#[derive(Serialize)]
struct MemoryResult {
    width: usize,
    height: usize,
    frames: usize,
    /// The frames as stored (16-bit), GB.
    frames_gb: f64,
    upsample: usize,
    passes: usize,
    tiles: usize,
    /// Rows of tiles, each read from the frames in turn when they stay on disk.
    bands: usize,
    /// Whether `fpm reconstruct` read the frames band by band.
    read_by_band: bool,
    /// The HR mosaic as complex32, GB.
    mosaic_gb: f64,
    /// Peak resident set of the `fpm reconstruct` process, GB.
    peak_rss_gb: f64,
    /// Its wall time, s.
    reconstruct_s: f64,
    /// Time to write the dataset, s.
    write_s: f64,
}

pub fn run(a: MemoryOptions) -> Result<()> {
    if a.width < a.field.min(64) || a.height < a.field.min(64) {
        bail!("frames of {}x{} are too small", a.width, a.height);
    }
    let dataset = a.scratch.join("dataset");
    let out = a.scratch.join("reconstruction");
    if a.scratch.exists() {
        bail!(
            "{} exists: give another --scratch (it is removed at the end)",
            a.scratch.display()
        );
    }
    let written = Instant::now();
    let frames = write_dataset(&a, &dataset)?;
    let write_s = written.elapsed().as_secs_f64();
    let exe = std::env::current_exe().context("the fpm executable")?;
    let mut cmd = Command::new(exe);
    cmd.arg("reconstruct")
        .arg(&dataset)
        .arg("--out")
        .arg(&out)
        .args(["--passes", &a.passes.to_string()])
        .args(["--upsample", &a.upsample.to_string()]);
    if let Some(gb) = a.frame_memory_gb {
        cmd.args(["--frame-memory-gb", &gb.to_string()]);
    }
    if !a.json {
        eprintln!("reconstructing {} ({frames} frames)…", dataset.display());
    }
    let began = Instant::now();
    let run = cmd.output().context("running fpm reconstruct")?;
    let reconstruct_s = began.elapsed().as_secs_f64();
    let stderr = String::from_utf8_lossy(&run.stderr);
    if !run.status.success() {
        bail!("fpm reconstruct failed: {stderr}");
    }
    // The largest resident set among the children waited for: the only child.
    let usage = nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_CHILDREN)
        .context("getrusage")?;
    let peak_rss_gb = usage.max_rss() as f64 * 1024.0 / 1e9;
    let report: serde_json::Value = serde_json::from_slice(
        &std::fs::read(out.join("report.json")).context("reading report.json")?,
    )
    .context("report.json")?;
    let tiles = report["tiles"].as_array().map_or(0, Vec::len);
    let mut rows: Vec<u64> = report["tiles"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|t| t["tile"]["y0"].as_u64())
        .collect();
    rows.dedup();
    let result = MemoryResult {
        width: a.width,
        height: a.height,
        frames,
        frames_gb: (frames * a.width * a.height * 2) as f64 / 1e9,
        upsample: a.upsample,
        passes: a.passes,
        tiles,
        bands: rows.len(),
        read_by_band: stderr.contains("band by band"),
        mosaic_gb: (a.width * a.height * a.upsample * a.upsample * 8) as f64 / 1e9,
        peak_rss_gb,
        reconstruct_s,
        write_s,
    };
    if !a.keep {
        std::fs::remove_dir_all(&a.scratch)
            .with_context(|| format!("removing {}", a.scratch.display()))?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&result)?);
        return Ok(());
    }
    let r = &result;
    println!(
        "{} frames of {}x{} ({:.1} GB as 16-bit), U = {}, {} pass(es), {} tiles in {} bands, frames {}:",
        r.frames,
        r.width,
        r.height,
        r.frames_gb,
        r.upsample,
        r.passes,
        r.tiles,
        r.bands,
        if r.read_by_band {
            "read from disk band by band"
        } else {
            "held in memory"
        }
    );
    println!(
        "  peak resident memory of fpm reconstruct: {:.2} GB (the HR mosaic alone: {:.2} GB as complex32); {:.0} s to reconstruct and write, {:.0} s to write the dataset",
        r.peak_rss_gb, r.mosaic_gb, r.reconstruct_s, r.write_s
    );
    Ok(())
}

/// A simulated `field`² acquisition repeated over `width × height`, written into
/// `dir` as a dataset; the number of frames.
fn write_dataset(a: &MemoryOptions, dir: &Path) -> Result<usize> {
    let source = a.scratch.join("field");
    let scene = Scene {
        truth: Scene::placed(0.0, 0.0, 0.0, 92.0),
        noise: Noise::Realistic,
        size: a.field,
        seed: 1,
        stray_light: 0.0,
    };
    if !a.json {
        eprintln!("simulating a {}² field…", a.field);
    }
    simulation::write_acquisition(&scene, &AcquisitionSet::default(), &source)?;
    let manifest =
        std::fs::read_to_string(source.join("dataset.toml")).context("the field's manifest")?;
    std::fs::create_dir_all(dir.join("frames"))
        .with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join("dataset.toml"), &manifest)?;
    let files: Vec<PathBuf> = std::fs::read_dir(source.join("frames"))?
        .map(|e| e.map(|e| e.path()))
        .collect::<std::io::Result<_>>()?;
    let bar = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(files.len() as u64)
    };
    for path in &files {
        let Pixels::U16(field) = image_io::read(path)? else {
            bail!("{}: not 16-bit", path.display());
        };
        let (fh, fw) = field.dim();
        let frame = Array2::from_shape_fn((a.height, a.width), |(r, c)| field[[r % fh, c % fw]]);
        let name = path.file_name().context("frame name")?;
        image_io::write_tiff_u16(&dir.join("frames").join(name), frame.view())?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    std::fs::remove_dir_all(&source)?;
    Ok(files.len())
}
