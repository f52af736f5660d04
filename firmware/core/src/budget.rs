//! The current budget: what the lit LEDs draw, and the brightness that keeps it in bounds.

use fpm_protocol::Rgb;
use smart_leds::RGB8;

/// How requested colours become what the LEDs show: smart-leds' gamma table (colours
/// as the eye sees them; off by default, because then a value is proportional to the
/// light, which quantitative imaging wants), then smart-leds' brightness scaling, in
/// the order smart-leds prescribes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Output {
    /// Global brightness, 0–255 (255: values unchanged).
    pub brightness: u8,
    /// Gamma-correct before dimming.
    pub gamma: bool,
}

impl Output {
    /// What an LED asked for `c` shows.
    pub fn apply(self, c: Rgb) -> RGB8 {
        let rgb = core::iter::once(RGB8::new(c.r, c.g, c.b));
        let shown = if self.gamma {
            smart_leds::brightness(smart_leds::gamma(rgb), self.brightness).next()
        } else {
            smart_leds::brightness(rgb, self.brightness).next()
        };
        shown.unwrap_or_default()
    }

    /// The same at another brightness.
    pub const fn at(self, brightness: u8) -> Self {
        Self {
            brightness,
            gamma: self.gamma,
        }
    }
}

/// Channel current drawn by `pixels` as shifted out, µA.
pub fn current_ua<'a>(pixels: impl IntoIterator<Item = &'a RGB8>, channel_current_ua: u32) -> u64 {
    let sum: u64 = pixels
        .into_iter()
        .map(|p| p.r as u64 + p.g as u64 + p.b as u64)
        .sum();
    (sum * channel_current_ua as u64).div_ceil(255)
}

/// Current drawn by `colors` shown through `output`, µA: computed on the values that
/// would be shifted out.
pub fn current_at(colors: &[Rgb], output: Output, channel_current_ua: u32) -> u64 {
    let sum: u64 = colors
        .iter()
        .map(|&c| {
            let d = output.apply(c);
            d.r as u64 + d.g as u64 + d.b as u64
        })
        .sum();
    (sum * channel_current_ua as u64).div_ceil(255)
}

/// µA to mA, rounded up (a budget report never understates).
pub const fn ua_to_ma(ua: u64) -> u32 {
    let ma = ua.div_ceil(1000);
    if ma > u32::MAX as u64 {
        u32::MAX
    } else {
        ma as u32
    }
}

/// The highest brightness ≤ `output.brightness` at which `colors` draw at most
/// `limit_ua`. Current grows monotonically with brightness, so a binary search finds it.
pub fn fit_brightness(
    colors: &[Rgb],
    output: Output,
    channel_current_ua: u32,
    limit_ua: u64,
) -> u8 {
    let brightness = output.brightness;
    if current_at(colors, output, channel_current_ua) <= limit_ua {
        return brightness;
    }
    let (mut lo, mut hi) = (0u8, brightness); // lo fits, hi does not
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if current_at(colors, output.at(mid), channel_current_ua) <= limit_ua {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

#[cfg(test)]
mod tests {
    use super::*;

    const LINEAR: Output = Output {
        brightness: 255,
        gamma: false,
    };
    const GAMMA: Output = Output {
        brightness: 255,
        gamma: true,
    };

    #[test]
    fn full_white_board_draws_about_26_amps() {
        let colors = [Rgb::WHITE; 441];
        let ma = ua_to_ma(current_at(&colors, LINEAR, 20_000));
        assert_eq!(ma, 441 * 3 * 20);
        // Full white stays full white through the gamma table.
        assert_eq!(ua_to_ma(current_at(&colors, GAMMA, 20_000)), ma);
    }

    #[test]
    fn brightness_and_gamma_are_smart_leds_own() {
        let grey = Rgb::new(128, 1, 255);
        // Full brightness, no gamma: values unchanged (linear light).
        assert_eq!(LINEAR.apply(grey), RGB8::new(128, 1, 255));
        // smart-leds' brightness: v·(b+1)/256, so 0 turns everything off.
        assert_eq!(LINEAR.at(127).apply(grey), RGB8::new(64, 0, 127));
        assert_eq!(LINEAR.at(0).apply(Rgb::WHITE), RGB8::default());
        // Gamma first (128 → 37, 1 → 0), then brightness.
        assert_eq!(GAMMA.apply(grey), RGB8::new(37, 0, 255));
        assert_eq!(GAMMA.at(127).apply(grey), RGB8::new(18, 0, 127));
    }

    #[test]
    fn the_budget_counts_what_is_shifted_out() {
        // Half grey: linear draws half, gamma-corrected about a seventh.
        let colors = [Rgb::new(128, 128, 128); 100];
        let linear = current_at(&colors, LINEAR, 20_000);
        let gamma = current_at(&colors, GAMMA, 20_000);
        assert_eq!(linear, (100 * 3 * 128 * 20_000u64).div_ceil(255));
        assert_eq!(gamma, (100 * 3 * 37 * 20_000u64).div_ceil(255));
    }

    #[test]
    fn fitted_brightness_is_the_largest_that_fits() {
        let colors = [Rgb::WHITE; 441];
        let limit = 4_000_000; // 4 A
        for output in [LINEAR, GAMMA] {
            let b = fit_brightness(&colors, output, 20_000, limit);
            assert!(current_at(&colors, output.at(b), 20_000) <= limit);
            assert!(current_at(&colors, output.at(b + 1), 20_000) > limit);
            // nothing to do when it already fits
            assert_eq!(
                fit_brightness(&colors[..10], output.at(200), 20_000, limit),
                200
            );
            // a limit below one LED step gives zero
            assert_eq!(fit_brightness(&colors, output, 20_000, 0), 0);
        }
    }
}
