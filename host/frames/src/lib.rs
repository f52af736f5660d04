//! # fpm-frames
//!
//! How camera frames reach the host: an iceoryx2 publish-subscribe service of `[u16]`
//! pixel slices with a [`FrameHeader`] user header, and an event service on which the
//! publisher signals each frame, so the consumer sleeps until one arrives. Frames are
//! written once into shared memory by the camera side and read in place by the host.
//!
//! * Service names: [`ServiceNames::for_camera`] — `fpm/camera/<id>/frames` (publish-
//!   subscribe) and `fpm/camera/<id>/frame-ready` (event, id [`FRAME_READY`]).
//! * Header: 48 bytes, `#[repr(C)]`, type name [`FrameHeader::TYPE_NAME`]; see its
//!   field docs for the offsets a C, C++ or Python driver must match.
//! * Memory: one data segment per publisher of
//!   `(max_subscribers · (buffer + borrowed) + loaned)` = [`SAMPLES_PER_PUBLISHER`]
//!   frames of the publisher's maximum size; 7 × 40 MB = 280 MB reserved for 20 MP
//!   frames (pages are committed only when written).
//! * A slow consumer loses the oldest buffered frame (iceoryx2's safe overflow), never
//!   blocks the camera; gaps show in `frame_number`, which the consumer checks.

mod header;
mod publisher;
mod service;
mod settings;
mod snapshots;
mod subscriber;

pub use header::FrameHeader;
pub use iceoryx2::prelude::LogLevel;
pub use publisher::{FrameLoan, FramePublisher};
pub use service::{
    cleanup_stale, node, set_ipc_log_level, stale_nodes, ServiceNames, FRAME_READY,
    SAMPLES_PER_PUBLISHER,
};
pub use settings::{read_settings, SettingsPublisher, MAX_SETTINGS_BYTES};
pub use snapshots::{
    snapshot_service_name, SnapshotHeader, SnapshotPublisher, SnapshotSubscriber, SnapshotView,
};
pub use subscriber::{Frame, FrameSubscriber};

/// The largest frame the contract is sized for by default: 5472 × 3648 (20 MP).
pub const DEFAULT_MAX_PIXELS: usize = 5472 * 3648;

/// Everything that can go wrong moving frames.
#[derive(Debug, thiserror::Error)]
pub enum FrameError {
    /// An iceoryx2 call failed.
    #[error("iceoryx2: {what}: {detail}")]
    Ipc {
        /// The step that failed.
        what: &'static str,
        /// iceoryx2's error.
        detail: String,
    },
    /// A frame or header that breaks the contract.
    #[error("frame {frame_number}: {field} {problem}")]
    Invalid {
        /// The frame's number (as sent).
        frame_number: u64,
        /// The offending header field.
        field: &'static str,
        /// What is wrong with it.
        problem: String,
    },
    /// A frame bigger than the publisher was set up for.
    #[error("frame of {pixels} pixels exceeds this publisher's maximum of {max}")]
    TooLarge {
        /// Pixels in the frame.
        pixels: usize,
        /// The publisher's maximum.
        max: usize,
    },
}

/// Turn an iceoryx2 error of step `what` into a [`FrameError`] (for crates that build
/// further services on [`node`]).
pub fn ipc_error(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> FrameError {
    ipc(what)
}

pub(crate) fn ipc(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> FrameError {
    move |e| FrameError::Ipc {
        what,
        detail: format!("{e:?}"),
    }
}
