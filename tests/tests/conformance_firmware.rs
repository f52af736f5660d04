//! Conformance against the real firmware: the UF2 image users flash, booted in an
//! emulated RP2040 (`fpm emulator --firmware`, rp2040js under Node), its USB CDC-ACM
//! port behind a pseudo-terminal. The same suite as for the host-compiled emulator.

use fpm_tests::Target;

/// The controller the suite runs against.
pub const TARGET: Target = Target::Firmware;

mod conformance_suite;

/// The frames decoded at `pin` that the emulator logged, as "N LEDs in X µs; T0H …".
fn frames_at(log: &str, pin: u8) -> Vec<String> {
    let key = format!("WS2812 frame at GP{pin}: ");
    log.lines()
        .filter_map(|l| l.split_once(key.as_str()).map(|(_, t)| t.to_owned()))
        .collect()
}

/// The first one or two numbers after `key` in `text`.
fn numbers_after(text: &str, key: &str) -> Vec<f64> {
    let rest = text
        .split_once(key)
        .unwrap_or_else(|| panic!("no {key} in {text}"))
        .1;
    rest.split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .filter(|s| !s.is_empty())
        .take(2)
        .map(|s| s.parse().unwrap())
        .collect()
}

/// A shortest–longest range in ns, or None for "none" (no such bit in the frame).
fn range_after(text: &str, key: &str) -> Option<Vec<f64>> {
    let rest = text
        .split_once(key)
        .unwrap_or_else(|| panic!("no {key} in {text}"))
        .1;
    (!rest.starts_with("none")).then(|| numbers_after(text, key))
}

/// LEDs in a logged frame.
fn leds_in(frame: &str) -> usize {
    numbers_after(frame, "")[0] as usize
}

/// One frame as seen at its pin, against the WS2812B datasheet (T0H 0.4 µs ± 150 ns,
/// T1H 0.8 µs ± 150 ns, bit period 1.25 µs), in the time the sequence timing assumes
/// (`led_shift_ns` per LED), with no pause inside it long enough to latch part of it.
fn assert_frame_timing(frame: &str, led_shift_ns: u32) {
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
    let period = numbers_after(frame, "bit period ");
    assert!(
        period[0] >= 1_150.0 && period[1] <= 1_350.0,
        "period {period:?}: {frame}"
    );
    let low = numbers_after(frame, "longest low inside ")[0];
    assert!(low < 5_000.0, "a {low} ns pause inside a frame: {frame}");
    let shift_us = numbers_after(frame, "LEDs in ")[0];
    let expected = leds_in(frame) as f64 * led_shift_ns as f64 / 1e3;
    assert!(
        (shift_us - expected).abs() <= 0.02 * expected + 2.0,
        "{} LEDs shifted in {shift_us} µs, the timing model says {expected} µs: {frame}",
        leds_in(frame)
    );
}

/// The WS2812 data at GP16 as the LEDs see it, timed in emulated time with the PIO
/// stepped cycle by cycle at the firmware's own clock divider: every pulse within the
/// datasheet, the whole 441-LED frame in the time the sequence timing assumes (the
/// board's per-LED shift time), and at least the 280 µs latch before the next frame.
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
    let before = frames_at(&emu.log_text(), 16).len();
    let wait_for_frames = |n: usize| {
        emu.log_when(
            |l| frames_at(l, 16).len() >= before + n,
            Duration::from_secs(20),
        );
    };
    // The whole chain, then (once it has latched) only the first LED: two frames.
    dev.pattern(Pattern::All, Rgb::new(8, 4, 2)).unwrap();
    wait_for_frames(1);
    dev.set_leds(&[LedIndex::new(0, 0)], Rgb::new(0, 0, 1), true)
        .unwrap();
    wait_for_frames(2);
    let log = emu.log_text();
    let frames = frames_at(&log, 16)[before..].to_vec();
    assert_eq!(frames.len(), 2, "{log}");
    assert!(!log.contains("malformed pulse"), "{log}");
    for frame in &frames {
        assert_frame_timing(frame, limits.led_shift_ns);
    }
    for frame in &frames[1..] {
        let gap = numbers_after(frame, "latch before it ")[0];
        assert!(gap >= 280.0, "only {gap} µs low before a frame: {frame}");
    }
    assert_eq!(leds_in(&frames[0]), 441, "{}", frames[0]);
    assert_eq!(leds_in(&frames[1]), 1, "{}", frames[1]);
    // Nothing on the pins of lanes this board does not wire.
    for pin in 17..=19 {
        assert!(frames_at(&log, pin).is_empty(), "{log}");
    }
}

/// The images for chains cut into 2 and 4 lanes, checked at GP16–GP19: the board
/// reports its wiring; a whole-array frame goes out on every lane at once, each lane
/// its own run of LEDs within the datasheet, the frame in the time the sequence timing
/// assumes for the longest lane; LEDs lit from dark in several lanes shift each lane
/// only up to its last changed LED, and the chain then shows exactly those LEDs in
/// exactly those colours.
#[test]
fn multi_lane_images_shift_each_lane_at_its_pin() {
    use fpm_acquire::controller::Controller;
    use fpm_protocol::{LedIndex, Pattern, Rgb};
    use std::time::Duration;

    for lanes in [2u8, 4] {
        let dir = fpm_tests::TempDir::new(&format!("lanes-{lanes}"));
        let uf2 = fpm_tests::firmware_uf2_with_lanes(lanes).to_string_lossy();
        let emu = fpm_tests::Emulator::start_at(&dir.0.join("ctl.tty"), &["--firmware", &uf2]);
        let dev = Controller::open(&emu.port(), Duration::from_secs(2)).unwrap();
        let info = dev.info();
        let g = info.geometry;
        assert_eq!(g.lanes, lanes, "the board reports its wiring");
        let count = g.rows as usize * g.cols as usize;
        let lane_len = count.div_ceil(lanes as usize);
        let pins: Vec<u8> = (16..16 + lanes).collect();
        // Do something, then wait until the chain has latched once more; the log and
        // the chain's last "shifted" line.
        let shifted = |action: &dyn Fn()| -> (String, String) {
            let before = emu.log_text().matches("chain shifted").count();
            action();
            let log = emu.log_when(
                |l| l.matches("chain shifted").count() > before,
                Duration::from_secs(20),
            );
            let last = log
                .lines()
                .rfind(|l| l.contains("chain shifted"))
                .unwrap_or_else(|| panic!("the chain never latched:\n{log}"))
                .to_owned();
            (log, last)
        };
        std::thread::sleep(Duration::from_millis(200));
        let start = emu.log_text();
        let before: Vec<usize> = pins.iter().map(|&p| frames_at(&start, p).len()).collect();

        // The whole array: every lane shifts its full run, in parallel.
        let (log, _) = shifted(&|| {
            dev.pattern(Pattern::All, Rgb::new(8, 4, 2)).unwrap();
        });
        assert!(!log.contains("malformed pulse"), "{log}");
        let mut longest_us: f64 = 0.0;
        for (k, &pin) in pins.iter().enumerate() {
            let frames = frames_at(&log, pin)[before[k]..].to_vec();
            assert_eq!(frames.len(), 1, "lane {k} at GP{pin}:\n{log}");
            let run = lane_len.min(count - k * lane_len);
            assert_eq!(leds_in(&frames[0]), run, "lane {k}: {}", frames[0]);
            assert_frame_timing(&frames[0], info.limits.led_shift_ns);
            longest_us = longest_us.max(numbers_after(&frames[0], "LEDs in ")[0]);
        }
        let model_us = lane_len as f64 * info.limits.led_shift_ns as f64 / 1e3;
        assert!(
            (longest_us - model_us).abs() <= 0.02 * model_us + 2.0,
            "{lanes} lanes shifted the array in {longest_us} µs, the timing model says {model_us} µs"
        );
        assert!(
            log.contains(&format!("LEDs lit: {count} of {count}")),
            "{log}"
        );
        shifted(&|| {
            dev.clear().unwrap();
        });

        // From dark, one LED in every lane (late in each but the last, early in that
        // one), in one colour: each lane shifts up to its LED.
        let offsets: Vec<usize> = (0..lanes as usize)
            .map(|k| {
                if k + 1 == lanes as usize {
                    3
                } else {
                    lane_len - 2 - k
                }
            })
            .collect();
        let leds: Vec<LedIndex> = offsets
            .iter()
            .enumerate()
            .map(|(k, &offset)| {
                fpm_firmware::chain::led_at(&g, (k * lane_len + offset) as u16).unwrap()
            })
            .collect();
        let expected: Vec<usize> = offsets.iter().map(|o| o + 1).collect();
        let (_, last) = shifted(&|| {
            dev.set_leds(&leds, Rgb::new(1, 2, 200), false).unwrap();
        });
        assert!(
            last.contains(&format!("chain shifted {expected:?} LED(s)")),
            "{lanes} lanes, expected {expected:?}: {last}"
        );
        // Then each its own colour, one at a time: only its lane shifts, up to it.
        let colours: Vec<Rgb> = (0..lanes)
            .map(|k| Rgb::new(10 * k + 1, 40 + k, 200 - 10 * k))
            .collect();
        for (k, (&led, &colour)) in leds.iter().zip(&colours).enumerate() {
            let mut expected = vec![0usize; lanes as usize];
            expected[k] = offsets[k] + 1;
            let (_, last) = shifted(&|| {
                dev.set_leds(&[led], colour, true).unwrap();
            });
            assert!(
                last.contains(&format!("chain shifted {expected:?} LED(s)")),
                "lane {k} of {lanes}, expected {expected:?}: {last}"
            );
        }
        let log = emu.log_text();
        let lit = log.lines().rfind(|l| l.contains("LEDs lit")).unwrap();
        for (led, c) in leds.iter().zip(&colours) {
            let shown = format!(
                "({},{}) #{:02x}{:02x}{:02x}",
                led.row, led.col, c.r, c.g, c.b
            );
            assert!(lit.contains(&shown), "{shown} not in {lit}");
        }
        assert_eq!(lit.matches('#').count(), lanes as usize, "{lit}");
        assert!(!log.contains("malformed pulse"), "{log}");
        drop(dev);
    }
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
