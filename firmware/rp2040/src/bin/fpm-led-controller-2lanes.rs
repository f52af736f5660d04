//! The image for a chain cut into 2 runs, fed by GP16 and GP17: the whole array
//! shifts out twice as fast.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

fpm_firmware_rp2040::image!(2);
