//! The LED controller as the service last found it: shown in `/api/status` and on the
//! page, and what decides whether a job that drives the rig is taken. A board that
//! speaks another protocol version is refused up front, with what to do, instead of
//! failing every job in turn; one flashed since is found at the next request.

use std::time::Duration;

use fpm_acquire::controller::{Controller, ControllerError};
use serde::Serialize;
use utoipa::ToSchema;

/// How long the service's own look at the board waits for each answer.
const CHECK_TIMEOUT: Duration = Duration::from_secs(2);

/// What the service knows of its LED controller.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum Board {
    /// Not looked at yet (the service has just started).
    Unchecked {
        /// The serial port.
        port: String,
    },
    /// It answered the handshake in this host's protocol.
    Ready {
        /// The serial port.
        port: String,
        /// The protocol version it speaks.
        protocol: String,
        /// Its firmware's version.
        firmware: String,
        /// The board's name.
        name: String,
        /// Its serial number.
        serial: u64,
    },
    /// It speaks a protocol version this host does not: jobs that drive the rig are
    /// refused until the firmware (or this host) is updated.
    Mismatch {
        /// The serial port.
        port: String,
        /// The protocol version this host speaks.
        host: String,
        /// The one the board speaks.
        device: String,
        /// What is wrong and what to do, as a refused job is told.
        error: String,
    },
    /// It could not be opened or did not answer (unplugged, in use, not an fpm board):
    /// a job waits a while for it when it runs.
    Unreachable {
        /// The serial port.
        port: String,
        /// Why, as the controller client said it.
        error: String,
    },
}

impl Board {
    /// Open the controller on `port`, read its version and identity, and close it.
    pub fn check(port: &str) -> Self {
        match Controller::open(port, CHECK_TIMEOUT) {
            Ok(dev) => Self::of(&dev),
            Err(e) => Self::from_error(port, &e),
        }
    }

    /// A controller that answered the handshake.
    pub fn of(dev: &Controller) -> Self {
        let info = dev.info();
        Self::Ready {
            port: dev.port().to_owned(),
            protocol: info.protocol.to_string(),
            firmware: info.firmware.to_string(),
            name: info.board.to_string(),
            serial: info.serial,
        }
    }

    /// What opening the controller on `port` failed with says of it.
    pub fn from_error(port: &str, e: &ControllerError) -> Self {
        match e {
            ControllerError::VersionMismatch { host, device, .. } => Self::Mismatch {
                port: port.to_owned(),
                host: host.to_string(),
                device: device.to_string(),
                error: refusal_text(e),
            },
            other => Self::Unreachable {
                port: port.to_owned(),
                error: other.to_string(),
            },
        }
    }

    /// Why a job that drives the rig is refused now (None: it is taken).
    pub fn refusal(&self) -> Option<&str> {
        match self {
            Self::Mismatch { error, .. } => Some(error),
            _ => None,
        }
    }
}

/// A version mismatch as a refused request says it: the client's error (both versions
/// and which side to update, how), then what the service does meanwhile.
fn refusal_text(e: &ControllerError) -> String {
    format!(
        "{e}; jobs that drive the rig are refused until then, and the board is looked at again with the next one"
    )
}
