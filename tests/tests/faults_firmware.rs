//! Faults with the real firmware image in an emulated RP2040 (see `faults_suite`).

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod faults_suite;
