//! The image for a chain cut into 4 runs, fed by GP16 to GP19: the whole array shifts
//! out four times as fast.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

fpm_firmware_rp2040::image!(4);
