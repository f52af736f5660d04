//! # fpm-acquire
//!
//! Acquisition from a live rig, in the order a frame travels:
//!
//! * [`controller`]: the typed client of the LED controller (board or emulator) over a
//!   serial port;
//! * [`capture`]: one capture sequence — the controller steps through LEDs, the camera's
//!   frames are taken off the iceoryx2 frame service (the one copy out of shared
//!   memory) and every frame is labelled with the LED that lit it: [`labeller`], the
//!   sans-IO state machine the capture loop feeds (steps and frames in, labels out),
//!   on [`label`], the pairing of camera stamps with controller triggers;
//! * [`stage`]: how the focus stage moves (by hand, or a motorised or virtual stage);
//! * [`board_geometry`]: the array geometry a board stores, from and to a calibration;
//! * [`acquisition`]: the acquisition as a sans-IO state machine — calibrate (pdcFPM)
//!   → order nearest-first → capture → retake what is missing → stream into the
//!   reconstruction → write the dataset — events in, actions out;
//! * [`rig`]: what every driver reads from the rig before it starts;
//! * [`control`]: how a running acquisition is watched and steered, in every mode;
//! * [`pipeline`]: the I/O loop that drives it on a live rig.
//!
//! Nothing here knows whether the rig is real or virtual.

pub mod acquisition;
pub mod board_geometry;
pub mod capture;
pub mod color;
pub mod control;
pub mod controller;
pub mod dpc;
pub mod journal;
pub mod label;
pub mod labeller;
pub mod multiplexed;
pub mod page;
pub mod pipeline;
pub mod rig;
pub mod scan;
pub mod stage;
pub mod stream;
pub mod summary;

pub use acquisition::{Acquisition, Action, Event, Phase, Progress, Snapshot};
pub use capture::{capture, CaptureReport, Sequence, Shot, ShotView};
pub use controller::Controller;
pub use pipeline::{acquire, AcquireSummary, Plan, Watcher};
pub use stage::{
    FocusStage, ManualStage, MotorisedFocus, Slide, StageChoice, StagePosition, TowardLeds,
};
