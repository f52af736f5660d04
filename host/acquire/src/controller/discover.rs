//! Finding controllers: USB serial ports with the board's vendor and product id, plus
//! ports named by the user (an emulator's link, an RS-232 adapter), each asked who it
//! is over the protocol.

use std::time::Duration;

use fpm_protocol::{DeviceInfo, USB_PID, USB_VID};
use serde::Serialize;

use super::Controller;

/// Ports to look at besides USB ones, separated like `PATH` (`:` on Unix).
pub const EXTRA_PORTS_ENV: &str = "FPM_EXTRA_PORTS";

/// A port that may hold a controller.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate {
    /// Device path.
    pub port: String,
    /// USB identity, for ports found by vendor and product id.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub usb: Option<UsbIdentity>,
}

/// What USB says about a port.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UsbIdentity {
    /// "1209:0001".
    pub vid_pid: String,
    /// The USB serial number string, if the device reports one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub serial_number: Option<String>,
}

/// A candidate with what it answered.
#[derive(Debug, Clone, Serialize)]
pub struct Found {
    /// The port.
    #[serde(flatten)]
    pub candidate: Candidate,
    /// Its identity, if it answered as a controller.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub info: Option<DeviceInfo>,
    /// Why not, if it did not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The ports to ask: USB serial ports with our vendor and product id (from sysfs, no
/// libudev needed), then the paths in [`EXTRA_PORTS_ENV`], each once.
pub fn candidates() -> Vec<Candidate> {
    let mut found: Vec<Candidate> = serialport::available_ports()
        .unwrap_or_default()
        .into_iter()
        .filter_map(|p| match p.port_type {
            serialport::SerialPortType::UsbPort(usb)
                if usb.vid == USB_VID && usb.pid == USB_PID =>
            {
                Some(Candidate {
                    port: p.port_name,
                    usb: Some(UsbIdentity {
                        vid_pid: format!("{:04x}:{:04x}", usb.vid, usb.pid),
                        serial_number: usb.serial_number,
                    }),
                })
            }
            _ => None,
        })
        .collect();
    if let Some(extra) = std::env::var_os(EXTRA_PORTS_ENV) {
        for path in std::env::split_paths(&extra) {
            let port = path.to_string_lossy().into_owned();
            if !port.is_empty() && !found.iter().any(|c| c.port == port) {
                found.push(Candidate { port, usb: None });
            }
        }
    }
    found
}

/// Ask every candidate who it is (one at a time: a port is opened by one host only).
pub fn probe(candidates: Vec<Candidate>, timeout: Duration) -> Vec<Found> {
    candidates
        .into_iter()
        .map(
            |candidate| match Controller::open(&candidate.port, timeout) {
                Ok(dev) => Found {
                    info: Some(dev.info().clone()),
                    error: None,
                    candidate,
                },
                Err(e) => Found {
                    info: None,
                    error: Some(e.to_string()),
                    candidate,
                },
            },
        )
        .collect()
}

/// The one controller connected, for commands run without `--port`: an error that
/// lists what was found when there is none or more than one.
pub fn the_only_board(timeout: Duration) -> Result<String, String> {
    let found = probe(candidates(), timeout);
    let boards: Vec<&Found> = found.iter().filter(|f| f.info.is_some()).collect();
    match boards.as_slice() {
        [one] => Ok(one.candidate.port.clone()),
        [] => Err(format!(
            "no LED controller found (USB {USB_VID:04x}:{USB_PID:04x}{}); give --port, or list other ports in {EXTRA_PORTS_ENV}",
            if found.is_empty() {
                String::new()
            } else {
                format!(
                    "; ports that did not answer: {}",
                    found
                        .iter()
                        .map(|f| format!(
                            "{} ({})",
                            f.candidate.port,
                            f.error.as_deref().unwrap_or("?")
                        ))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        )),
        many => Err(format!(
            "{} LED controllers found ({}); choose one with --port",
            many.len(),
            many.iter()
                .map(|f| f.candidate.port.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The udev rule shipped in the repository matches the ids boards enumerate with.
    #[test]
    fn the_udev_rule_matches_the_boards_usb_ids() {
        let rule = include_str!("../../../../udev/99-fpm.rules");
        let line = rule
            .lines()
            .find(|l| l.starts_with("SUBSYSTEM"))
            .expect("a rule line");
        assert!(line.contains(&format!("ATTRS{{idVendor}}==\"{USB_VID:04x}\"")));
        assert!(line.contains(&format!("ATTRS{{idProduct}}==\"{USB_PID:04x}\"")));
        assert!(line.contains("SYMLINK+=\"fpm-$attr{serial}\""));
    }

    #[test]
    fn extra_ports_are_asked_once_each() {
        std::env::set_var(EXTRA_PORTS_ENV, "/tmp/a.tty:/tmp/b.tty:/tmp/a.tty:");
        let ports: Vec<String> = candidates()
            .into_iter()
            .filter(|c| c.usb.is_none())
            .map(|c| c.port)
            .collect();
        std::env::remove_var(EXTRA_PORTS_ENV);
        assert_eq!(ports, ["/tmp/a.tty", "/tmp/b.tty"]);
    }
}
