//! `fpm bench …`: the flags of fpm's measurements; the measurements are `fpm-bench`'s.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use fpm_bench::{LinkOptions, MemoryOptions};

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Request round-trip over the serial link: ping and a 441-LED pattern.
    Link(LinkArgs),
    /// pdcFPM calibration accuracy and speed on simulated data: the paper's Table 1, an
    /// off-axis feature, and a random sweep of the paper's range; then whether the
    /// reported uncertainties cover the errors over random hard cases.
    Calibration {
        /// Random cases in the sweep.
        #[arg(long, default_value_t = 30)]
        random: usize,
        /// Random hard cases for the uncertainty coverage (dim and bright exposures,
        /// 15–60 µm features on and off axis, defocus ±100–300 µm); 0 skips it.
        #[arg(long, default_value_t = 100)]
        coverage: usize,
        /// Seed of the sweep.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Calibrate each sweep case this many times and keep the median time (this
        /// machine's noise is as large as the differences that matter).
        #[arg(long, default_value_t = 5)]
        repeat: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// One DPC update (four half-circle frames to phase and absorption) on one core,
    /// against the six FFTs it needs.
    Dpc {
        /// Frame side, pixels.
        #[arg(long, default_value_t = 256)]
        size: usize,
        /// Updates timed.
        #[arg(long, default_value_t = 200)]
        rounds: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Reconstruction quality with a misplaced LED array: nominal vs pdcFPM-calibrated vs
    /// true geometry (the paper's Fig. 1 and 5 trends).
    Geometry {
        /// Camera field, pixels.
        #[arg(long, default_value_t = 128)]
        size: usize,
        /// EPRY passes.
        #[arg(long, default_value_t = 10)]
        passes: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// How often each reconstruction warning fires on good simulated sets (false alarms)
    /// and on sets with the condition it names (detections): three samples, 12- and
    /// 8-bit cameras, auto and dim dark field; an undeclared display gamma, a wrong LED
    /// height, a non-telecentric objective.
    Warnings {
        /// Seeds of good sets (12 sets each).
        #[arg(long, default_value_t = 4)]
        seeds: u64,
        /// Seeds of sets with a fault (18 sets each).
        #[arg(long, default_value_t = 2)]
        fault_seeds: u64,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Camera-frame hand-off through iceoryx2 shared memory versus a Unix socket, for
    /// 2048² and 5472×3648 (20 MP) frames.
    Frames {
        /// Frames per size.
        #[arg(long, default_value_t = 200)]
        rounds: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// EPRY speed: one frame update against the two FFTs it needs, one pass over 441
    /// frames, and the streaming latency (last frame → final image), in the same run.
    Epry {
        /// Camera field, pixels.
        #[arg(long, default_value_t = 256)]
        size: usize,
        /// HR pixels per camera pixel.
        #[arg(long, default_value_t = 4)]
        upsample: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Peak memory of a large reconstruction (441 frames of 20 MP by default): the
    /// dataset is written to disk, `fpm reconstruct` runs on it in a child process, and
    /// its peak resident set is read from the kernel.
    Memory(MemoryArgs),
    /// The whole `fpm reconstruct` process on a 441-frame set, timed from outside,
    /// beside EPRY alone and each automatic step (from the run's report.json), and
    /// fpm-rs's EPRY on the same frames when a Python with fpm-rs is at hand.
    Reconstruct(ReconstructArgs),
    /// LED switch time of single-LED scans (the firmware's chain model): full chain
    /// versus partial shifts, for 1, 2 and 4 data lanes.
    LedSwitch {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// The acquisition service as its clients see it, on virtual rigs started for the
    /// run: API round trips (1 and 50 clients), event and snapshot latency, cancel, and
    /// its overhead on a 441-LED acquisition against `fpm acquire`.
    Serve(ServeArgs),
    /// Fields per hour of a whole-slide scan on the virtual rig (calibrated at the
    /// first field, stitched), each field reconstructed while the next is acquired,
    /// against the same scan reconstructing the fields after it.
    Scan {
        /// The grid, ROWSxCOLS.
        #[arg(long, default_value = "3x3", value_parser = crate::scan::rows_cols)]
        fields: (usize, usize),
        /// Sensor side, pixels (192–1024).
        #[arg(long, default_value_t = 192)]
        size: usize,
        /// Light only the central LEDS × LEDS of the array per field (default: all).
        #[arg(long)]
        leds: Option<usize>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

/// `fpm bench serve`'s flags.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Requests per round-trip measurement.
    #[arg(long, default_value_t = 2000)]
    requests: usize,
    /// Concurrent clients in the loaded round-trip measurement.
    #[arg(long, default_value_t = 50)]
    clients: usize,
    /// The virtual camera's side, pixels (default: `fpm serve --virtual`'s, 256).
    #[arg(long)]
    size: Option<usize>,
    /// How long each LED is lit, ms (default: the service's, 40).
    #[arg(long)]
    step_ms: Option<f64>,
    /// Acquisitions per side in the overhead comparison (alternating).
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// The virtual rig's controller the real firmware image (the UF2 users flash) in an
    /// emulated RP2040, on both sides (`fpm serve --virtual-firmware`).
    #[arg(long, value_name = "UF2")]
    firmware: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
pub struct LinkArgs {
    /// Controller port; without it an emulator is started on a pseudo-terminal.
    #[arg(long)]
    port: Option<String>,
    /// Requests per measurement.
    #[arg(long, default_value_t = 2000)]
    count: usize,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// `fpm bench memory`'s flags.
#[derive(Args, Debug)]
pub struct MemoryArgs {
    /// Frame width, pixels (default: a 20 MP sensor).
    #[arg(long, default_value_t = 5472)]
    width: usize,
    /// Frame height, pixels.
    #[arg(long, default_value_t = 3648)]
    height: usize,
    /// Side of the simulated field that is repeated across the frame, pixels.
    #[arg(long, default_value_t = 512)]
    field: usize,
    /// Where the dataset and the reconstruction go (needs the frames' size on disk:
    /// 17.6 GB for 441 frames of 20 MP). Removed at the end unless --keep.
    #[arg(long, default_value = "fpm-bench-memory")]
    scratch: PathBuf,
    /// EPRY passes (the peak does not depend on them).
    #[arg(long, default_value_t = 1)]
    passes: usize,
    /// HR pixels per camera pixel.
    #[arg(long, default_value_t = 4)]
    upsample: usize,
    /// Passed to `fpm reconstruct` (frames above it are read from disk band by band);
    /// its default when not given.
    #[arg(long)]
    frame_memory_gb: Option<f64>,
    /// Keep the dataset and the reconstruction.
    #[arg(long)]
    keep: bool,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// `fpm bench reconstruct`'s flags.
#[derive(Args, Debug)]
pub struct ReconstructArgs {
    /// A dataset to reconstruct (default: 441 frames simulated for the run).
    #[arg(long)]
    dataset: Option<std::path::PathBuf>,
    /// Sensor side of the simulated set, pixels.
    #[arg(long, default_value_t = 256)]
    size: usize,
    /// EPRY passes.
    #[arg(long, default_value_t = 3)]
    passes: usize,
    /// HR pixels per camera pixel (default: `fpm reconstruct`'s).
    #[arg(long)]
    upsample: Option<usize>,
    /// Runs of `fpm reconstruct`; the median is reported.
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// A Python with fpm-rs, numpy and tifffile (default: the venv
    /// tools/peers/compare.sh makes, when it exists).
    #[arg(long)]
    peers_python: Option<std::path::PathBuf>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

impl From<ReconstructArgs> for fpm_bench::reconstruct::ReconstructOptions {
    fn from(a: ReconstructArgs) -> Self {
        Self {
            dataset: a.dataset,
            size: a.size,
            passes: a.passes,
            upsample: a.upsample,
            rounds: a.rounds,
            peers_python: a.peers_python,
            json: a.json,
        }
    }
}

/// Run one benchmark.
pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Link(a) => fpm_bench::link::run(LinkOptions {
            port: a.port,
            count: a.count,
            json: a.json,
        }),
        BenchCommand::LedSwitch { json } => fpm_bench::led_switch::run(json),
        BenchCommand::Calibration {
            random,
            coverage,
            seed,
            repeat,
            json,
        } => fpm_bench::calibration::run(random, coverage, seed, repeat, json),
        BenchCommand::Dpc { size, rounds, json } => fpm_bench::dpc::run(size, rounds, json),
        BenchCommand::Geometry { size, passes, json } => {
            fpm_bench::geometry::run(size, passes, json)
        }
        BenchCommand::Warnings {
            seeds,
            fault_seeds,
            json,
        } => fpm_bench::warnings::run(seeds, fault_seeds, json),
        BenchCommand::Frames { rounds, json } => fpm_bench::frames::run(rounds, json),
        BenchCommand::Memory(a) => fpm_bench::memory::run(MemoryOptions {
            width: a.width,
            height: a.height,
            field: a.field,
            scratch: a.scratch,
            passes: a.passes,
            upsample: a.upsample,
            frame_memory_gb: a.frame_memory_gb,
            keep: a.keep,
            json: a.json,
        }),
        BenchCommand::Reconstruct(a) => fpm_bench::reconstruct::run(a.into()),
        BenchCommand::Epry {
            size,
            upsample,
            json,
        } => fpm_bench::epry::run(size, upsample, json),
        BenchCommand::Scan {
            fields,
            size,
            leds,
            json,
        } => {
            let fpm = std::env::current_exe().context("locating the fpm executable")?;
            fpm_bench::scan::run(
                &fpm_bench::scan::ScanOptions {
                    rows: fields.0,
                    cols: fields.1,
                    size,
                    leds,
                    json,
                },
                &fpm,
            )
            .map(drop)
        }
        BenchCommand::Serve(a) => fpm_bench::serve::run(fpm_bench::serve::ServeOptions {
            requests: a.requests,
            clients: a.clients,
            size: a.size,
            step_ms: a.step_ms,
            rounds: a.rounds,
            firmware: a.firmware,
            json: a.json,
        }),
    }
}
