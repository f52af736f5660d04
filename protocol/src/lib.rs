//! # fpm-protocol: the LED controller's wire contract
//!
//! Everything that crosses the serial link between the fpm LED controller (the RP2040
//! firmware or its emulator) and the host lives here, shared verbatim by both sides.
//!
//! * Transport: a byte stream (USB CDC-ACM or a pseudo-terminal) carrying COBS frames,
//!   each frame one [postcard-rpc](postcard_rpc) message: a header (key + sequence number)
//!   followed by a postcard body.
//! * Keys are hashes of an endpoint's path *and* its message schema, so a peer built
//!   against a different message layout gets `WireError::UnknownKey` instead of
//!   mis-decoding bytes.
//! * [`VersionEndpoint`] is frozen: its path and types never change, so any host can ask
//!   any firmware which protocol it speaks before using anything else.
//!
//! The endpoint and topic tables are in [`icd`]; the limits a device enforces are in
//! [`limits`].
#![no_std]
#![deny(missing_docs)]

pub mod board;
pub mod calibration;
pub mod error;
pub mod icd;
pub mod led_sets;
pub mod light;
pub mod limits;
pub mod sequence;

pub use board::*;
pub use calibration::*;
pub use error::*;
pub use icd::*;
pub use led_sets::*;
pub use light::*;
pub use sequence::*;

pub use postcard_rpc;
pub use postcard_rpc::standard_icd::{WireError, ERROR_PATH};

use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Version of this wire contract.
///
/// `major` changes when an existing message changes meaning or layout; `minor` when
/// endpoints or topics are added. A host talks to any device with the same `major`;
/// before using an endpoint added in a later minor version it checks
/// [`ProtocolVersion::supports`], so that an older device gets a clear "update the
/// firmware" instead of an unknown key.
///
/// History: 1.0 lighting, budget, sequences; 1.1 the stored board geometry
/// (`fpm/board/geometry`) and gamma correction (`fpm/light/gamma`); 1.2 LED sets lit
/// whole by sequence steps (`fpm/light/set/define`, `fpm/seq/set-steps`,
/// `fpm/seq/set-step`: [`led_sets`]); 1.3 the reboot into the boot ROM's USB mode
/// (`fpm/device/bootsel`), for flashing a board in place.
pub const PROTOCOL_VERSION: ProtocolVersion = PROTOCOL_1_3;

/// USB vendor id the controller enumerates with (pid.codes, the open-hardware vendor id).
/// Hosts find boards by it (`fpm device list`); the udev rule in `udev/` matches it.
pub const USB_VID: u16 = 0x1209;
/// USB product id: pid.codes' test PID, fine for development; register a PID before
/// shipping boards.
pub const USB_PID: u16 = 0x0001;

/// Protocol 1.3: what a device must speak for [`BootselEndpoint`].
pub const PROTOCOL_1_3: ProtocolVersion = ProtocolVersion { major: 1, minor: 3 };

/// Protocol 1.1: what a device must speak for the stored geometry and gamma endpoints.
pub const PROTOCOL_1_1: ProtocolVersion = ProtocolVersion { major: 1, minor: 1 };

/// A protocol version, as reported by [`VersionEndpoint`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ProtocolVersion {
    /// Incompatible changes.
    pub major: u16,
    /// Compatible additions.
    pub minor: u16,
}

impl ProtocolVersion {
    /// Whether a host built against `self` can talk to a device speaking `device` at
    /// all (same major version; later additions are checked with [`Self::supports`]).
    pub fn accepts(&self, device: &ProtocolVersion) -> bool {
        self.major == device.major
    }

    /// Whether a device speaking `self` has what was added in `since`.
    pub fn supports(&self, since: ProtocolVersion) -> bool {
        self.major == since.major && self.minor >= since.minor
    }
}

impl ProtocolVersion {
    /// Whether `self` comes before `other`.
    pub fn is_older_than(&self, other: &ProtocolVersion) -> bool {
        (self.major, self.minor) < (other.major, other.minor)
    }
}

impl core::fmt::Display for ProtocolVersion {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}.{}", self.major, self.minor)
    }
}
