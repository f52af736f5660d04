//! # fpm-bench
//!
//! `fpm bench …`: fpm's measurements, reported as percentiles with the conditions
//! they were measured under and, where speed is the question, as ratios against a
//! baseline measured in the same run (these machines are noisy). One module per
//! benchmark, each a `run` the CLI calls with its options (the flags are the CLI's);
//! the criterion micro-benchmark of the EPRY update is `benches/epry.rs`.

pub mod calibration;
pub mod dpc;
pub mod epry;
mod fftw;
pub mod frames;
pub mod geometry;
pub mod led_switch;
pub mod link;
pub mod memory;
pub mod reconstruct;
pub mod scan;
pub mod serve;
mod stats;
pub mod warnings;

pub use memory::MemoryOptions;
pub use stats::Percentiles;

/// `fpm bench link`'s options.
#[derive(Debug, Clone)]
pub struct LinkOptions {
    /// Controller port; without it an emulator is started on a pseudo-terminal.
    pub port: Option<String>,
    /// Requests per measurement.
    pub count: usize,
    /// Print JSON.
    pub json: bool,
}
