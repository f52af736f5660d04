//! The WS2812 chain: a PIO program per data lane fed by DMA, shifting out only as many
//! LEDs as the controller logic asks for (LEDs past the end keep their colour).
//!
//! The controller logic writes synchronously; the LED task shifts asynchronously. A
//! write that arrives while a shift is in progress is merged into the pending frame
//! (newest colours, longest shift per lane), so no change is ever lost.

use core::cell::RefCell;

use embassy_futures::join::join4;
use embassy_rp::dma::{AnyChannel, Channel};
use embassy_rp::pio::program::{Assembler, JmpCondition, OutDestination, SetDestination, SideSet};
use embassy_rp::pio::{
    Common, Config, FifoJoin, Instance, LoadedProgram, PioPin, ShiftConfig, ShiftDirection,
    StateMachine,
};
use embassy_rp::Peri;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::Timer;
use fixed::types::U24F8;
use fpm_firmware::chain::{grb_word, MAX_LANES};
use fpm_firmware::{LedStrip, SmartLedsWrite, RGB8};
use fpm_protocol::limits::MAX_LEDS;

// Bit timing in PIO cycles: 10 cycles per bit at 8 MHz = 800 kbit/s. A 0 is high for
// T1 (375 ns), a 1 for T1 + T2 (750 ns): inside both the WS2812B's T0H 0.4 µs ± 150 ns,
// T1H 0.8 µs ± 150 ns and the V5 parts' T0H 220–380 ns, T1H 580–1000 ns. The
// datasheet's T1 = 2 gives a T0H of 250 ns, on the edge of the first window (and below
// it by a system cycle when the fractional divider rounds down); measured at GP16 by
// tests/tests/conformance_firmware.rs.
const T1: u8 = 3; // start of bit: high
const T2: u8 = 3; // data: high for a 1, low for a 0
const T3: u8 = 4; // end of bit: low
const CYCLES_PER_BIT: u32 = (T1 + T2 + T3) as u32;

/// Load the WS2812 program (the RP2040 datasheet's, §3.6.2) into a PIO block.
pub fn load_program<'d, P: Instance>(common: &mut Common<'d, P>) -> LoadedProgram<'d, P> {
    let side_set = SideSet::new(false, 1, false);
    let mut a: Assembler<32> = Assembler::new_with_side_set(side_set);
    let mut wrap_target = a.label();
    let mut wrap_source = a.label();
    let mut do_zero = a.label();
    a.set_with_side_set(SetDestination::PINDIRS, 1, 0);
    a.bind(&mut wrap_target);
    a.out_with_delay_and_side_set(OutDestination::X, 1, T3 - 1, 0);
    a.jmp_with_delay_and_side_set(JmpCondition::XIsZero, &mut do_zero, T1 - 1, 1);
    a.jmp_with_delay_and_side_set(JmpCondition::Always, &mut wrap_target, T2 - 1, 1);
    a.bind(&mut do_zero);
    a.nop_with_delay_and_side_set(T2 - 1, 0);
    a.bind(&mut wrap_source);
    let program = a.assemble_with_wrap(wrap_source, wrap_target);
    common.load_program(&program)
}

/// One data line: a PIO state machine and the DMA channel that feeds it.
pub struct Lane<'d, P: Instance, const S: usize> {
    sm: StateMachine<'d, P, S>,
    dma: Peri<'d, AnyChannel>,
}

impl<'d, P: Instance, const S: usize> Lane<'d, P, S> {
    /// Configure state machine `S` to drive `pin` with the loaded program.
    pub fn new(
        common: &mut Common<'d, P>,
        mut sm: StateMachine<'d, P, S>,
        dma: Peri<'d, impl Channel>,
        pin: Peri<'d, impl PioPin>,
        program: &LoadedProgram<'d, P>,
    ) -> Self {
        let mut cfg = Config::default();
        let out_pin = common.make_pio_pin(pin);
        cfg.set_out_pins(&[&out_pin]);
        cfg.set_set_pins(&[&out_pin]);
        cfg.use_program(program, &[&out_pin]);
        let clock_khz = U24F8::from_num(embassy_rp::clocks::clk_sys_freq() / 1000);
        cfg.clock_divider = clock_khz / (U24F8::from_num(800) * CYCLES_PER_BIT);
        cfg.fifo_join = FifoJoin::TxOnly;
        cfg.shift_out = ShiftConfig {
            auto_fill: true,
            threshold: 24,
            direction: ShiftDirection::Left,
        };
        sm.set_config(&cfg);
        // As the pico-sdk's pio_sm_init: empty FIFOs and an empty output shift register,
        // so the first `out` waits for data instead of shifting out whatever the register
        // held (24 zero bits at power-up: a stray frame on every lane at start-up).
        sm.clear_fifos();
        sm.restart();
        sm.set_enable(true);
        Self {
            sm,
            dma: dma.into(),
        }
    }

    /// Shift `words` out and return once the last bit has left the pin.
    pub async fn shift(&mut self, words: &[u32]) {
        if words.is_empty() {
            return;
        }
        self.sm
            .tx()
            .dma_push(self.dma.reborrow(), words, false)
            .await;
        // The DMA is done when the last word is in the FIFO, not on the wire.
        while !self.sm.tx().empty() {
            Timer::after_micros(5).await;
        }
        Timer::after_micros(30).await; // the last LED's 24 bits
    }
}

/// Up to four lanes on one PIO block; lanes the board does not wire are `None`.
pub struct Chain<'d, P: Instance> {
    pub lane0: Lane<'d, P, 0>,
    pub lane1: Option<Lane<'d, P, 1>>,
    pub lane2: Option<Lane<'d, P, 2>>,
    pub lane3: Option<Lane<'d, P, 3>>,
}

async fn shift_lane<P: Instance, const S: usize>(lane: &mut Option<Lane<'_, P, S>>, words: &[u32]) {
    if let Some(lane) = lane {
        lane.shift(words).await;
    }
}

impl<P: Instance> Chain<'_, P> {
    /// Shift every lane's prefix in parallel.
    pub async fn shift(&mut self, words: &[u32], lane_len: usize, shift: &[u16; MAX_LANES]) {
        let part = |k: usize| {
            let start = (k * lane_len).min(words.len());
            let end = (start + shift[k] as usize).min(words.len());
            &words[start..end]
        };
        join4(
            self.lane0.shift(part(0)),
            shift_lane(&mut self.lane1, part(1)),
            shift_lane(&mut self.lane2, part(2)),
            shift_lane(&mut self.lane3, part(3)),
        )
        .await;
    }
}

struct Frame {
    words: [u32; MAX_LEDS],
    shift: [u16; MAX_LANES],
    lane_len: usize,
}

/// The frame waiting to be shifted out.
pub struct PendingFrame {
    frame: Mutex<CriticalSectionRawMutex, RefCell<Frame>>,
    ready: Signal<CriticalSectionRawMutex, ()>,
    /// When the last shift had latched (device µs), for the main loop to report.
    pub latched: Signal<CriticalSectionRawMutex, u64>,
}

impl PendingFrame {
    /// Nothing pending.
    pub const fn new() -> Self {
        Self {
            frame: Mutex::new(RefCell::new(Frame {
                words: [0; MAX_LEDS],
                shift: [0; MAX_LANES],
                lane_len: 0,
            })),
            ready: Signal::new(),
            latched: Signal::new(),
        }
    }
}

/// The controller logic's view of the chain.
pub struct RpStrip {
    pending: &'static PendingFrame,
    max_current_ua: u64,
    channel_current_ua: u32,
    led_count: usize,
    lanes: usize,
}

impl RpStrip {
    /// A strip of `board`'s LEDs that never drives more than its current rating.
    pub fn new(pending: &'static PendingFrame, board: &fpm_firmware::BoardConfig) -> Self {
        Self {
            pending,
            max_current_ua: board.max_current_ma as u64 * 1000,
            channel_current_ua: board.channel_current_ua,
            led_count: board.geometry.led_count() as usize,
            lanes: board.geometry.lanes as usize,
        }
    }
}

/// A whole-chain write, for code that drives the chain as any smart-leds strip.
impl SmartLedsWrite for RpStrip {
    type Error = core::convert::Infallible;
    type Color = RGB8;

    fn write<T, I>(&mut self, colors: T) -> Result<(), Self::Error>
    where
        T: IntoIterator<Item = I>,
        I: Into<RGB8>,
    {
        let (count, lanes) = (self.led_count, self.lanes);
        fpm_firmware::hw::write_whole_chain(self, colors, count, lanes);
        Ok(())
    }
}

impl LedStrip for RpStrip {
    fn write(&mut self, pixels: &[RGB8], lane_len: usize, shift: &[u16]) {
        // Last line of defence, independent of the logic that already keeps the budget:
        // a frame that would overload the supply is never shifted out.
        let need = fpm_firmware::budget::current_ua(pixels, self.channel_current_ua);
        if need > self.max_current_ua {
            defmt::error!("refusing a frame that draws {} mA", need / 1000);
            return;
        }
        self.pending.frame.lock(|f| {
            let mut f = f.borrow_mut();
            for (w, p) in f.words.iter_mut().zip(pixels) {
                *w = grb_word(*p);
            }
            f.lane_len = lane_len;
            for (pending, &s) in f.shift.iter_mut().zip(shift) {
                *pending = (*pending).max(s);
            }
        });
        self.pending.ready.signal(());
    }

    /// The DMA task shifts when the main loop next yields, which can be milliseconds
    /// later (USB writes): the logic waits for the task's report instead of the model.
    fn latches_later(&self) -> bool {
        true
    }
}

/// Shift pending frames out as they come.
#[embassy_executor::task]
pub async fn led_task(
    mut chain: Chain<'static, embassy_rp::peripherals::PIO0>,
    pending: &'static PendingFrame,
    latch_us: u32,
) -> ! {
    let mut words = [0u32; MAX_LEDS];
    loop {
        pending.ready.wait().await;
        let (lane_len, shift) = pending.frame.lock(|f| {
            let mut f = f.borrow_mut();
            words.copy_from_slice(&f.words);
            let shift = f.shift;
            f.shift = [0; MAX_LANES];
            (f.lane_len, shift)
        });
        chain.shift(&words, lane_len, &shift).await;
        Timer::after_micros(latch_us as u64).await;
        pending
            .latched
            .signal(embassy_time::Instant::now().as_micros());
    }
}
