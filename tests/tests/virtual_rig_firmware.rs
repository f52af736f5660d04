//! The virtual rig with the real firmware image in an emulated RP2040: the LEDs the
//! camera sees at each trigger are those decoded from the firmware's WS2812 pin, so a
//! bright frame under a bright-field LED shows that the step's LEDs had latched before
//! the trigger (see `virtual_rig_suite`).

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod virtual_rig_suite;
