//! Conformance against the real firmware: the UF2 image users flash, booted in an
//! emulated RP2040 (`fpm emulator --firmware`, rp2040js under Node), its USB CDC-ACM
//! port behind a pseudo-terminal. The same suite as for the host-compiled emulator.

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod conformance_suite;

/// The WS2812 data at GP16 as the LEDs see it, timed in emulated time with the PIO
/// stepped cycle by cycle at the firmware's own clock divider: every pulse within the
/// WS2812B datasheet (T0H 0.4 µs ± 150 ns, T1H 0.8 µs ± 150 ns, bit period 1.25 µs),
/// the whole 441-LED frame in the time the sequence timing assumes (the board's
/// per-LED shift time), no pause inside a frame long enough to latch part of it, and
/// at least the 280 µs latch before the next frame.
#[test]
fn ws2812_timing_at_the_pin_meets_the_datasheet() {
    use fpm_acquire::controller::Controller;
    use fpm_protocol::{LedIndex, Pattern, Rgb};
    use std::time::Duration;

    let dir = fpm_tests::TempDir::new("ws2812");
    let emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    let dev = Controller::open(&emu.port(), Duration::from_secs(2)).unwrap();
    let limits = dev.info().limits;
    // Frames from start-up are not this test's.
    std::thread::sleep(Duration::from_millis(200));
    let before = emu.log_text().matches("WS2812 frame at GP16: ").count();
    let frames = |log: &str| -> Vec<String> {
        log.lines()
            .filter_map(|l| {
                l.split_once("WS2812 frame at GP16: ")
                    .map(|(_, t)| t.to_owned())
            })
            .collect()
    };
    let wait_for_frames = |n: usize| {
        emu.log_when(|l| frames(l).len() >= before + n, Duration::from_secs(20));
    };
    // The whole chain, then (once it has latched) only the first LED: two frames.
    dev.pattern(Pattern::All, Rgb::new(8, 4, 2)).unwrap();
    wait_for_frames(1);
    dev.set_leds(&[LedIndex::new(0, 0)], Rgb::new(0, 0, 1), true)
        .unwrap();
    wait_for_frames(2);
    let log = emu.log_text();
    let frames = frames(&log)[before..].to_vec();
    assert_eq!(frames.len(), 2, "{log}");
    assert!(!log.contains("malformed pulse"), "{log}");
    let number_after = |text: &str, key: &str| -> Vec<f64> {
        let rest = text
            .split_once(key)
            .unwrap_or_else(|| panic!("no {key} in {text}"))
            .1;
        rest.split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .filter(|s| !s.is_empty())
            .take(2)
            .map(|s| s.parse().unwrap())
            .collect()
    };
    // A shortest–longest range in ns, or None for "none" (no such bit in the frame).
    let range_after = |text: &str, key: &str| -> Option<Vec<f64>> {
        let rest = text
            .split_once(key)
            .unwrap_or_else(|| panic!("no {key} in {text}"))
            .1;
        (!rest.starts_with("none")).then(|| number_after(text, key))
    };
    for frame in &frames {
        let t0h = range_after(frame, "T0H ").expect("every frame has 0 bits here");
        assert!(
            t0h[0] >= 250.0 && t0h[1] <= 550.0,
            "T0H {t0h:?} ns: {frame}"
        );
        if let Some(t1h) = range_after(frame, "T1H ") {
            assert!(
                t1h[0] >= 650.0 && t1h[1] <= 950.0,
                "T1H {t1h:?} ns: {frame}"
            );
        }
        let period = number_after(frame, "bit period ");
        assert!(
            period[0] >= 1_150.0 && period[1] <= 1_350.0,
            "period {period:?}: {frame}"
        );
        let low = number_after(frame, "longest low inside ")[0];
        assert!(low < 5_000.0, "a {low} ns pause inside a frame: {frame}");
        let leds = number_after(frame, "")[0];
        let shift_us = number_after(frame, "LEDs in ")[0];
        let expected = leds * limits.led_shift_ns as f64 / 1e3;
        assert!(
            (shift_us - expected).abs() <= 0.02 * expected + 2.0,
            "{leds} LEDs shifted in {shift_us} µs, the timing model says {expected} µs: {frame}"
        );
    }
    for frame in &frames[1..] {
        let gap = number_after(frame, "latch before it ")[0];
        assert!(gap >= 280.0, "only {gap} µs low before a frame: {frame}");
    }
    assert!(frames[0].starts_with("441 LEDs"), "{}", frames[0]);
    assert!(frames[1].starts_with("1 LEDs"), "{}", frames[1]);
}

/// Request round trips over USB, in emulated time (what a board would show, whatever
/// the emulator's speed): from the packet that ends a request reaching the firmware
/// to its first reply bytes (rp2040js delivers packets at once: no 1 ms USB frames).
#[test]
fn request_round_trips_in_emulated_time() {
    use fpm_acquire::controller::Controller;
    use std::time::Duration;

    let dir = fpm_tests::TempDir::new("round-trip");
    let mut emu = TARGET.start(&dir.0.join("ctl.tty"), &[]);
    {
        let dev = Controller::open(&emu.port(), Duration::from_secs(2)).unwrap();
        for i in 0..50 {
            assert_eq!(dev.ping(i).unwrap(), i);
        }
    }
    emu.stop();
    let log = emu.log_text();
    let line = log
        .lines()
        .find(|l| l.contains("USB request to reply, emulated"))
        .unwrap_or_else(|| panic!("no round-trip summary:\n{log}"));
    let after = |key: &str| -> f64 {
        let rest = line.split_once(key).unwrap().1;
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    assert!(after("emulated: ") >= 50.0, "{line}");
    let p50 = after("p50 ");
    assert!(p50 > 0.0 && p50 < 1_000.0, "{line}");
}
