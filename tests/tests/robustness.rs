//! Robustness against the host-compiled emulator (see `robustness_suite`).

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::HostEmulator;

mod robustness_suite;
