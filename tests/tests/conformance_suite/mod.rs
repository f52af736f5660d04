//! The conformance suite: every endpoint and topic, exercised by the real host client
//! against a controller running as a separate process behind a pseudo-terminal —
//! the host-compiled emulator (`conformance.rs`) or the real firmware image in an
//! emulated RP2040 (`conformance_firmware.rs`), chosen by the including test's
//! `TARGET`.

use std::time::Duration;

use fpm_acquire::controller::scan::{scan_steps, Order, Selection};
use fpm_acquire::controller::{Controller, SequenceEvent};
use fpm_firmware::chain::chain_index;
use fpm_protocol::*;
use fpm_tests::{Emulator, Target, TempDir};

use crate::TARGET;

const TIMEOUT: Duration = Duration::from_secs(2);

/// How late the firmware may time-stamp a camera edge (interrupt, then the woken task).
const MAX_EDGE_LATENCY_US: u64 = 50;

/// A controller of the suite's target; `extra` are options of the host-compiled
/// emulator (the firmware image has its board built in).
fn emulator(tag: &str, extra: &[&str]) -> (TempDir, Emulator) {
    let dir = TempDir::new(tag);
    let emu = TARGET.start(&dir.0.join("ctl.tty"), extra);
    (dir, emu)
}

fn timing(trigger_in: Option<TriggerIn>) -> SequenceTiming {
    SequenceTiming {
        settle_us: 300,
        exposure_us: 2_000,
        trigger_out: Some(TriggerOut {
            delay_us: 50,
            pulse_us: 100,
            polarity: Polarity::ActiveHigh,
        }),
        trigger_in,
        clear_at_end: true,
    }
}

/// Collect events until the end of the run.
fn drain(events: &mut fpm_acquire::controller::SequenceEvents) -> (Vec<StepEvent>, SequenceEnd) {
    let mut steps = vec![];
    loop {
        match events.next(Duration::from_secs(5)).expect("sequence event") {
            SequenceEvent::Step(s) => steps.push(s),
            SequenceEvent::SetStep(s) => panic!("no LED set was uploaded: {s:?}"),
            SequenceEvent::End(e) => return (steps, e),
        }
    }
}

#[test]
fn identity_version_and_ping() {
    let (_dir, emu) = emulator("identity", &["--serial", "1234"]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    assert_eq!(dev.version().unwrap(), PROTOCOL_VERSION);
    let info = dev.read_info().unwrap();
    assert_eq!(&info, dev.info());
    match TARGET {
        Target::HostEmulator => assert_eq!(info.serial, 1234),
        // The serial number is the flash's unique id, which the emulated flash does
        // not have; the board is the one the image was built for.
        Target::Firmware => {
            assert_eq!(info.board.as_str(), "fpm-pico-21x21");
            // The USB identity of firmware/rp2040/src/board.rs and link.rs, as a host
            // reads it from the device descriptor and its strings.
            let expected =
                "USB device 1209:0001, manufacturer \"fpm\", product \"fpm LED controller\"";
            let log = emu.log_when(|l| l.contains(expected), Duration::from_secs(10));
            assert!(log.contains(expected), "{log}");
        }
    }
    assert_eq!((info.geometry.rows, info.geometry.cols), (21, 21));
    assert_eq!(info.geometry.center, LedIndex::new(10, 10));
    assert_eq!(info.protocol, PROTOCOL_VERSION);
    assert_eq!(info.limits.max_current_ma, 4000);
    for x in [0, 1, u32::MAX, 0x0000_0100] {
        assert_eq!(dev.ping(x).unwrap(), x);
    }
}

#[test]
fn lighting_endpoints_change_what_is_lit() {
    let (_dir, emu) = emulator("lighting", &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();

    let lit = dev
        .set_led(LedIndex::new(10, 10), Rgb::new(0, 255, 0))
        .unwrap();
    assert_eq!((lit.leds_on, lit.current_ma), (1, 20));
    let s = dev.status().unwrap();
    assert_eq!((s.leds_on, s.current_ma), (1, 20));

    // A list longer than one request: the client splits it, the device adds.
    let leds: Vec<LedIndex> = (0..5u8)
        .flat_map(|r| (0..20u8).map(move |c| LedIndex::new(r, c)))
        .collect();
    let lit = dev.set_leds(&leds, Rgb::new(10, 0, 0), false).unwrap();
    assert_eq!(lit.leds_on, 100);
    let lit = dev
        .set_leds(&[LedIndex::new(20, 20)], Rgb::new(10, 0, 0), true)
        .unwrap();
    assert_eq!(lit.leds_on, 101);

    let bf = dev
        .pattern(Pattern::BrightField { na: 0.1 }, Rgb::WHITE)
        .unwrap();
    let df = dev
        .pattern(Pattern::DarkField { na: 0.1 }, Rgb::new(1, 1, 1))
        .unwrap();
    assert_eq!(bf.leds_on + df.leds_on, 441);
    let ring = dev
        .pattern(
            Pattern::Annulus {
                inner: 0.05,
                outer: 0.1,
            },
            Rgb::WHITE,
        )
        .unwrap();
    let inner = dev
        .pattern(Pattern::BrightField { na: 0.05 }, Rgb::WHITE)
        .unwrap();
    assert_eq!(ring.leds_on + inner.leds_on, bf.leds_on);
    // The halves leave out the dividing line through the centre: on that line, the
    // disc reaches |p| ≤ na·h / (pitch·√(1 − na²)) pitches.
    let reach = (0.1 * 92.0 / (2.5 * (1.0f64 - 0.01).sqrt())).floor() as u16;
    let on_line = 2 * reach + 1;
    let mut halves = vec![];
    for half in [Half::Top, Half::Bottom, Half::Left, Half::Right] {
        halves.push(
            dev.pattern(Pattern::HalfCircle { na: 0.1, half }, Rgb::WHITE)
                .unwrap()
                .leds_on,
        );
    }
    assert_eq!(halves[0], halves[1]);
    assert_eq!(halves[2], halves[3]);
    assert_eq!(halves[0] + halves[1] + on_line, bf.leds_on);
    assert_eq!(halves[2] + halves[3] + on_line, bf.leds_on);
    let all = dev.pattern(Pattern::All, Rgb::new(1, 0, 0)).unwrap();
    assert_eq!(all.leds_on, 441);

    let dim = dev.set_brightness(100).unwrap();
    assert_eq!(dim.brightness, 100);
    // 1 × 100/255 rounds to 0: every LED goes dark at this brightness.
    assert_eq!(dim.leds_on, 0);
    dev.set_brightness(255).unwrap();

    let off = dev.clear().unwrap();
    assert_eq!((off.leds_on, off.current_ma), (0, 0));
    assert_eq!(dev.status().unwrap().leds_on, 0);
}

#[test]
fn the_current_budget_holds_over_the_wire() {
    let (_dir, emu) = emulator("budget", &["--max-current-ma", "3000"]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    // The supply's rating: 3000 mA as configured on the emulator, the board's 4000 mA
    // in the firmware image.
    let rating = dev.info().limits.max_current_ma;
    assert_eq!(
        rating,
        match TARGET {
            Target::HostEmulator => 3000,
            Target::Firmware => 4000,
        }
    );
    let err = dev.pattern(Pattern::All, Rgb::WHITE).unwrap_err();
    assert_eq!(
        err.device_error(),
        Some(DeviceError::OverBudget {
            required_ma: 26_460,
            limit_ma: rating,
            step: None
        })
    );
    assert!(err.to_string().contains("26460 mA"), "{err}");
    assert_eq!(
        dev.status().unwrap().leds_on,
        0,
        "a refused request lights nothing"
    );

    let budget = dev
        .set_budget(BudgetConfig {
            limit_ma: 1000,
            policy: BudgetPolicy::Scale,
        })
        .unwrap();
    assert_eq!(budget.limit_ma, 1000);
    let lit = dev.pattern(Pattern::All, Rgb::WHITE).unwrap();
    assert!(
        lit.scaled && lit.current_ma <= 1000 && lit.leds_on == 441,
        "{lit:?}"
    );
    let s = dev.status().unwrap();
    assert!(s.current_ma <= 1000);
    assert_eq!(s.budget, budget);

    let over = dev
        .set_budget(BudgetConfig {
            limit_ma: rating + 1,
            policy: BudgetPolicy::Refuse,
        })
        .unwrap_err();
    assert_eq!(
        over.device_error(),
        Some(DeviceError::TooMany {
            requested: rating + 1,
            max: rating
        })
    );
}

#[test]
fn out_of_range_values_get_typed_errors() {
    let (_dir, emu) = emulator("range", &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let e = dev.set_led(LedIndex::new(21, 3), Rgb::WHITE).unwrap_err();
    assert_eq!(
        e.device_error(),
        Some(DeviceError::BadLed { row: 21, col: 3 })
    );
    assert!(e.to_string().contains("row 21, col 3"), "{e}");
    for p in [
        Pattern::BrightField { na: -0.1 },
        Pattern::DarkField { na: f32::NAN },
        Pattern::Annulus {
            inner: 0.5,
            outer: 0.4,
        },
    ] {
        assert_eq!(
            dev.pattern(p, Rgb::WHITE).unwrap_err().device_error(),
            Some(DeviceError::BadParam(Param::Na))
        );
    }
    assert_eq!(
        dev.abort_sequence().unwrap_err().device_error(),
        Some(DeviceError::NotRunning)
    );
    assert_eq!(
        dev.start_sequence(77).unwrap_err().device_error(),
        Some(DeviceError::WrongSequence {
            requested: 77,
            defined: 0
        })
    );
    let zero = dev
        .set_budget(BudgetConfig {
            limit_ma: 0,
            policy: BudgetPolicy::Refuse,
        })
        .unwrap_err();
    assert_eq!(
        zero.device_error(),
        Some(DeviceError::BadParam(Param::Budget))
    );
    // Still healthy afterwards.
    assert_eq!(dev.ping(5).unwrap(), 5);
}

#[test]
fn a_full_scan_reports_every_step_in_order_with_device_timing() {
    let (_dir, emu) = emulator(
        "scan",
        &["--camera-exposure-us", "1500", "--camera-latency-us", "25"],
    );
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let g = dev.info().geometry;
    let steps = scan_steps(&g, Selection::All, Order::Nearest, Rgb::new(0, 0, 40));
    assert_eq!(steps.len(), 441);
    let trig_in = TriggerIn {
        edge: Edge::Falling,
        timeout_us: 200_000,
    };
    let loaded = dev
        .upload_sequence(11, &steps, timing(Some(trig_in)))
        .unwrap();
    assert_eq!(
        loaded,
        StepsLoaded {
            loaded: 441,
            total: 441
        }
    );
    assert_eq!(dev.sequence_status().unwrap().state, SequenceState::Ready);

    let mut events = dev.subscribe().unwrap();
    let started = dev.start_sequence(11).unwrap();
    assert_eq!(started.steps, 441);
    let (got, end) = drain(&mut events);

    assert_eq!(end.outcome, SequenceOutcome::Done);
    assert_eq!(end.completed, 441);
    assert_eq!(got.len(), 441);
    let mut prev_end = started.started_us;
    let mut worst_latency = 0;
    for (i, ev) in got.iter().enumerate() {
        assert_eq!(ev.step as usize, i);
        assert_eq!(ev.sequence_id, 11);
        assert_eq!(ev.illumination, steps[i].illumination);
        assert_eq!(ev.leds_on, 1);
        // Each step starts after the previous ended, and is lit only after its LED
        // data has been shifted out: at least as far as its own chain position.
        let Illumination::Led(led) = ev.illumination else {
            panic!("not an LED step")
        };
        let index = chain_index(&g, led).unwrap() as u64;
        assert!(
            ev.light_on_us >= prev_end + (index + 1) * 30 + 280,
            "step {i}: lit too early"
        );
        assert!(
            ev.trigger_us >= ev.light_on_us + 300 + 50,
            "step {i}: triggered before settling"
        );
        // The emulated camera's exposure ends latency + exposure after the trigger. The
        // host-compiled emulator stamps the edge exactly; the firmware stamps it in the
        // task the GPIO interrupt wakes, a few µs later.
        let exposure_end = ev.trigger_us + 25 + 1500;
        let stamped = ev.trigger_in_us.expect("the camera's edge");
        let late = stamped.checked_sub(exposure_end).unwrap_or(u64::MAX);
        match TARGET {
            Target::HostEmulator => assert_eq!(late, 0, "step {i}"),
            Target::Firmware => assert!(late <= MAX_EDGE_LATENCY_US, "step {i}: {late} µs late"),
        }
        worst_latency = worst_latency.max(late);
        assert_eq!(ev.end_us, stamped);
        prev_end = ev.end_us;
    }
    eprintln!("camera edge stamped at most {worst_latency} µs after it happened");
    if TARGET == Target::Firmware {
        // The trigger pulses as measured at the pin (GP14): one per step, active high,
        // as wide as asked, fired when the step's event says, after settling.
        // The emulator logs a pulse when its pin falls, which can be after the last
        // reply: wait for the log to hold one per step (or time out and say so).
        let marker = "trigger out at GP14: high at ";
        let log = emu.log_when(
            |log| log.matches(marker).count() >= got.len(),
            Duration::from_secs(5),
        );
        let pulses: Vec<(u64, u64)> = log
            .lines()
            .filter_map(|l| {
                let rest = l.split(marker).nth(1)?;
                let (at, width) = rest.split_once(" µs for ")?;
                Some((
                    at.parse().ok()?,
                    width.trim_end_matches(" µs").parse().ok()?,
                ))
            })
            .collect();
        assert_eq!(pulses.len(), got.len(), "one pulse per step at the pin");
        for (i, (ev, &(at, width))) in got.iter().zip(&pulses).enumerate() {
            assert!(
                at.abs_diff(ev.trigger_us) <= 5,
                "step {i}: pin {at} vs event {}",
                ev.trigger_us
            );
            // The firmware ends the pulse on its own deadline, as late as it stamps edges.
            assert!(
                (100..=100 + MAX_EDGE_LATENCY_US).contains(&width),
                "step {i}: pulse {width} µs, asked 100"
            );
            assert!(
                at >= ev.light_on_us + 300 + 50,
                "step {i}: fired before settling"
            );
        }
        let widest = pulses.iter().map(|p| p.1).max().unwrap_or(0);
        eprintln!(
            "trigger pulses at GP14: {} of 100–{widest} µs",
            pulses.len()
        );
    }
    assert_eq!(end.end_us, prev_end);
    let status = dev.sequence_status().unwrap();
    assert_eq!(
        (status.state, status.completed),
        (SequenceState::Ready, 441)
    );
    assert_eq!(dev.status().unwrap().leds_on, 0, "cleared at the end");
}

#[test]
fn without_a_camera_the_trigger_wait_times_out_with_a_typed_error() {
    let (_dir, emu) = emulator("nocam", &["--no-camera"]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let g = dev.info().geometry;
    let steps = scan_steps(
        &g,
        Selection::Pattern(Pattern::BrightField { na: 0.05 }),
        Order::Nearest,
        Rgb::WHITE,
    );
    let trig_in = TriggerIn {
        edge: Edge::Rising,
        timeout_us: 30_000,
    };
    dev.upload_sequence(3, &steps, timing(Some(trig_in)))
        .unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(3).unwrap();
    let (got, end) = drain(&mut events);
    assert!(got.is_empty());
    assert_eq!(
        end.outcome,
        SequenceOutcome::Failed(DeviceError::TriggerTimeout { step: 0 })
    );
    // It failed at the deadline, not before.
    let status = dev.status().unwrap();
    assert_eq!(status.sequence.last_outcome, Some(end.outcome));
    assert_eq!(status.leds_on, 0);
}

#[test]
fn abort_stops_a_running_sequence_and_busy_guards_the_rest() {
    let (_dir, emu) = emulator("abort", &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let g = dev.info().geometry;
    let steps = scan_steps(&g, Selection::All, Order::Raster, Rgb::WHITE);
    dev.upload_sequence(5, &steps, timing(None)).unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(5).unwrap();
    // Let a few steps run.
    for _ in 0..3 {
        assert!(matches!(
            events.next(Duration::from_secs(2)).unwrap(),
            SequenceEvent::Step(_)
        ));
    }
    assert_eq!(
        dev.set_led(LedIndex::new(0, 0), Rgb::WHITE)
            .unwrap_err()
            .device_error(),
        Some(DeviceError::Busy)
    );
    assert_eq!(
        dev.upload_sequence(6, &steps[..2], timing(None))
            .unwrap_err()
            .device_error(),
        Some(DeviceError::Busy)
    );
    // Writing flash would stall the running sequence: the geometry waits for its end.
    assert!(matches!(
        dev.store_calibration(None),
        Err(fpm_acquire::controller::ControllerError::Storage(
            StorageError::Busy
        ))
    ));
    assert_eq!(dev.status().unwrap().sequence.state, SequenceState::Running);
    let status = dev.abort_sequence().unwrap();
    assert_eq!(status.last_outcome, Some(SequenceOutcome::Aborted));
    let (_, end) = drain(&mut events);
    assert_eq!(end.outcome, SequenceOutcome::Aborted);
    assert!(end.completed >= 3 && end.completed < 441);
    assert_eq!(dev.status().unwrap().leds_on, 0);
}

#[test]
fn the_cli_speaks_json_and_reports_errors() {
    let (_dir, emu) = emulator("cli", &[]);
    let run = |args: &[&str]| {
        std::process::Command::new(fpm_tests::fpm_bin())
            .args(["device", "--port", &emu.port()])
            .args(args)
            .output()
            .unwrap()
    };
    let out = run(&["--json", "info"]);
    assert!(out.status.success());
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["geometry"]["rows"], 21);
    assert_eq!(info["protocol"]["major"], PROTOCOL_VERSION.major);

    let out = run(&["led", "4", "7", "--color", "#102030"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("lit 1 LED"));

    let out = run(&["led", "40", "7"]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("LED (row 40, col 7) is not on the board")
    );

    let out = run(&[
        "--json",
        "run-sequence",
        "--select",
        "bright-field",
        "--na",
        "0.05",
        "--exposure-us",
        "500",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let last = lines.last().unwrap();
    assert_eq!(last["event"], "end");
    assert_eq!(last["outcome"], "Done");
    assert_eq!(lines.len() as u64 - 1, last["completed"].as_u64().unwrap());

    let out = std::process::Command::new(fpm_tests::fpm_bin())
        .args(["device", "--port", "/nonexistent/tty", "info"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("cannot open serial port /nonexistent/tty")
    );
}

/// `fpm device list` finds the board on a port it is told to look at besides USB ones
/// (an emulator has no USB identity), with its serial number and protocol, and
/// `fpm device info` needs no `--port` when exactly one board answers.
#[test]
fn boards_are_listed_and_found_without_a_port() {
    let (_dir, emu) = emulator("list", &[]);
    let fpm = |extra: &str, args: &[&str]| {
        std::process::Command::new(fpm_tests::fpm_bin())
            .env_remove("FPM_PORT")
            .env("FPM_EXTRA_PORTS", extra)
            .arg("device")
            .args(args)
            .output()
            .unwrap()
    };
    let both = format!("{}:/nonexistent/tty", emu.port());
    let out = fpm(&both, &["list", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let list: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let list = list.as_array().unwrap();
    assert_eq!(list.len(), 2, "{list:?}");
    assert_eq!(list[0]["port"], emu.port());
    assert_eq!(list[0]["info"]["protocol"]["major"], PROTOCOL_VERSION.major);
    assert!(list[1]["info"].is_null());
    assert!(list[1]["error"]
        .as_str()
        .unwrap()
        .contains("cannot open serial port /nonexistent/tty"));

    let out = fpm(&both, &["--json", "info"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(info["serial"], list[0]["info"]["serial"]);

    let out = fpm("/nonexistent/tty", &["info"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no LED controller found (USB 1209:0001") && stderr.contains("--port"),
        "{stderr}"
    );
}

#[test]
/// What is lit is logged as the chain shows it (for the firmware: decoded from the
/// WS2812 data pin, GP16), and a stopped controller removes its link.
fn the_emulator_logs_what_it_lights_and_cleans_up_its_link() {
    let dir = TempDir::new("log");
    let link = dir.0.join("ctl.tty");
    let mut emu = TARGET.start(&link, &[]);
    {
        let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
        dev.set_led(LedIndex::new(2, 19), Rgb::new(1, 2, 3))
            .unwrap();
    }
    // The reply comes before the chain has shifted out and latched (on the firmware,
    // the emulated PIO runs on after it): wait for the log, within reason.
    let lit = "LEDs lit: (2,19) #010203";
    emu.log_when(|l| l.contains(lit), Duration::from_secs(5));
    let status = emu.stop().expect("emulator ran");
    assert!(status.success(), "{status}");
    assert!(emu.log_text().contains(lit), "{}", emu.log_text());
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "link removed on exit"
    );
}

/// The restart in BOOTSEL, as `fpm device bootsel` asks it: the running sequence
/// aborted, every LED turned off and latched, the answer, then the board leaves its
/// port (the emulator ends, successfully, as the port does). On the firmware image the
/// harness sees it hand over to the boot ROM: the ROM's reboot magic in the watchdog's
/// scratch register and a restart address inside the ROM.
#[test]
fn bootsel_turns_every_led_off_answers_and_leaves_the_port() {
    let dir = TempDir::new("bootsel");
    let link = dir.0.join("ctl.tty");
    let mut emu = TARGET.start(&link, &["--no-camera"]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    dev.set_led(LedIndex::new(10, 10), Rgb::WHITE).unwrap();
    emu.log_when(|l| l.contains("LEDs lit: (10,10)"), Duration::from_secs(5));
    dev.reboot_to_bootsel().unwrap();
    let status = emu
        .exited_within(Duration::from_secs(20))
        .unwrap_or_else(|| panic!("still running after BOOTSEL:\n{}", emu.log_text()));
    assert!(status.success(), "{status}\n{}", emu.log_text());
    let log = emu.log_text();
    let off = log.rfind("LEDs: all off");
    let lit = log.rfind("LEDs lit: (10,10)");
    assert!(
        off > lit,
        "the LEDs were not turned off before the restart:\n{log}"
    );
    assert!(log.contains("BOOTSEL"), "{log}");
    if TARGET == fpm_tests::Target::Firmware {
        let entry = log
            .split("restart at ROM address 0x")
            .nth(1)
            .and_then(|s| s.split_whitespace().next())
            .and_then(|h| u32::from_str_radix(h, 16).ok())
            .unwrap_or_else(|| panic!("no hand-over to the boot ROM:\n{log}"));
        assert!(
            entry < 0x4000,
            "the restart address {entry:#x} is not in the 16 KiB ROM"
        );
    }
}

fn board_calibration(dx_mm: f32) -> BoardCalibration {
    BoardCalibration {
        dx_mm,
        dy_mm: -0.87,
        theta_deg: 4.9,
        height_mm: 91.6,
        sigma: PlacementSigma {
            dx_mm: 0.002,
            dy_mm: 0.002,
            theta_deg: 0.02,
            height_mm: 0.3,
        },
        rms_residual_um: 0.5,
        calibrated_unix_s: 1_796_000_000,
    }
}

#[test]
/// The board keeps its calibration in flash (protocol 1.1): stored, read back after a
/// restart with the flash kept (a board unplugged and plugged in again), refused when
/// unusable, forgotten on request. On the real firmware the chip's own flash routines
/// program an emulated SPI NOR chip, the serial number is the chip's unique id, and a
/// power cut in the middle of a write leaves the old record.
fn the_board_remembers_its_geometry_across_restarts() {
    let dir = TempDir::new("geometry");
    let link = dir.0.join("ctl.tty");
    let flash = dir.0.join("flash.img").to_string_lossy().into_owned();
    let serial: u64 = 0x1234_5678_90ab_cf01;
    let serial_arg = serial.to_string();
    let start = |extra: &[&str]| {
        let mut args = vec!["--flash", flash.as_str(), "--serial", serial_arg.as_str()];
        args.extend_from_slice(extra);
        TARGET.start(&link, &args)
    };
    let first = board_calibration(1.52);
    let second = board_calibration(-2.75);

    let mut emu = start(&[]);
    {
        let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
        assert_eq!(dev.info().protocol, PROTOCOL_VERSION);
        assert_eq!(dev.info().serial, serial, "serial number (flash unique id)");
        assert_eq!(
            dev.stored_calibration().unwrap(),
            StoredCalibration::NotCalibrated
        );
        assert_eq!(
            dev.store_calibration(Some(first)).unwrap(),
            StoredCalibration::Calibrated(first)
        );
        let bad = BoardCalibration {
            height_mm: -1.0,
            ..second
        };
        assert!(matches!(
            dev.store_calibration(Some(bad)),
            Err(fpm_acquire::controller::ControllerError::Storage(
                StorageError::Invalid
            ))
        ));
        assert_eq!(
            dev.stored_calibration().unwrap(),
            StoredCalibration::Calibrated(first)
        );
    }
    assert!(emu.stop().expect("emulator ran").success());

    if TARGET == Target::Firmware {
        // Power lost 20 bytes into the next record: the old one survives.
        let mut emu = start(&["--power-cut-after", "20"]);
        {
            let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
            assert!(dev.store_calibration(Some(second)).is_err());
        }
        let status = emu.stop();
        assert!(
            emu.log_text().contains("power cut during a flash write"),
            "{status:?}\n{}",
            emu.log_text()
        );
    }

    let mut emu = start(&[]);
    {
        let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
        assert_eq!(
            dev.stored_calibration().unwrap(),
            StoredCalibration::Calibrated(first),
            "kept across the restart"
        );
        assert_eq!(
            dev.store_calibration(Some(second)).unwrap(),
            StoredCalibration::Calibrated(second)
        );
        assert_eq!(
            dev.store_calibration(None).unwrap(),
            StoredCalibration::NotCalibrated
        );
    }
    assert!(emu.stop().expect("emulator ran").success());
    let mut emu = start(&[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    assert_eq!(
        dev.stored_calibration().unwrap(),
        StoredCalibration::NotCalibrated,
        "forgetting is kept too"
    );
    drop(dev);
    emu.stop();
}

#[test]
/// Gamma correction (smart-leds' table) changes what is shifted out, as the chain shows
/// it (for the firmware: decoded at GP16), and the current is counted on those values.
fn gamma_changes_what_is_shifted_out_and_the_current_counts_it() {
    let (_dir, emu) = emulator("gamma", &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    assert!(!dev.gamma(None).unwrap(), "off by default: light ∝ value");
    let lit = dev
        .set_led(LedIndex::new(3, 4), Rgb::new(128, 0, 255))
        .unwrap();
    // (128 + 255) × 20 mA / 255, rounded up.
    assert_eq!(lit.current_ma, 31);
    assert!(dev.gamma(Some(true)).unwrap());
    assert!(dev.gamma(None).unwrap());
    // 128 → 37 through the table; 255 stays.
    let status = dev.status().unwrap();
    assert_eq!(status.current_ma, ((37 + 255) * 20u32).div_ceil(255));
    let shown = "LEDs lit: (3,4) #2500ff";
    let log = emu.log_when(|l| l.contains(shown), Duration::from_secs(5));
    assert!(log.contains(shown), "{log}");
    assert!(!dev.gamma(Some(false)).unwrap());
    assert_eq!(dev.status().unwrap().current_ma, 31);
}

#[test]
/// A change shifts out only up to the last LED that changed, in each lane (for the
/// firmware: the words counted at GP16 before the latch).
fn a_partial_shift_stops_at_the_last_changed_led() {
    let (_dir, emu) = emulator("partial", &[]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    let g = dev.info().geometry;
    let led_at_chain = |k: u16| fpm_firmware::chain::led_at(&g, k).unwrap();
    let wait_for = |text: &str| {
        let log = emu.log_when(|l| l.contains(text), Duration::from_secs(5));
        assert!(log.contains(text), "no \"{text}\" in the log:\n{log}");
        log
    };
    // From dark, the LED at chain position 100: 101 LEDs go out.
    dev.set_led(led_at_chain(100), Rgb::new(0, 0, 9)).unwrap();
    wait_for("chain shifted [101] LED(s)");
    // Moving it to position 5 changes positions 5 and 100: still 101.
    let before = emu.log_text().matches("chain shifted").count();
    dev.set_led(led_at_chain(5), Rgb::new(0, 0, 9)).unwrap();
    let log = emu.log_when(
        |l| l.matches("chain shifted").count() > before,
        Duration::from_secs(5),
    );
    let last = log.lines().rfind(|l| l.contains("chain shifted")).unwrap();
    assert!(last.contains("[101]"), "{last}");
    // Adding position 3 changes only it: 4 LEDs go out, the rest keep their colour.
    dev.set_leds(&[led_at_chain(3)], Rgb::new(0, 0, 9), true)
        .unwrap();
    let log = wait_for("chain shifted [4] LED(s)");
    let lit = log.lines().rfind(|l| l.contains("LEDs lit")).unwrap();
    for k in [3, 5] {
        let led = led_at_chain(k);
        assert!(lit.contains(&format!("({},{})", led.row, led.col)), "{lit}");
    }
}

/// Protocol 1.2: a table of LED sets, each lit whole by a sequence step that names it
/// (multiplexed illumination), reported on its own topic; the 1.0 sequence path is
/// untouched beside it.
#[test]
fn led_sets_are_lit_whole_by_the_steps_that_name_them() {
    let (_dir, emu) = emulator("sets", &["--no-camera"]);
    let dev = Controller::open(&emu.port(), TIMEOUT).unwrap();
    assert!(dev.info().protocol.supports(PROTOCOL_1_2));
    let led = |r, c| LedIndex::new(r, c);
    let sets = vec![
        vec![led(10, 10), led(3, 4), led(17, 2), led(5, 19)],
        vec![led(0, 0)],
        (0..8).map(|c| led(20, c)).collect::<Vec<_>>(),
    ];
    let defined = dev.define_led_sets(&sets).unwrap();
    assert_eq!((defined.sets, defined.leds), (3, 13));
    let color = Rgb::new(0, 0, 40);
    let order = [0u16, 1, 2, 0];
    let steps: Vec<SetStep> = order.iter().map(|&set| SetStep { set, color }).collect();
    let loaded = dev.upload_set_sequence(21, &steps, timing(None)).unwrap();
    assert_eq!(loaded.loaded, 4);
    let mut events = dev.subscribe().unwrap();
    let started = dev.start_sequence(21).unwrap();
    let mut got = vec![];
    let end = loop {
        match events.next(Duration::from_secs(5)).expect("sequence event") {
            SequenceEvent::SetStep(s) => got.push(s),
            SequenceEvent::Step(s) => panic!("a set step reported as a 1.0 step: {s:?}"),
            SequenceEvent::End(e) => break e,
        }
    };
    assert_eq!(end.outcome, SequenceOutcome::Done);
    assert_eq!(end.completed, 4);
    let mut prev_end = started.started_us;
    for (i, ev) in got.iter().enumerate() {
        assert_eq!((ev.sequence_id, ev.step as usize), (21, i));
        assert_eq!(ev.set, order[i]);
        assert_eq!(ev.color, color);
        assert_eq!(
            ev.leds_on as usize,
            sets[order[i] as usize].len(),
            "step {i}"
        );
        assert!(ev.light_on_us > prev_end && ev.trigger_us >= ev.light_on_us + 300);
        prev_end = ev.end_us;
    }
    assert_eq!(dev.status().unwrap().leds_on, 0, "cleared at the end");

    // A step naming a set the table does not hold is refused when uploaded, naming
    // its index and how many there are; so is a set defined out of order.
    let missing = [SetStep { set: 3, color }];
    assert_eq!(
        dev.upload_set_sequence(22, &missing, timing(None))
            .unwrap_err()
            .device_error(),
        Some(DeviceError::TooMany {
            requested: 4,
            max: 3
        })
    );
    let skipped = LedSetDefine {
        index: 5,
        leds: heapless::Vec::from_slice(&[led(1, 1)]).unwrap(),
    };
    assert!(matches!(
        dev.request::<LedSetDefineEndpoint>(&skipped).unwrap(),
        Err(DeviceError::ChunkOutOfRange {
            offset: 5,
            loaded: 3,
            ..
        })
    ));
    // Each step is held to the current budget: eight LEDs in white exceed 100 mA.
    dev.set_budget(BudgetConfig {
        limit_ma: 100,
        policy: BudgetPolicy::Refuse,
    })
    .unwrap();
    let white = [SetStep {
        set: 2,
        color: Rgb::WHITE,
    }];
    assert!(matches!(
        dev.upload_set_sequence(23, &white, timing(None))
            .unwrap_err()
            .device_error(),
        Some(DeviceError::OverBudget { step: Some(0), .. })
    ));
    // The 1.0 path still runs beside the table.
    let one = [Step {
        illumination: Illumination::Led(led(10, 10)),
        color,
    }];
    dev.upload_sequence(24, &one, timing(None)).unwrap();
    let mut events = dev.subscribe().unwrap();
    dev.start_sequence(24).unwrap();
    let (steps, end) = drain(&mut events);
    assert_eq!((steps.len(), end.outcome), (1, SequenceOutcome::Done));
}
