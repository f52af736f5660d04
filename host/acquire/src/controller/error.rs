//! What can go wrong talking to a controller, in words a user can act on.

use std::time::Duration;

use fpm_protocol::{DeviceError, ProtocolVersion, StorageError, WireError};

/// An error from the LED controller client.
#[derive(Debug, thiserror::Error)]
pub enum ControllerError {
    /// The port could not be opened.
    #[error("cannot open serial port {port}: {reason}")]
    Open {
        /// Port path.
        port: String,
        /// What the OS said.
        reason: String,
    },
    /// No answer within the request timeout.
    #[error("{port} did not answer {request} within {timeout:?}; is it an fpm LED controller, powered and not busy with another program?")]
    Timeout {
        /// Port path.
        port: String,
        /// Endpoint path.
        request: &'static str,
        /// The timeout.
        timeout: Duration,
    },
    /// The link closed (device unplugged, emulator stopped).
    #[error("lost the connection to {port} during {request}: the device was unplugged, reset or stopped")]
    Disconnected {
        /// Port path.
        port: String,
        /// Endpoint path, or what was being waited for.
        request: &'static str,
    },
    /// The device answers but does not know the version endpoint.
    #[error("the device at {port} does not speak the fpm protocol (it answered the version request with {reply})")]
    NotFpm {
        /// Port path.
        port: String,
        /// What it answered.
        reply: String,
    },
    /// The versions are incompatible.
    #[error("protocol version mismatch: this host speaks fpm protocol {host}, the controller at {port} speaks {device}; {advice}")]
    VersionMismatch {
        /// Port path.
        port: String,
        /// Host's version.
        host: ProtocolVersion,
        /// Device's version.
        device: ProtocolVersion,
        /// Which side to update.
        advice: &'static str,
    },
    /// The device rejected the request at the protocol level.
    #[error("the controller at {port} rejected {request}: {error}")]
    Wire {
        /// Port path.
        port: String,
        /// Endpoint path.
        request: &'static str,
        /// Its standard error.
        error: WireError,
    },
    /// A reply that did not decode.
    #[error("the controller at {port} sent an undecodable reply to {request}")]
    BadReply {
        /// Port path.
        port: String,
        /// Endpoint path.
        request: &'static str,
    },
    /// The device refused the request.
    #[error("the controller refused {request}: {error}")]
    Device {
        /// Endpoint path.
        request: &'static str,
        /// The device's reason.
        error: DeviceError,
    },
    /// The device's firmware predates the request.
    #[error("the controller at {port} speaks fpm protocol {device}, which has no {request} (added in {since}); flash newer firmware onto it")]
    Unsupported {
        /// Port path.
        port: String,
        /// Endpoint path.
        request: &'static str,
        /// The version that added it.
        since: ProtocolVersion,
        /// The device's version.
        device: ProtocolVersion,
    },
    /// The device did not store its calibration.
    #[error("the controller did not store the geometry: {0}")]
    Storage(StorageError),
    /// Invalid input on the host side, before anything was sent.
    #[error("{0}")]
    Invalid(String),
}

impl ControllerError {
    /// The device's own error, if it refused the request.
    pub fn device_error(&self) -> Option<DeviceError> {
        match self {
            ControllerError::Device { error, .. } => Some(*error),
            _ => None,
        }
    }
}
