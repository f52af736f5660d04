//! The current budget: what the lit LEDs draw, and the brightness that keeps it in bounds.

use fpm_protocol::Rgb;

/// Apply a global brightness (0–255) to one channel value, rounding to nearest.
pub const fn dim(value: u8, brightness: u8) -> u8 {
    ((value as u32 * brightness as u32 + 127) / 255) as u8
}

/// Apply a global brightness to a colour.
pub const fn dim_rgb(c: Rgb, brightness: u8) -> Rgb {
    Rgb::new(
        dim(c.r, brightness),
        dim(c.g, brightness),
        dim(c.b, brightness),
    )
}

/// Channel current drawn by `pixels` (already dimmed), µA.
pub fn current_ua<'a>(pixels: impl IntoIterator<Item = &'a Rgb>, channel_current_ua: u32) -> u64 {
    let sum: u64 = pixels
        .into_iter()
        .map(|p| p.r as u64 + p.g as u64 + p.b as u64)
        .sum();
    (sum * channel_current_ua as u64).div_ceil(255)
}

/// Current drawn by `colors` at `brightness`, µA.
pub fn current_at(colors: &[Rgb], brightness: u8, channel_current_ua: u32) -> u64 {
    let sum: u64 = colors
        .iter()
        .map(|c| {
            let d = dim_rgb(*c, brightness);
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

/// The highest brightness ≤ `brightness` at which `colors` draw at most `limit_ua`.
/// Current grows monotonically with brightness, so a binary search finds it.
pub fn fit_brightness(
    colors: &[Rgb],
    brightness: u8,
    channel_current_ua: u32,
    limit_ua: u64,
) -> u8 {
    if current_at(colors, brightness, channel_current_ua) <= limit_ua {
        return brightness;
    }
    let (mut lo, mut hi) = (0u8, brightness); // lo fits, hi does not
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if current_at(colors, mid, channel_current_ua) <= limit_ua {
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

    #[test]
    fn full_white_board_draws_about_26_amps() {
        let colors = [Rgb::WHITE; 441];
        let ma = ua_to_ma(current_at(&colors, 255, 20_000));
        assert_eq!(ma, 441 * 3 * 20);
    }

    #[test]
    fn dimming_rounds_to_nearest_and_keeps_extremes() {
        assert_eq!(dim(255, 255), 255);
        assert_eq!(dim(255, 0), 0);
        assert_eq!(dim(0, 255), 0);
        assert_eq!(dim(255, 128), 128);
        assert_eq!(dim(1, 127), 0);
        assert_eq!(dim(1, 128), 1);
    }

    #[test]
    fn fitted_brightness_is_the_largest_that_fits() {
        let colors = [Rgb::WHITE; 441];
        let limit = 4_000_000; // 4 A
        let b = fit_brightness(&colors, 255, 20_000, limit);
        assert!(current_at(&colors, b, 20_000) <= limit);
        assert!(current_at(&colors, b + 1, 20_000) > limit);
        // nothing to do when it already fits
        assert_eq!(fit_brightness(&colors[..10], 200, 20_000, limit), 200);
        // a limit below one LED step gives zero
        assert_eq!(fit_brightness(&colors, 255, 20_000, 0), 0);
    }
}
