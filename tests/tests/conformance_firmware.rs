//! Conformance against the real firmware: the UF2 image users flash, booted in an
//! emulated RP2040 (`fpm emulator --firmware`, rp2040js under Node), its USB CDC-ACM
//! port behind a pseudo-terminal. The same suite as for the host-compiled emulator.

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod conformance_suite;
