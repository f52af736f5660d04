//! The G-code stage driver: GRBL 1.1 and Marlin 2, told apart when the port opens.
//!
//! Both take absolute moves in mm. GRBL is moved in machine coordinates (`G53`) and
//! followed by polling its status (`?`) until it is idle; Marlin is moved with `G90`
//! `G0` and waited for with `M400`, whose `ok` comes when the motion is done. Limits are
//! read from the firmware (`$$`, `M211`) and checked by [`crate::MotorStage`] before
//! any move is sent.

use std::time::{Duration, Instant};

use crate::line::LinePort;
use crate::{grbl, marlin, Firmware, Limits, Position, StageError};

/// Which G-code firmware is on the port.
#[derive(Debug, Clone, PartialEq)]
pub enum Dialect {
    /// GRBL, its version (`1.1h`) and settings.
    Grbl {
        version: String,
        settings: grbl::Settings,
    },
    /// Marlin, its name and version, and its soft end stops.
    Marlin {
        name: String,
        endstops: Option<marlin::SoftEndstops>,
    },
}

/// A stage running G-code firmware.
pub struct Gcode {
    port: LinePort,
    dialect: Dialect,
    /// GRBL's last work coordinate offset, mm, for reports that give WPos.
    wco: Option<[f64; 3]>,
    /// Marlin: the last target sent, mm. `M114` rounds to 10 µm; a report within that
    /// rounding of the target is the target.
    sent: Option<[f64; 3]>,
}

/// How long to wait for an answer to a short command.
const ANSWER: Duration = Duration::from_secs(3);
/// How often GRBL is polled while it moves.
const POLL: Duration = Duration::from_millis(40);
/// The longest Marlin move waited for without a busy message (it sends one every 2 s
/// unless its host keep-alive is off).
const MARLIN_MOVE: Duration = Duration::from_secs(60);
/// The longest homing cycle waited for.
const HOMING: Duration = Duration::from_secs(180);

fn mm(um: f64) -> String {
    format!("{:.4}", um / 1000.0)
}

impl Gcode {
    /// Open `path` at `baud` (115200 for GRBL and most Marlin boards) and find out which
    /// firmware answers.
    pub fn open(path: &str, baud: u32) -> Result<Self, StageError> {
        let mut port = LinePort::open(path, baud)?;
        let dialect = detect(&mut port)?;
        tracing::info!(port = path, firmware = ?dialect, "G-code stage");
        let mut g = Self {
            port,
            dialect,
            wco: None,
            sent: None,
        };
        if let Dialect::Marlin { .. } = g.dialect {
            g.command("G21")?;
            g.command("G90")?;
        }
        Ok(g)
    }

    /// Which firmware this is.
    pub fn dialect(&self) -> &Dialect {
        &self.dialect
    }

    /// Send `line` and wait for its `ok`.
    fn command(&mut self, line: &str) -> Result<(), StageError> {
        self.command_within(line, ANSWER)
    }

    fn command_within(&mut self, line: &str, wait: Duration) -> Result<(), StageError> {
        let during = format!("sending `{line}`");
        self.port.send_line(line, &during)?;
        let port = self.port.name().to_string();
        match &self.dialect {
            Dialect::Grbl { .. } => {
                let mut wco = self.wco;
                self.port.wait_for(
                    Instant::now() + wait,
                    &during,
                    |l| l == "ok",
                    |l| match grbl::parse_line(l) {
                        grbl::Reply::Error(9) => Err(StageError::Alarm {
                            port: port.clone(),
                            what: format!("GRBL is in its alarm state and refused `{line}`"),
                            advice: "home the stage (`fpm stage home`) or unlock it".into(),
                        }),
                        grbl::Reply::Error(n) => Err(StageError::Refused {
                            port: port.clone(),
                            command: line.into(),
                            what: format!("error:{n}, {}", grbl::error_meaning(n)),
                        }),
                        grbl::Reply::Alarm(n) => Err(grbl_alarm(&port, n)),
                        grbl::Reply::Status(s) => {
                            wco = s.wco.or(wco);
                            Ok(())
                        }
                        _ => Ok(()),
                    },
                )?;
                self.wco = wco;
            }
            Dialect::Marlin { .. } => {
                // Marlin's busy messages mean "still working": each one extends the wait.
                let mut deadline = Instant::now() + wait;
                loop {
                    match self.port.read_line(deadline, &during)? {
                        None => {
                            return Err(StageError::Timeout {
                                port,
                                during,
                                after: wait,
                            })
                        }
                        Some(l) => match marlin::parse_line(&l) {
                            marlin::Reply::Ok => break,
                            marlin::Reply::Busy => deadline = Instant::now() + wait,
                            marlin::Reply::Error(e) => return Err(marlin_error(&port, line, e)),
                            marlin::Reply::Unknown(c) => {
                                return Err(StageError::Refused {
                                    port,
                                    command: line.into(),
                                    what: format!("Marlin does not know `{c}`"),
                                })
                            }
                            _ => {}
                        },
                    }
                }
            }
        }
        Ok(())
    }

    /// One GRBL status report.
    fn grbl_status(&mut self, during: &str) -> Result<grbl::Status, StageError> {
        self.port.send(b"?", during)?;
        let port = self.port.name().to_string();
        let mut status = None;
        self.port.wait_for(
            Instant::now() + ANSWER,
            during,
            |l| {
                status = grbl::parse_status(l);
                status.is_some()
            },
            |l| match grbl::parse_line(l) {
                grbl::Reply::Alarm(n) => Err(grbl_alarm(&port, n)),
                _ => Ok(()),
            },
        )?;
        let status = status.ok_or_else(|| StageError::Unexpected {
            port: self.port.name().into(),
            during: during.into(),
            line: "no status".into(),
        })?;
        if status.wco.is_some() {
            self.wco = status.wco;
        }
        Ok(status)
    }

    /// GRBL's machine position from a status report, mm.
    fn grbl_position(&mut self, during: &str) -> Result<(grbl::State, [f64; 3]), StageError> {
        // A report with WPos needs the offset, which GRBL sends every few reports.
        for _ in 0..40 {
            let s = self.grbl_status(during)?;
            if let Some(m) = s.mpos {
                return Ok((s.state, m));
            }
            if let (Some(w), Some(o)) = (s.wpos, self.wco) {
                return Ok((s.state, [w[0] + o[0], w[1] + o[1], w[2] + o[2]]));
            }
            std::thread::sleep(POLL);
        }
        Err(StageError::Unexpected {
            port: self.port.name().into(),
            during: during.into(),
            line: "status reports with WPos but never WCO".into(),
        })
    }

    /// Soft-reset GRBL (0x18) and wait for its start-up line.
    fn grbl_reset(&mut self) -> Result<(), StageError> {
        let during = "resetting GRBL after an alarm";
        self.port.send(&[0x18], during)?;
        self.port.wait_for(
            Instant::now() + ANSWER,
            during,
            |l| matches!(grbl::parse_line(l), grbl::Reply::Banner(_)),
            |_| Ok(()),
        )?;
        Ok(())
    }

    fn max_rate_mm_s(&self) -> f64 {
        match &self.dialect {
            Dialect::Grbl { settings, .. } => {
                settings
                    .max_rate_mm_min
                    .iter()
                    .copied()
                    .filter(|r| *r > 0.0)
                    .fold(f64::INFINITY, f64::min)
                    .min(1e6)
                    / 60.0
            }
            Dialect::Marlin { .. } => 1.0,
        }
    }
}

fn grbl_alarm(port: &str, code: u16) -> StageError {
    let (what, advice) = grbl::alarm_meaning(code);
    StageError::Alarm {
        port: port.into(),
        what: what.into(),
        advice: advice.into(),
    }
}

fn marlin_error(port: &str, command: &str, e: String) -> StageError {
    if e.contains("halted") || e.contains("kill") {
        StageError::Alarm {
            port: port.into(),
            what: format!("Marlin halted: {e}"),
            advice: "clear the cause (an end stop, a driver fault) and reset the board".into(),
        }
    } else {
        StageError::Refused {
            port: port.into(),
            command: command.into(),
            what: e,
        }
    }
}

/// Ask the firmware who it is. GRBL answers `$I` with `[VER:…]` and `ok`; Marlin says it
/// does not know the command. A board that resets when the port opens (an Arduino)
/// misses the first request while its boot loader runs, so ask again.
fn detect(port: &mut LinePort) -> Result<Dialect, StageError> {
    let during = "asking which G-code firmware this is";
    port.discard_input();
    let mut grbl_version: Option<String> = None;
    let mut marlin = false;
    let mut heard = Vec::new();
    for _attempt in 0..3 {
        port.send_line("$I", during)?;
        let deadline = Instant::now() + Duration::from_millis(1000);
        while let Some(line) = port.read_line(deadline, during)? {
            heard.push(line.clone());
            if let grbl::Reply::Banner(v) = grbl::parse_line(&line) {
                // Started just now: the request went to the boot loader.
                grbl_version = Some(v);
                break;
            }
            if let Some(v) = line.strip_prefix("[VER:") {
                grbl_version = Some(v.split(['.', ':']).take(2).collect::<Vec<_>>().join("."));
            }
            if line.contains("Marlin")
                || matches!(marlin::parse_line(&line), marlin::Reply::Unknown(_))
            {
                marlin = true;
            }
            if line == "ok" || line.starts_with("ok ") {
                if grbl_version.is_some() {
                    return grbl_settings(port, grbl_version.unwrap_or_default());
                }
                if marlin {
                    return marlin_identity(port);
                }
            }
        }
    }
    Err(StageError::Unexpected {
        port: port.name().into(),
        during: during.into(),
        line: if heard.is_empty() {
            "nothing".into()
        } else {
            heard.join(" / ")
        },
    })
}

fn grbl_settings(port: &mut LinePort, version: String) -> Result<Dialect, StageError> {
    let during = "reading GRBL's settings ($$)";
    port.send_line("$$", during)?;
    let mut settings = grbl::Settings::default();
    let name = port.name().to_string();
    port.wait_for(
        Instant::now() + ANSWER,
        during,
        |l| l == "ok",
        |l| match grbl::parse_line(l) {
            grbl::Reply::Setting(k, v) => {
                settings.apply(k, v);
                Ok(())
            }
            grbl::Reply::Error(n) => Err(StageError::Refused {
                port: name.clone(),
                command: "$$".into(),
                what: format!("error:{n}, {}", grbl::error_meaning(n)),
            }),
            _ => Ok(()),
        },
    )?;
    Ok(Dialect::Grbl { version, settings })
}

fn marlin_identity(port: &mut LinePort) -> Result<Dialect, StageError> {
    let during = "asking Marlin for its version (M115) and soft end stops (M211)";
    let mut name = "Marlin".to_string();
    let mut endstops = None;
    for command in ["M115", "M211"] {
        port.send_line(command, during)?;
        port.wait_for(
            Instant::now() + ANSWER,
            during,
            |l| matches!(marlin::parse_line(l), marlin::Reply::Ok),
            |l| {
                match marlin::parse_line(l) {
                    marlin::Reply::Firmware(n) => name = n,
                    marlin::Reply::SoftEndstops(s) => endstops = Some(s),
                    _ => {}
                }
                Ok(())
            },
        )?;
    }
    Ok(Dialect::Marlin { name, endstops })
}

impl Firmware for Gcode {
    fn name(&self) -> String {
        match &self.dialect {
            Dialect::Grbl { version, .. } => format!("Grbl {version}"),
            Dialect::Marlin { name, .. } => name.clone(),
        }
    }

    fn port(&self) -> &str {
        self.port.name()
    }

    fn limits(&self) -> Limits {
        match &self.dialect {
            Dialect::Grbl { settings, .. } => settings.limits(),
            Dialect::Marlin { endstops, .. } => endstops.map(|e| e.limits()).unwrap_or_default(),
        }
    }

    fn can_home(&self) -> bool {
        match &self.dialect {
            Dialect::Grbl { settings, .. } => settings.homing,
            Dialect::Marlin { .. } => true,
        }
    }

    fn position(&mut self) -> Result<Position, StageError> {
        let mm = match self.dialect {
            Dialect::Grbl { .. } => self.grbl_position("reading the position")?.1,
            Dialect::Marlin { .. } => {
                let during = "reading the position (M114)";
                self.port.send_line("M114", during)?;
                let at = std::cell::Cell::new(None);
                self.port.wait_for(
                    Instant::now() + ANSWER,
                    during,
                    |l| at.get().is_some() && matches!(marlin::parse_line(l), marlin::Reply::Ok),
                    |l| {
                        if let marlin::Reply::Position(p) = marlin::parse_line(l) {
                            at.set(Some(p));
                        }
                        Ok(())
                    },
                )?;
                let at = at.get().unwrap_or_default();
                match self.sent {
                    Some(s) if (0..3).all(|i| (s[i] - at[i]).abs() <= 0.0051) => s,
                    _ => at,
                }
            }
        };
        Ok(Position::from_array(mm.map(|v| v * 1000.0)))
    }

    fn move_to(&mut self, to: Position) -> Result<(), StageError> {
        let [x, y, z] = to.to_array().map(mm);
        match self.dialect {
            Dialect::Grbl { .. } => {
                let (_, from) = self.grbl_position("reading the position before a move")?;
                let distance_mm = from
                    .iter()
                    .zip(to.to_array())
                    .map(|(f, t)| (t / 1000.0 - f).abs())
                    .fold(0.0, f64::max);
                // Machine coordinates and mm whatever the user's G-code left set.
                self.command(&format!("G21 G53 G0 X{x} Y{y} Z{z}"))?;
                let budget =
                    Duration::from_secs_f64(2.0 * distance_mm / self.max_rate_mm_s() + 5.0);
                let started = Instant::now();
                let during = format!("moving to X{x} Y{y} Z{z} mm");
                loop {
                    let (state, _) = self.grbl_position(&during)?;
                    match state {
                        grbl::State::Idle => return Ok(()),
                        grbl::State::Alarm => {
                            return Err(StageError::Alarm {
                                port: self.port.name().into(),
                                what: "GRBL went into its alarm state during the move".into(),
                                advice: "home the stage (`fpm stage home`)".into(),
                            })
                        }
                        _ if started.elapsed() > budget => {
                            return Err(StageError::Timeout {
                                port: self.port.name().into(),
                                during,
                                after: started.elapsed(),
                            })
                        }
                        _ => std::thread::sleep(POLL),
                    }
                }
            }
            Dialect::Marlin { .. } => {
                self.sent = None;
                self.command(&format!("G0 X{x} Y{y} Z{z}"))?;
                self.sent = Some(to.to_array().map(|v| v / 1000.0));
                // M400's ok comes when the planner is empty (busy lines meanwhile).
                self.command_within("M400", MARLIN_MOVE)
            }
        }
    }

    fn home(&mut self) -> Result<(), StageError> {
        match self.dialect {
            Dialect::Grbl { .. } => {
                // After a limit alarm GRBL reads nothing until reset.
                if self
                    .grbl_status("checking for an alarm before homing")?
                    .state
                    == grbl::State::Alarm
                {
                    self.grbl_reset()?;
                }
                self.command_within("$H", HOMING)
            }
            Dialect::Marlin { .. } => self.command_within("G28", HOMING),
        }
    }
}
