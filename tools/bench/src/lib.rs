//! # fpm-bench
//!
//! `fpm bench …`: fpm's measurements, reported as percentiles with the conditions
//! they were measured under and, where speed is the question, as ratios against a
//! baseline measured in the same run (these machines are noisy). One module per
//! benchmark; the criterion micro-benchmark of the EPRY update is `benches/epry.rs`.

mod calibration;
mod epry;
mod fftw;
mod frames;
mod geometry;
mod led_switch;
mod link;
mod memory;
mod stats;

use anyhow::Result;
use clap::{Args, Subcommand};

pub use stats::Percentiles;

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
    Memory(memory::MemoryArgs),
    /// LED switch time of single-LED scans (the firmware's chain model): full chain
    /// versus partial shifts, for 1, 2 and 4 data lanes.
    LedSwitch {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
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

/// Run one benchmark.
pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Link(a) => link::run(a),
        BenchCommand::LedSwitch { json } => led_switch::run(json),
        BenchCommand::Calibration {
            random,
            coverage,
            seed,
            repeat,
            json,
        } => calibration::run(random, coverage, seed, repeat, json),
        BenchCommand::Geometry { size, passes, json } => geometry::run(size, passes, json),
        BenchCommand::Frames { rounds, json } => frames::run(rounds, json),
        BenchCommand::Memory(a) => memory::run(a),
        BenchCommand::Epry {
            size,
            upsample,
            json,
        } => epry::run(size, upsample, json),
    }
}
