//! Typed errors of the application endpoints. Protocol-level failures (bad frame,
//! unknown key, undecodable body) use postcard-rpc's standard `WireError` instead.

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// A request parameter that was out of range.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Param {
    /// A numerical aperture (must be finite, in (0, 1]; annulus inner in [0, outer)).
    Na,
    /// Trigger pulse width (≥ 1 µs).
    PulseWidth,
    /// Trigger-in timeout (≥ 1 µs).
    TriggerTimeout,
    /// A sequence with zero steps.
    StepCount,
    /// A current budget of zero.
    Budget,
}

/// Why the device refused or stopped something.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeviceError {
    /// The LED is not on the board.
    BadLed {
        /// Requested row.
        row: u8,
        /// Requested column.
        col: u8,
    },
    /// A parameter is out of range.
    BadParam(Param),
    /// More LEDs or steps than the device accepts.
    TooMany {
        /// Requested count.
        requested: u32,
        /// The device's limit.
        max: u32,
    },
    /// A sequence is running; only status and abort are accepted.
    Busy,
    /// No sequence is running.
    NotRunning,
    /// The request names a sequence id other than the defined one.
    WrongSequence {
        /// The id given.
        requested: u32,
        /// The id defined (0 = none).
        defined: u32,
    },
    /// A chunk starts beyond the loaded steps or ends beyond the defined count.
    ChunkOutOfRange {
        /// Chunk offset.
        offset: u16,
        /// Chunk length.
        len: u16,
        /// Steps already loaded.
        loaded: u16,
        /// Steps defined.
        total: u16,
    },
    /// Start was requested before every step was uploaded.
    Incomplete {
        /// Steps loaded.
        loaded: u16,
        /// Steps defined.
        total: u16,
    },
    /// The request would draw more current than the budget allows.
    OverBudget {
        /// Current the request needs, mA.
        required_ma: u32,
        /// Budget, mA.
        limit_ma: u32,
        /// Offending sequence step, if the request was a sequence.
        step: Option<u16>,
    },
    /// The camera's trigger-in edge did not come within the timeout.
    TriggerTimeout {
        /// Step that timed out.
        step: u16,
    },
}

impl core::fmt::Display for DeviceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            DeviceError::BadLed { row, col } => {
                write!(f, "LED (row {row}, col {col}) is not on the board")
            }
            DeviceError::BadParam(p) => write!(f, "parameter out of range: {p:?}"),
            DeviceError::TooMany { requested, max } => {
                write!(
                    f,
                    "too many items: {requested} requested, the device takes {max}"
                )
            }
            DeviceError::Busy => f.write_str("a capture sequence is running (abort it first)"),
            DeviceError::NotRunning => f.write_str("no capture sequence is running"),
            DeviceError::WrongSequence { requested, defined } => write!(
                f,
                "sequence {requested} is not the defined sequence ({defined})"
            ),
            DeviceError::ChunkOutOfRange {
                offset,
                len,
                loaded,
                total,
            } => write!(
                f,
                "step chunk {offset}..{} does not fit: {loaded} of {total} steps loaded",
                *offset as u32 + *len as u32
            ),
            DeviceError::Incomplete { loaded, total } => {
                write!(f, "sequence incomplete: {loaded} of {total} steps loaded")
            }
            DeviceError::OverBudget {
                required_ma,
                limit_ma,
                step,
            } => {
                write!(f, "needs {required_ma} mA, over the {limit_ma} mA budget")?;
                if let Some(s) = step {
                    write!(f, " (step {s})")?;
                }
                Ok(())
            }
            DeviceError::TriggerTimeout { step } => {
                write!(f, "no trigger-in edge from the camera at step {step}")
            }
        }
    }
}

impl core::error::Error for DeviceError {}
