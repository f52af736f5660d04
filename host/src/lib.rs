//! # fpm-host
//!
//! fpm on the host, without devices or processes: the dataset format
//! (`docs/dataset.md`), calibration and reconstruction of datasets and their outputs
//! (the reports for people are `fpm-report`'s), and scoring against a simulation's truth. The physics is
//! `fpm-physics`; acquisition from a live rig is `fpm-acquire`.

pub mod calibration;
pub mod camera_gamma;
pub mod color;
pub mod dataset;
pub mod dpc;
pub mod ome;
pub mod ome_zarr;
pub mod pyramid;
pub mod reconstruction;
pub mod refinement;
pub mod scan;
pub mod simulation;
pub mod truth;
