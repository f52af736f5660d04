//! PICOBOOT over USB (nusb, no libusb): the RP2040 boot ROM's vendor interface (class
//! 0xFF) found on the bus by its ids, its two bulk endpoints claimed. Reaching it needs
//! the udev rule for USB 2e8a:0003 (`udev/99-fpm.rules`).

use std::time::Duration;

use nusb::descriptors::TransferType;
use nusb::transfer::{Buffer, Bulk, ControlIn, ControlOut, ControlType, In, Out, Recipient};
use nusb::transfer::{Direction, TransferError};
use nusb::{Endpoint, Interface, MaybeFuture};

use crate::picoboot::{self, Transport, TransportError, STATUS_LEN};

/// How long one transfer may take (an erase of a sector takes tens of ms).
const TIMEOUT: Duration = Duration::from_secs(5);

/// A boot ROM's PICOBOOT interface on USB.
pub struct UsbTransport {
    interface: Interface,
    out: Endpoint<Bulk, Out>,
    input: Endpoint<Bulk, In>,
}

/// The boot ROM on the bus, opened: None when no RP2040 waits in BOOTSEL; an error
/// (naming the udev rule) when one does but cannot be opened.
pub fn open_boot_rom() -> Result<Option<(UsbTransport, String)>, String> {
    let devices = nusb::list_devices()
        .wait()
        .map_err(|e| format!("listing USB devices: {e}"))?;
    let Some(info) = devices
        .into_iter()
        .find(|d| (d.vendor_id(), d.product_id()) == picoboot::USB_ID)
    else {
        return Ok(None);
    };
    let name = format!("USB bus {} device {}", info.busnum(), info.device_address());
    let Some(number) = info
        .interfaces()
        .find(|i| i.class() == 0xff)
        .map(|i| i.interface_number())
    else {
        return Err(format!("{name}: the boot ROM shows no PICOBOOT interface"));
    };
    let unreachable = |e: nusb::Error| {
        format!("{name}: {e}; install the udev rule (sudo cp udev/99-fpm.rules /etc/udev/rules.d/ && sudo udevadm control --reload), then run this again")
    };
    let device = info.open().wait().map_err(unreachable)?;
    let interface = device.claim_interface(number).wait().map_err(unreachable)?;
    let (mut out_address, mut in_address) = (None, None);
    if let Some(d) = interface.descriptor() {
        for e in d.endpoints() {
            if e.transfer_type() != TransferType::Bulk {
                continue;
            }
            match e.direction() {
                Direction::Out => out_address = out_address.or(Some(e.address())),
                Direction::In => in_address = in_address.or(Some(e.address())),
            }
        }
    }
    let (Some(out_address), Some(in_address)) = (out_address, in_address) else {
        return Err(format!(
            "{name}: the PICOBOOT interface lacks its bulk endpoints"
        ));
    };
    let out = interface
        .endpoint::<Bulk, Out>(out_address)
        .map_err(unreachable)?;
    let input = interface
        .endpoint::<Bulk, In>(in_address)
        .map_err(unreachable)?;
    Ok(Some((
        UsbTransport {
            interface,
            out,
            input,
        },
        name,
    )))
}

fn transfer_error(e: TransferError) -> TransportError {
    match e {
        TransferError::Stall => TransportError::Stall,
        other => TransportError::Gone(other.to_string()),
    }
}

impl Transport for UsbTransport {
    fn bulk_out(&mut self, data: &[u8]) -> Result<(), TransportError> {
        let done = self
            .out
            .transfer_blocking(Buffer::from(data.to_vec()), TIMEOUT);
        done.status.map_err(transfer_error)
    }

    fn bulk_in(&mut self, len: usize) -> Result<Vec<u8>, TransportError> {
        // An IN request is whole packets; a zero-length packet ends it at once.
        let packet = self.input.max_packet_size().max(1);
        let asked = len.max(1).div_ceil(packet) * packet;
        let done = self.input.transfer_blocking(Buffer::new(asked), TIMEOUT);
        let mut got = done.into_result().map_err(transfer_error)?.into_vec();
        if got.len() != len {
            return Err(TransportError::Gone(format!(
                "{} bytes came where {len} were asked",
                got.len()
            )));
        }
        got.truncate(len);
        Ok(got)
    }

    fn command_status(&mut self) -> Result<[u8; STATUS_LEN], TransportError> {
        let got = self
            .interface
            .control_in(
                ControlIn {
                    control_type: ControlType::Vendor,
                    recipient: Recipient::Interface,
                    request: picoboot::REQUEST_GET_COMMAND_STATUS,
                    value: 0,
                    index: u16::from(self.interface.interface_number()),
                    length: STATUS_LEN as u16,
                },
                TIMEOUT,
            )
            .wait()
            .map_err(transfer_error)?;
        got.try_into()
            .map_err(|_| TransportError::Gone("a status of the wrong length".into()))
    }

    fn reset_interface(&mut self) -> Result<(), TransportError> {
        // As picotool does: both endpoints' halts cleared, then the ROM's own reset.
        let _ = self.out.clear_halt().wait();
        let _ = self.input.clear_halt().wait();
        self.interface
            .control_out(
                ControlOut {
                    control_type: ControlType::Vendor,
                    recipient: Recipient::Interface,
                    request: picoboot::REQUEST_INTERFACE_RESET,
                    value: 0,
                    index: u16::from(self.interface.interface_number()),
                    data: &[],
                },
                TIMEOUT,
            )
            .wait()
            .map_err(transfer_error)
    }
}
