//! # fpm-host
//!
//! fpm on the host, without devices or processes: the dataset format
//! (`docs/dataset.md`), calibration and reconstruction of datasets with their reports
//! and outputs, and scoring against a simulation's truth. The physics is
//! `fpm-physics`; acquisition from a live rig is `fpm-acquire`.

pub mod calibration;
pub mod camera_gamma;
pub mod charts;
pub mod colour_bar;
pub mod dataset;
pub mod glyphs;
pub mod html;
pub mod ome;
pub mod ome_zarr;
pub mod pages;
pub mod pyramid;
pub mod reconstruction;
pub mod refinement;
pub mod scale_bar;
pub mod simulation;
pub mod truth;
