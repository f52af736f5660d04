//! # fpm-dataset
//!
//! The files fpm reads and writes, and nothing computed on them: the dataset format
//! (`docs/dataset.md`: `dataset.toml` plus one TIFF or PNG per frame, strict on load),
//! the OME-XML that gives the reconstruction's TIFFs their physical units, OME-Zarr
//! with its multiscale pyramid, and the 2×2 reductions those pyramids are made of.
//! The jobs that use them (calibration, reconstruction, colour, scans) are `fpm-host`'s,
//! which re-exports these modules under the same names.

pub mod dataset;
pub mod ome;
pub mod ome_zarr;
pub mod pyramid;
