//! Stage conformance and faults: each driver in `fpm-stage` against an emulator that
//! speaks its firmware's protocol on a real pseudo-terminal (`fpm-stage-emulator`):
//! GRBL 1.1, Marlin 2 and the Sangaboard. The same suite runs against each; the
//! emulators' hidden state (where the carriage really is, what was sent) is the truth.

use std::time::{Duration, Instant};

use fpm_stage::{
    Connection, Limits, Position, Protocol, Range, Stage, StageError, StageOptions, Target,
};
use fpm_stage_emulator::{Config, Emulator, Fault, Kind};

/// µm per step of the emulated Sangaboard (the driver is told the same).
const UM_PER_STEP: [f64; 3] = [0.5, 0.5, 0.1];

fn options() -> StageOptions {
    StageOptions {
        settle: Duration::from_millis(10),
        ..StageOptions::default()
    }
}

fn open(emulator: &Emulator, kind: Kind, options: StageOptions) -> Box<dyn Stage + Send> {
    let protocol = match kind {
        Kind::Sangaboard => Protocol::Sangaboard,
        _ => Protocol::Gcode,
    };
    let connection = Connection {
        protocol,
        port: emulator.path().display().to_string(),
        baud: 115_200,
    };
    connection
        .open(options, Some(UM_PER_STEP))
        .unwrap_or_else(|e| panic!("opening {kind:?}: {e}"))
}

/// A point well inside every emulator's travel, relative to its range.
fn inside(kind: Kind, fraction: [f64; 3]) -> Position {
    let travel = Config::new(kind).travel_um;
    let v: [f64; 3] = [0, 1, 2].map(|i| match kind {
        Kind::Grbl => -fraction[i] * travel[i],
        Kind::Marlin => fraction[i] * travel[i],
        // The Sangaboard counts from power-on, either way.
        Kind::Sangaboard => (fraction[i] - 0.5) * 2000.0,
    });
    Position::from_array(v)
}

fn ready(kind: Kind, config: Config, options: StageOptions) -> (Emulator, Box<dyn Stage + Send>) {
    let emulator = Emulator::start(config, None).expect("starting the emulator");
    let mut stage = open(&emulator, kind, options);
    if stage.info().can_home {
        stage.home().expect("homing");
    }
    (emulator, stage)
}

/// The emulated `kind`, quick enough for tests: 40 mm/s in X and Y, 10 in Z.
fn config(kind: Kind) -> Config {
    let mut c = Config::new(kind);
    c.speed_um_s = [40_000.0, 40_000.0, 10_000.0];
    c
}

const KINDS: [Kind; 3] = [Kind::Grbl, Kind::Marlin, Kind::Sangaboard];

#[test]
fn each_stage_names_its_firmware_and_limits() {
    for kind in KINDS {
        let emulator = Emulator::start(config(kind), None).unwrap();
        let stage = open(&emulator, kind, options());
        let info = stage.info();
        let z = info.limits.z.map(|r| (r.min_um, r.max_um));
        match kind {
            Kind::Grbl => {
                assert_eq!(info.firmware, "Grbl 1.1h");
                assert!(info.can_home);
                assert_eq!(z, Some((-5000.0, 0.0)));
            }
            Kind::Marlin => {
                assert!(
                    info.firmware.starts_with("Marlin 2.1.2.1"),
                    "{}",
                    info.firmware
                );
                assert!(info.can_home);
                assert_eq!(z, Some((0.0, 5000.0)));
            }
            Kind::Sangaboard => {
                assert_eq!(info.firmware, "Sangaboard Firmware v1.0.4");
                assert!(!info.can_home);
                assert_eq!(info.limits, Limits::default());
            }
        }
        assert_eq!(info.port, emulator.path().display().to_string());
    }
}

#[test]
fn each_stage_moves_where_asked_and_returns_once_there() {
    for kind in KINDS {
        let config = config(kind);
        let (emulator, mut stage) = ready(kind, config.clone(), options());
        let mut from = stage.position().unwrap();
        for fraction in [[0.3, 0.6, 0.4], [0.7, 0.2, 0.45], [0.31, 0.61, 0.401]] {
            let to = inside(kind, fraction);
            let started = Instant::now();
            let at = stage.move_to(Target::at(to)).unwrap();
            let took = started.elapsed().as_secs_f64();
            // The motors are there and still; the driver's answer agrees with them.
            let motor = emulator.motor_um();
            assert!(!emulator.moving(), "{kind:?}: returned while moving");
            for i in 0..3 {
                let step = if kind == Kind::Sangaboard {
                    UM_PER_STEP[i]
                } else {
                    1.0
                };
                assert!(
                    (motor[i] - to.to_array()[i]).abs() <= step,
                    "{kind:?} axis {i}: motor {} for {}",
                    motor[i],
                    to.to_array()[i]
                );
                assert!(
                    (at.to_array()[i] - motor[i]).abs() <= 1.0,
                    "{kind:?}: reported {at} at motor {motor:?}"
                );
            }
            // A move takes its distance over the speed: the driver waited for it.
            let speed = match kind {
                Kind::Sangaboard => UM_PER_STEP.map(|u| u / (config.step_delay_us * 1e-6)),
                _ => config.speed_um_s,
            };
            let need = (0..3)
                .map(|i| (to.to_array()[i] - from.to_array()[i]).abs() / speed[i])
                .fold(0.0, f64::max);
            assert!(
                took >= need,
                "{kind:?}: returned after {took:.3} s, the move takes {need:.3} s"
            );
            from = at;
        }
        // One axis alone: the others stay.
        let before = stage.position().unwrap();
        let z = inside(kind, [0.0, 0.0, 0.5]).z_um;
        let at = stage.move_to(Target::z(z)).unwrap();
        assert!((at.x_um - before.x_um).abs() < 1.0 && (at.y_um - before.y_um).abs() < 1.0);
        assert!((at.z_um - z).abs() <= 1.0);
    }
}

#[test]
fn backlash_is_taken_up_by_approaching_from_below() {
    for kind in KINDS {
        let mut config = config(kind);
        config.backlash_um = [0.0, 0.0, 6.0];
        // The carriage's Z after arriving at `z` from above and from below.
        let arrive = |compensate: bool| -> [f64; 2] {
            let mut opts = options();
            if compensate {
                opts.backlash_um = [0.0, 0.0, 10.0];
            }
            let (emulator, mut stage) = ready(kind, config.clone(), opts);
            let z = inside(kind, [0.5, 0.5, 0.5]).z_um;
            let mut out = [0.0; 2];
            for (k, start) in [z + 200.0, z - 200.0].into_iter().enumerate() {
                stage.move_to(Target::z(start)).unwrap();
                stage.move_to(Target::z(z)).unwrap();
                out[k] = emulator.mechanical_um()[2];
            }
            out
        };
        let [from_above, from_below] = arrive(false);
        assert!(
            (from_above - from_below).abs() > 5.0,
            "{kind:?}: the emulator's play should show without compensation ({from_above} vs {from_below})"
        );
        let [from_above, from_below] = arrive(true);
        assert!(
            (from_above - from_below).abs() < 0.2,
            "{kind:?}: with compensation both approaches end alike ({from_above} vs {from_below})"
        );
    }
}

#[test]
fn a_move_beyond_the_limits_is_refused_before_it_is_sent() {
    for kind in KINDS {
        let mut opts = options();
        // The Sangaboard has no limits of its own: the user's.
        opts.limits.z = Some(Range {
            min_um: -3000.0,
            max_um: 3000.0,
        });
        let (emulator, mut stage) = ready(kind, config(kind), opts.clone());
        let before = emulator.received().len();
        let bad = match kind {
            Kind::Grbl => -5200.0,
            Kind::Marlin => 5200.0,
            Kind::Sangaboard => 3100.0,
        };
        match stage.move_to(Target::z(bad)) {
            Err(StageError::OutOfRange {
                axis, target_um, ..
            }) => {
                assert_eq!(axis, fpm_stage::Axis::Z);
                assert_eq!(target_um, bad);
            }
            other => panic!("{kind:?}: expected a refusal, got {other:?}"),
        }
        let sent = &emulator.received()[before..];
        assert!(
            sent.iter()
                .all(|l| !l.contains('G') && !l.starts_with("mr")),
            "{kind:?}: a motion command went out: {sent:?}"
        );
        // Backlash overshoot counts too: a target just inside whose approach would
        // dip below the limit is refused.
        if kind != Kind::Marlin {
            continue;
        }
        opts.backlash_um = [0.0, 0.0, 50.0];
        drop(stage);
        let mut stage = open(&emulator, kind, opts);
        stage.move_to(Target::z(1000.0)).unwrap();
        assert!(matches!(
            stage.move_to(Target::z(20.0)),
            Err(StageError::OutOfRange { .. })
        ));
    }
}

#[test]
fn grbl_alarms_are_reported_and_homing_recovers() {
    let (emulator, mut stage) = ready(Kind::Grbl, config(Kind::Grbl), options());
    let far = inside(Kind::Grbl, [0.9, 0.9, 0.5]);
    // A limit switch closes mid-move.
    let mover = std::thread::scope(|s| {
        let h = s.spawn(|| stage.move_to(Target::at(far)));
        std::thread::sleep(Duration::from_millis(100));
        assert!(emulator.moving(), "the move should still be under way");
        emulator.inject(Fault::LimitSwitch);
        h.join().unwrap()
    });
    match mover {
        Err(e @ StageError::Alarm { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("hard limit") && msg.contains("home"), "{msg}");
        }
        other => panic!("expected an alarm, got {other:?}"),
    }
    // Locked until homed; homing resets and recovers.
    assert!(matches!(
        stage.move_to(Target::z(-100.0)),
        Err(StageError::Alarm { .. }) | Err(StageError::Timeout { .. })
    ));
    stage.home().unwrap();
    let at = stage.move_to(Target::z(-100.0)).unwrap();
    assert!((at.z_um + 100.0).abs() <= 1.0);
}

#[test]
fn grbl_starts_locked_until_homed() {
    let emulator = Emulator::start(config(Kind::Grbl), None).unwrap();
    let mut stage = open(&emulator, Kind::Grbl, options());
    let e = stage.move_to(Target::z(-100.0)).unwrap_err();
    assert!(matches!(e, StageError::Alarm { .. }), "{e}");
    assert!(e.to_string().contains("home"), "{e}");
}

#[test]
fn marlin_limit_switch_and_halt_are_reported() {
    let (emulator, mut stage) = ready(Kind::Marlin, config(Kind::Marlin), options());
    let far = inside(Kind::Marlin, [0.9, 0.9, 0.5]);
    let moved = std::thread::scope(|s| {
        let h = s.spawn(|| stage.move_to(Target::at(far)));
        std::thread::sleep(Duration::from_millis(100));
        assert!(emulator.moving(), "the move should still be under way");
        emulator.inject(Fault::LimitSwitch);
        h.join().unwrap()
    });
    assert!(matches!(moved, Err(StageError::Missed { .. })), "{moved:?}");
    let moved = std::thread::scope(|s| {
        let h = s.spawn(|| stage.move_to(Target::at(inside(Kind::Marlin, [0.1, 0.1, 0.5]))));
        std::thread::sleep(Duration::from_millis(100));
        assert!(emulator.moving(), "the move should still be under way");
        emulator.inject(Fault::Halt);
        h.join().unwrap()
    });
    match moved {
        Err(e @ StageError::Alarm { .. }) => assert!(e.to_string().contains("halted"), "{e}"),
        other => panic!("expected Marlin's halt, got {other:?}"),
    }
}

#[test]
fn a_stage_unplugged_mid_move_fails_promptly_naming_its_port() {
    for kind in KINDS {
        let (mut emulator, mut stage) = ready(kind, config(kind), options());
        let port = emulator.path().display().to_string();
        let far = inside(kind, [0.9, 0.9, 0.9]);
        let started = Instant::now();
        let moved = std::thread::scope(|s| {
            let h = s.spawn(|| stage.move_to(Target::at(far)));
            std::thread::sleep(Duration::from_millis(100));
            assert!(
                emulator.moving(),
                "{kind:?}: the move should still be under way"
            );
            emulator.unplug();
            h.join().unwrap()
        });
        let e = moved.expect_err("a move whose stage went away");
        assert!(
            matches!(e, StageError::Disconnected { .. }),
            "{kind:?}: {e}"
        );
        assert!(e.to_string().contains(&port), "{e}");
        assert!(
            started.elapsed() < Duration::from_secs(3),
            "{kind:?}: took {:?}",
            started.elapsed()
        );
    }
}

#[test]
fn a_port_that_is_no_stage_is_named() {
    // The LED controller's protocol is binary: a G-code driver must give up, not hang.
    let e = match "gcode:/dev/null-no-such-port"
        .parse::<Connection>()
        .unwrap()
        .open(options(), None)
    {
        Err(e) => e,
        Ok(_) => panic!("opened a port that does not exist"),
    };
    assert!(matches!(e, StageError::Open { .. }), "{e}");
    assert!(e.to_string().contains("/dev/null-no-such-port"));
    let e = match "sangaboard:/dev/ttyX"
        .parse::<Connection>()
        .unwrap()
        .open(options(), None)
    {
        Err(e) => e,
        Ok(_) => panic!("a Sangaboard without a step size"),
    };
    assert!(e.to_string().contains("--stage-um-per-step"), "{e}");
    // A Sangaboard is not G-code firmware.
    let emulator = Emulator::start(config(Kind::Sangaboard), None).unwrap();
    let connection = Connection {
        protocol: Protocol::Gcode,
        port: emulator.path().display().to_string(),
        baud: 115_200,
    };
    let e = match connection.open(options(), None) {
        Err(e) => e,
        Ok(_) => panic!("a Sangaboard taken for G-code"),
    };
    assert!(matches!(e, StageError::Unexpected { .. }), "{e}");
    assert!(e.to_string().contains("Type 'help'"), "{e}");
}
