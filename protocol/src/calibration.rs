//! The array placement a board remembers: the last calibration, stored on the
//! controller so that any host that opens it starts from the measured geometry.
//!
//! Added in protocol 1.1. A host asks [`ProtocolVersion::supports`] with
//! [`BoardCalibration::SINCE`] before using these endpoints on an older device.

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::ProtocolVersion;

/// One standard deviation of each placement parameter (0 when the calibration did
/// not state one).
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PlacementSigma {
    /// σ of Δx, mm.
    pub dx_mm: f32,
    /// σ of Δy, mm.
    pub dy_mm: f32,
    /// σ of θ, degrees.
    pub theta_deg: f32,
    /// σ of h, mm.
    pub height_mm: f32,
}

/// The measured placement of the LED array (docs/dataset.md §1: Δx, Δy, θ, h), with
/// how sure the calibration was and when it was made.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BoardCalibration {
    /// Δx, mm.
    pub dx_mm: f32,
    /// Δy, mm.
    pub dy_mm: f32,
    /// θ, degrees.
    pub theta_deg: f32,
    /// h, LED plane to sample, mm.
    pub height_mm: f32,
    /// 1 σ of each.
    pub sigma: PlacementSigma,
    /// RMS residual of the calibration fit, µm at the sample (0 if unknown).
    pub rms_residual_um: f32,
    /// When the calibration was made, seconds since 1970-01-01 UTC (0 if unknown).
    pub calibrated_unix_s: u64,
}

impl BoardCalibration {
    /// The protocol version that introduced the geometry endpoints.
    pub const SINCE: ProtocolVersion = crate::PROTOCOL_1_1;

    /// Whether every number is usable: finite, h > 0, σ and residual ≥ 0.
    pub fn is_valid(&self) -> bool {
        let placement = [self.dx_mm, self.dy_mm, self.theta_deg, self.height_mm];
        let spreads = [
            self.rms_residual_um,
            self.sigma.dx_mm,
            self.sigma.dy_mm,
            self.sigma.theta_deg,
            self.sigma.height_mm,
        ];
        placement.iter().all(|x| x.is_finite())
            && spreads.iter().all(|x| x.is_finite() && *x >= 0.0)
            && self.height_mm > 0.0
    }
}

/// What the board has stored.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoredCalibration {
    /// Nothing was ever stored (or it was forgotten).
    NotCalibrated,
    /// The storage holds records, but none is intact: treat as not calibrated.
    Damaged,
    /// The last calibration stored.
    Calibrated(BoardCalibration),
}

/// Why the board did not store a calibration.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StorageError {
    /// A sequence is running (writing flash would stall it).
    Busy,
    /// A number is not finite, h ≤ 0 or a σ is negative.
    Invalid,
    /// This board has no storage for it.
    NoStorage,
    /// The flash reported an error, or did not read back what was written.
    Flash,
}

impl core::fmt::Display for StorageError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Busy => "a sequence is running; store the geometry after it ends",
            Self::Invalid => "the geometry is not usable (non-finite number, h ≤ 0 or negative σ)",
            Self::NoStorage => "this controller has no storage for a geometry",
            Self::Flash => "the flash write failed or did not read back",
        })
    }
}

/// Request of the geometry set endpoint: the calibration to store, or `None` to
/// forget the stored one.
pub type CalibrationUpdate = Option<BoardCalibration>;

/// Reply of the geometry set endpoint: what is stored now.
pub type StoreResult = Result<StoredCalibration, StorageError>;
