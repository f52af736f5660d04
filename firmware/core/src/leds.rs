//! The LED frame buffer: what was asked for, what is in the LEDs, and the one path by
//! which a new state reaches the strip (budget check, dimming, partial shift).

use fpm_protocol::{limits::MAX_LEDS, BudgetConfig, BudgetPolicy, DeviceError, Lit, Rgb};

use smart_leds::RGB8;

use crate::board::BoardConfig;
use crate::budget::{current_at, current_ua, fit_brightness, ua_to_ma, Output};
use crate::chain::{lane_len, update_time_us, MAX_LANES};
use crate::hw::LedStrip;

/// Colours by chain position. `requested` is what the host asked for (before
/// gamma and brightness), `shown` what the LEDs hold now (as shifted out), `staged`
/// the state being prepared by a request.
pub struct LedState {
    requested: [Rgb; MAX_LEDS],
    shown: [RGB8; MAX_LEDS],
    staged: [Rgb; MAX_LEDS],
    len: usize,
    output: Output,
    effective: u8,
}

impl LedState {
    /// All LEDs off (the strip is assumed dark at power-up).
    pub const fn new(led_count: usize, brightness: u8) -> Self {
        let len = if led_count < MAX_LEDS {
            led_count
        } else {
            MAX_LEDS
        };
        Self {
            requested: [Rgb::OFF; MAX_LEDS],
            shown: [RGB8::new(0, 0, 0); MAX_LEDS],
            staged: [Rgb::OFF; MAX_LEDS],
            len,
            output: Output {
                brightness,
                gamma: false,
            },
            effective: brightness,
        }
    }

    /// Start preparing a new state: a copy of the current one (`keep`) or all off.
    pub fn stage(&mut self, keep: bool) -> &mut [Rgb] {
        let n = self.len;
        if keep {
            self.staged[..n].copy_from_slice(&self.requested[..n]);
        } else {
            self.staged[..n].fill(Rgb::OFF);
        }
        &mut self.staged[..n]
    }

    /// The staged buffer, for a caller that fills it through [`Self::stage`] first.
    pub fn staged(&self) -> &[Rgb] {
        &self.staged[..self.len]
    }

    /// Current the staged state would draw through `output`, µA.
    pub fn staged_current_ua(&self, output: Output, channel_current_ua: u32) -> u64 {
        current_at(&self.staged[..self.len], output, channel_current_ua)
    }

    /// Make the staged state real through `output`, within `budget`, and shift it out
    /// on `board`'s chain. On refusal nothing changes.
    pub fn commit(
        &mut self,
        board: &BoardConfig,
        output: Output,
        budget: BudgetConfig,
        strip: &mut impl LedStrip,
        now_us: u64,
    ) -> Result<Lit, DeviceError> {
        let (geometry, channel_current_ua) = (&board.geometry, board.channel_current_ua);
        let n = self.len;
        let limit_ua = budget.limit_ma as u64 * 1000;
        let brightness = output.brightness;
        let need_ua = current_at(&self.staged[..n], output, channel_current_ua);
        let effective = if need_ua <= limit_ua {
            brightness
        } else {
            match budget.policy {
                BudgetPolicy::Refuse => {
                    return Err(DeviceError::OverBudget {
                        required_ma: ua_to_ma(need_ua),
                        limit_ma: budget.limit_ma,
                        step: None,
                    })
                }
                BudgetPolicy::Scale => {
                    fit_brightness(&self.staged[..n], output, channel_current_ua, limit_ua)
                }
            }
        };

        // Into `shown` as it will be shifted out, noting per lane the last LED that
        // changed.
        let per_lane = lane_len(geometry).max(1);
        let mut shift = [0u16; MAX_LANES];
        let shifted_out = output.at(effective);
        for i in 0..n {
            let px = shifted_out.apply(self.staged[i]);
            if px != self.shown[i] {
                self.shown[i] = px;
                if let Some(s) = shift.get_mut(i / per_lane) {
                    *s = (i % per_lane + 1) as u16;
                }
            }
        }
        self.requested[..n].copy_from_slice(&self.staged[..n]);
        self.output = output;
        self.effective = effective;
        let lanes = (geometry.lanes as usize).clamp(1, MAX_LANES);
        if shift.iter().any(|&s| s > 0) {
            strip.write(&self.shown[..n], per_lane, &shift[..lanes]);
        }
        let (led_shift_ns, latch_us) = (board.led_shift_ns, board.latch_us);
        Ok(Lit {
            leds_on: self.leds_on(),
            current_ma: ua_to_ma(current_ua(&self.shown[..n], channel_current_ua)),
            brightness: effective,
            scaled: effective < brightness,
            latched_us: now_us + update_time_us(&shift, led_shift_ns, latch_us),
        })
    }

    /// LEDs lit now.
    pub fn leds_on(&self) -> u16 {
        self.shown[..self.len]
            .iter()
            .filter(|&&p| p != RGB8::default())
            .count() as u16
    }

    /// Channel current drawn now, mA.
    pub fn current_ma(&self, channel_current_ua: u32) -> u32 {
        ua_to_ma(current_ua(&self.shown[..self.len], channel_current_ua))
    }

    /// Brightness asked for.
    pub fn brightness(&self) -> u8 {
        self.output.brightness
    }

    /// Brightness and gamma asked for.
    pub fn output(&self) -> Output {
        self.output
    }

    /// What the LEDs hold now, in chain order, as shifted out.
    pub fn shown(&self) -> &[RGB8] {
        &self.shown[..self.len]
    }
}
