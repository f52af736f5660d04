//! # fpm-physics
//!
//! The physics of Fourier ptychographic microscopy, as pure functions over arrays: no
//! files, no threads of its own beyond data-parallel loops, no clocks. Conventions are
//! those of `docs/dataset.md`: µm in the sample plane, mm for LED geometry,
//! cycles/µm for spatial frequencies, F(f) = Σ f(x)·exp(−i2π f·x).
//!
//! * [`optics`]: the system, LED geometry, illumination wave vectors, pupil, defocus;
//! * [`fft`]: 2-D FFTs with plans and scratch kept between calls;
//! * [`simulate`]: the full wave-optics forward model (finite LED distance, angular
//!   spectrum defocus, pupil, camera noise) and test objects;
//! * [`calibrate`]: pdcFPM — feature finding, defocus-shift measurement with a
//!   model-based bias correction, and the LED-array fit;
//! * [`frame`]: measured frames — counts, dark level, exposure — and the one
//!   conversion to intensity; [`background`]: a dark-field frame's own background;
//! * [`reconstruct`]: EPRY, offline, streaming and tiled; [`tiles`]: tile geometry and
//!   blending.

pub mod background;
pub mod bayer;
pub mod calibrate;
pub mod color;
pub mod coverage;
pub mod dpc;
pub mod fft;
pub mod frame;
pub mod image;
mod invalid;
pub mod led_list;
pub mod metrics;
pub mod multiplex;
pub mod optics;
pub mod reconstruct;
pub mod simulate;
pub mod stats;
pub mod stitch;
pub mod study;
pub mod tiles;

pub use image::Image;
pub use invalid::Invalid;
pub use led_list::{LedList, ListedLed};
pub use optics::{LedGeometry, LedIndex, Placement, Rings, System};
/// The complex type of every field (object, pupil, exit wave).
pub use rustfft::num_complex::Complex32;
