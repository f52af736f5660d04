//! # fpm-host
//!
//! The jobs fpm runs on datasets, without devices or processes: calibration and
//! reconstruction and their outputs (the reports for people are `fpm-report`'s),
//! colour, DPC, scan stitching, simulation, and scoring against a simulation's truth.
//! The files are `fpm-dataset`'s (re-exported here as `dataset`, `ome`, `ome_zarr` and
//! `pyramid`), the physics `fpm-physics`'s; acquisition from a live rig is
//! `fpm-acquire`'s.

pub use fpm_dataset::{dataset, ome, ome_zarr, pyramid};

pub mod calibration;
pub mod camera_gamma;
pub mod color;
pub mod dpc;
pub mod reconstruction;
pub mod refinement;
pub mod scan;
pub mod simulation;
pub mod truth;
