//! Robustness of the real firmware image in an emulated RP2040, bad input arriving over
//! its USB CDC-ACM port (see `robustness_suite`).

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod robustness_suite;
