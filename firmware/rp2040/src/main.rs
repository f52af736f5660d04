//! The image for the usual wiring: the whole chain on one data line (GP16).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

fpm_firmware_rp2040::image!(1);
