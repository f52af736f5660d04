//! USB CDC-ACM: the controller enumerates as a serial port carrying the COBS frames.

use embassy_rp::peripherals::USB;
use embassy_rp::usb::Driver;
use embassy_time::{with_timeout, Duration};
use embassy_usb::class::cdc_acm::{CdcAcmClass, Sender, State};
use embassy_usb::{Builder, UsbDevice};
use fpm_firmware::FrameSink;
use static_cell::StaticCell;

use crate::board::{USB_PID, USB_VID};

/// Full-speed bulk packet size.
pub const PACKET: usize = 64;

/// The USB device and its serial class.
pub fn build(
    driver: Driver<'static, USB>,
    serial: &'static str,
) -> (
    UsbDevice<'static, Driver<'static, USB>>,
    CdcAcmClass<'static, Driver<'static, USB>>,
) {
    let mut config = embassy_usb::Config::new(USB_VID, USB_PID);
    config.manufacturer = Some("fpm");
    config.product = Some("fpm LED controller");
    config.serial_number = Some(serial);
    config.max_power = 100;
    config.max_packet_size_0 = PACKET as u8;

    static CONFIG_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS_DESC: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
    static STATE: StaticCell<State> = StaticCell::new();
    let mut builder = Builder::new(
        driver,
        config,
        CONFIG_DESC.init([0; 256]),
        BOS_DESC.init([0; 256]),
        &mut [],
        CONTROL_BUF.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, STATE.init(State::new()), PACKET as u16);
    (builder.build(), class)
}

/// Run the USB device.
#[embassy_executor::task]
pub async fn usb_task(mut usb: UsbDevice<'static, Driver<'static, USB>>) -> ! {
    usb.run().await
}

/// Frames the controller logic produced, waiting to be sent.
pub struct Outbox {
    bytes: heapless::Vec<u8, 4096>,
    dropped: u32,
}

impl Outbox {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            bytes: heapless::Vec::new(),
            dropped: 0,
        }
    }

    /// Send everything queued. A host that stops reading must not stall the board:
    /// after 20 ms without progress the rest is dropped.
    pub async fn flush(&mut self, tx: &mut Sender<'static, Driver<'static, USB>>) {
        if self.bytes.is_empty() {
            return;
        }
        let mut ok = true;
        for packet in self.bytes.chunks(PACKET) {
            if !matches!(
                with_timeout(Duration::from_millis(20), tx.write_packet(packet)).await,
                Ok(Ok(()))
            ) {
                ok = false;
                break;
            }
        }
        // A transfer that ends on a full packet needs a zero-length packet to end it.
        if ok && self.bytes.len().is_multiple_of(PACKET) {
            let _ = with_timeout(Duration::from_millis(20), tx.write_packet(&[])).await;
        }
        if !ok {
            self.dropped = self.dropped.wrapping_add(1);
            defmt::warn!("host not reading: dropped {} bytes", self.bytes.len());
        }
        self.bytes.clear();
    }
}

impl FrameSink for Outbox {
    fn send(&mut self, encoded: &[u8]) {
        if self.bytes.extend_from_slice(encoded).is_err() {
            self.dropped = self.dropped.wrapping_add(1);
        }
    }
}
