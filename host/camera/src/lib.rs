//! # fpm-camera
//!
//! Real cameras into the frame contract ([`fpm_frames`]): GenICam cameras (GigE
//! Vision, USB3 Vision) through aravis, loaded at run time so that nothing else in fpm
//! needs it. `fpm camera run --aravis` opens the camera, sets what a capture needs
//! ([`settings`]), and publishes every frame with the camera's timestamp, decoding
//! packed pixels straight into shared memory ([`pixels`]).

pub mod aravis;
pub mod pixels;
pub mod run;
pub mod settings;
