//! The virtual rig with the host-compiled emulator (see `virtual_rig_suite`).

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::HostEmulator;

mod virtual_rig_suite;
