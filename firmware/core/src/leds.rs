//! The LED frame buffer: what was asked for, what is in the LEDs, and the one path by
//! which a new state reaches the strip (budget check, dimming, partial shift).

use fpm_protocol::{
    limits::MAX_LEDS, BoardGeometry, BudgetConfig, BudgetPolicy, DeviceError, Lit, Rgb,
};

use crate::budget::{current_at, current_ua, dim_rgb, fit_brightness, ua_to_ma};
use crate::chain::{lane_len, update_time_us, MAX_LANES};
use crate::hw::LedStrip;

/// Colours by chain position. `requested` is what the host asked for (before
/// brightness), `shown` what the LEDs hold now (after brightness), `staged` the state
/// being prepared by a request.
pub struct LedState {
    requested: [Rgb; MAX_LEDS],
    shown: [Rgb; MAX_LEDS],
    staged: [Rgb; MAX_LEDS],
    len: usize,
    brightness: u8,
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
            shown: [Rgb::OFF; MAX_LEDS],
            staged: [Rgb::OFF; MAX_LEDS],
            len,
            brightness,
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

    /// Current the staged state would draw at `brightness`, µA.
    pub fn staged_current_ua(&self, brightness: u8, channel_current_ua: u32) -> u64 {
        current_at(&self.staged[..self.len], brightness, channel_current_ua)
    }

    /// Make the staged state real at `brightness`, within `budget`, and shift it out.
    /// On refusal nothing changes.
    #[allow(clippy::too_many_arguments)]
    pub fn commit(
        &mut self,
        geometry: &BoardGeometry,
        brightness: u8,
        budget: BudgetConfig,
        channel_current_ua: u32,
        timing: (u32, u32),
        strip: &mut impl LedStrip,
        now_us: u64,
    ) -> Result<Lit, DeviceError> {
        let n = self.len;
        let limit_ua = budget.limit_ma as u64 * 1000;
        let need_ua = current_at(&self.staged[..n], brightness, channel_current_ua);
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
                    fit_brightness(&self.staged[..n], brightness, channel_current_ua, limit_ua)
                }
            }
        };

        // Dim into `shown`, noting per lane the last LED that changed.
        let per_lane = lane_len(geometry).max(1);
        let mut shift = [0u16; MAX_LANES];
        for i in 0..n {
            let px = dim_rgb(self.staged[i], effective);
            if px != self.shown[i] {
                self.shown[i] = px;
                if let Some(s) = shift.get_mut(i / per_lane) {
                    *s = (i % per_lane + 1) as u16;
                }
            }
        }
        self.requested[..n].copy_from_slice(&self.staged[..n]);
        self.brightness = brightness;
        self.effective = effective;
        let lanes = (geometry.lanes as usize).clamp(1, MAX_LANES);
        if shift.iter().any(|&s| s > 0) {
            strip.write(&self.shown[..n], per_lane, &shift[..lanes]);
        }
        let (led_shift_ns, latch_us) = timing;
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
            .filter(|p| !p.is_off())
            .count() as u16
    }

    /// Channel current drawn now, mA.
    pub fn current_ma(&self, channel_current_ua: u32) -> u32 {
        ua_to_ma(current_ua(&self.shown[..self.len], channel_current_ua))
    }

    /// Brightness asked for.
    pub fn brightness(&self) -> u8 {
        self.brightness
    }

    /// What the LEDs hold now, in chain order.
    pub fn shown(&self) -> &[Rgb] {
        &self.shown[..self.len]
    }
}
