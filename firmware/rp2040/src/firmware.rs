//! Start-up and the main loop: bytes from USB, edges from the camera, the LED task's
//! latch reports and the controller's own deadlines, handled in arrival order.

use embassy_executor::Spawner;
use embassy_futures::select::{select4, Either4};
use embassy_rp::flash::{Blocking, Flash};
use embassy_rp::gpio::{Input, Level, Output, Pull};
use embassy_rp::peripherals::{PIO0, USB};
use embassy_rp::pio::Pio;
use embassy_rp::{bind_interrupts, pio, usb};
use embassy_time::{Instant, Timer};
use fpm_firmware::{BoardConfig, CalibrationStore, Device};
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

use crate::link::{self, Outbox};
use crate::triggers::{self, Edges, TriggerPin};
use crate::ws2812::{self, Chain, Lane, PendingFrame, RpStrip};

bind_interrupts!(struct Irqs {
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
});

const FLASH_SIZE: usize = 2 * 1024 * 1024;
/// The calibration store: the last two sectors, left out of program space in memory.x.
const CALIBRATION_BASE: u32 = (FLASH_SIZE - 2 * embassy_rp::flash::ERASE_SIZE) as u32;

static PENDING: PendingFrame = PendingFrame::new();
static EDGES: Edges = Edges::new();

fn now_us() -> u64 {
    Instant::now().as_micros()
}

/// Run the controller for `board` (each image's `main` calls this with its wiring).
pub async fn run(spawner: Spawner, board: BoardConfig) -> ! {
    let p = embassy_rp::init(Default::default());
    let lanes = board.geometry.lanes;
    let led_count = board.geometry.led_count();

    let mut flash = Flash::<_, Blocking, FLASH_SIZE>::new_blocking(p.FLASH);
    let serial = serial_number(&mut flash);
    static SERIAL_TEXT: StaticCell<heapless::String<16>> = StaticCell::new();
    let serial_text = SERIAL_TEXT.init(hex16(serial));

    // LED chain: one PIO state machine and DMA channel per lane.
    let Pio {
        mut common,
        sm0,
        sm1,
        sm2,
        sm3,
        ..
    } = Pio::new(p.PIO0, Irqs);
    let program = ws2812::load_program(&mut common);
    let chain = Chain {
        lane0: Lane::new(&mut common, sm0, p.DMA_CH0, p.PIN_16, &program),
        lane1: (lanes > 1).then(|| Lane::new(&mut common, sm1, p.DMA_CH1, p.PIN_17, &program)),
        lane2: (lanes > 2).then(|| Lane::new(&mut common, sm2, p.DMA_CH2, p.PIN_18, &program)),
        lane3: (lanes > 3).then(|| Lane::new(&mut common, sm3, p.DMA_CH3, p.PIN_19, &program)),
    };
    spawner.must_spawn(ws2812::led_task(chain, &PENDING, board.latch_us));

    // Camera trigger lines.
    let trigger_out = TriggerPin(Output::new(p.PIN_14, Level::Low));
    spawner.must_spawn(triggers::trigger_in_task(
        Input::new(p.PIN_15, Pull::Up),
        &EDGES,
    ));

    // USB serial.
    let (usb, class) = link::build(usb::Driver::new(p.USB, Irqs), serial_text.as_str());
    spawner.must_spawn(link::usb_task(usb));
    let (mut tx, mut rx) = class.split();
    let mut status_led = Output::new(p.PIN_25, Level::Low);

    let strip = RpStrip::new(&PENDING, &board);
    let store = CalibrationStore::new(flash, CALIBRATION_BASE);
    let mut device = match Device::new(board, serial, strip, trigger_out, store) {
        Ok(d) => d,
        Err(e) => {
            // A bad board.rs: say so forever rather than run with wrong limits.
            loop {
                defmt::error!("invalid board configuration: {}", e);
                Timer::after_secs(1).await;
            }
        }
    };
    defmt::info!(
        "fpm LED controller ready: serial {=u64:x}, {} LEDs, {} lane(s)",
        serial,
        led_count,
        lanes
    );

    let mut outbox = Outbox::new();
    let mut packet = [0u8; link::PACKET];
    let mut next: Option<u64> = None;
    loop {
        let deadline = async {
            match next {
                Some(t) => Timer::at(Instant::from_micros(t)).await,
                None => core::future::pending().await,
            }
        };
        let read = async {
            rx.wait_connection().await;
            rx.read_packet(&mut packet).await
        };
        match select4(read, EDGES.receive(), PENDING.latched.wait(), deadline).await {
            Either4::First(Ok(n)) => {
                status_led.set_high();
                next = device.receive(&packet[..n], now_us(), &mut outbox);
            }
            Either4::First(Err(_)) => {
                // The host went away; sequences keep running on the device clock.
                status_led.set_low();
                next = device.poll(now_us(), &mut outbox);
            }
            Either4::Second((edge, at)) => {
                next = device.trigger_edge(edge, at, now_us(), &mut outbox)
            }
            Either4::Third(at) => next = device.strip_latched(at, now_us(), &mut outbox),
            Either4::Fourth(()) => next = device.poll(now_us(), &mut outbox),
        }
        outbox.flush(&mut tx).await;
        if device.bootsel_requested() {
            restart_in_bootsel().await;
        }
    }
}

/// The flash chip's unique id: the board's serial number (0 if it cannot be read).
fn serial_number(
    flash: &mut Flash<'_, embassy_rp::peripherals::FLASH, Blocking, FLASH_SIZE>,
) -> u64 {
    let mut uid = [0u8; 8];
    if flash.blocking_unique_id(&mut uid).is_err() {
        defmt::warn!("could not read the flash unique id; serial number 0");
    }
    u64::from_be_bytes(uid)
}

/// The reply is out and every LED written off: give the chain time to latch that,
/// then hand over to the boot ROM's USB mode, mass storage and PICOBOOT both on, as a
/// cold boot with BOOTSEL held.
async fn restart_in_bootsel() {
    defmt::info!("restarting in BOOTSEL, as asked");
    Timer::after_millis(50).await;
    embassy_rp::rom_data::reset_to_usb_boot(0, 0);
}

fn hex16(x: u64) -> heapless::String<16> {
    let mut s = heapless::String::new();
    for i in (0..16).rev() {
        let d = ((x >> (i * 4)) & 0xF) as u8;
        let c = if d < 10 { b'0' + d } else { b'a' + d - 10 };
        let _ = s.push(c as char);
    }
    s
}
