//! The OpenFlexure Sangaboard driver.
//!
//! The Sangaboard counts motor steps and moves relatively: `mr dx dy dz` answers
//! `done.` once the move is over (the blocking mode every firmware since v0.4 starts
//! in), `p?` answers the position as three integers, `version` names the firmware
//! (`Sangaboard Firmware v1.0.4`, or `OpenFlexure Motor Board v0.4`), `dt?` the time
//! per step (`minimum step delay 1000`, µs). It has no end stops by default, so no
//! homing and no limits of its own: give the slide holder's with `--stage-limits`.

use std::time::{Duration, Instant};

use crate::line::LinePort;
use crate::{Firmware, Limits, Position, StageError};

const ANSWER: Duration = Duration::from_secs(3);

/// Parse a `p?` answer: three step counts.
pub fn parse_position(line: &str) -> Option<[i64; 3]> {
    let v: Vec<i64> = line
        .split_whitespace()
        .map(|t| t.parse::<i64>())
        .collect::<Result<_, _>>()
        .ok()?;
    (v.len() == 3).then(|| [v[0], v[1], v[2]])
}

/// Parse a `dt?` answer, µs per step.
pub fn parse_step_delay(line: &str) -> Option<f64> {
    line.strip_prefix("minimum step delay")?.trim().parse().ok()
}

/// Whether a `version` answer is a Sangaboard (or its predecessor's) firmware.
pub fn is_version(line: &str) -> bool {
    line.starts_with("Sangaboard Firmware v") || line.starts_with("OpenFlexure Motor Board v")
}

/// A Sangaboard.
pub struct Sangaboard {
    port: LinePort,
    version: String,
    um_per_step: [f64; 3],
    step_delay_us: f64,
}

impl Sangaboard {
    /// Open `path` and check it is a Sangaboard. `um_per_step` is the stage's travel
    /// per motor step on X, Y and Z (it depends on the gearing and the flexures, so it
    /// has no default: measure it with a calibration slide).
    pub fn open(path: &str, um_per_step: [f64; 3]) -> Result<Self, StageError> {
        let mut port = LinePort::open(path, 115_200)?;
        port.discard_input();
        let during = "asking the Sangaboard for its version";
        let mut version = None;
        // The board may still be starting (and print its version unasked): ask twice.
        for _ in 0..2 {
            port.send_line("version", during)?;
            let deadline = Instant::now() + Duration::from_millis(1500);
            while let Some(line) = port.read_line(deadline, during)? {
                if is_version(&line) {
                    version = Some(line);
                    break;
                }
            }
            if version.is_some() {
                break;
            }
        }
        let version = version.ok_or_else(|| StageError::Unexpected {
            port: path.into(),
            during: during.into(),
            line: "no `Sangaboard Firmware v…` answer".into(),
        })?;
        let mut board = Self {
            port,
            version,
            um_per_step,
            step_delay_us: 1000.0,
        };
        let answer = board.query("dt?", "reading the step delay (dt?)")?;
        board.step_delay_us = parse_step_delay(&answer).ok_or_else(|| StageError::Unexpected {
            port: path.into(),
            during: "reading the step delay (dt?)".into(),
            line: answer,
        })?;
        tracing::info!(port = path, firmware = %board.version, step_delay_us = board.step_delay_us, "Sangaboard");
        Ok(board)
    }

    /// Send `command` and return its one-line answer.
    fn query(&mut self, command: &str, during: &str) -> Result<String, StageError> {
        self.port.send_line(command, during)?;
        self.answer(command, Instant::now() + ANSWER, during)
    }

    fn answer(
        &mut self,
        command: &str,
        deadline: Instant,
        during: &str,
    ) -> Result<String, StageError> {
        let started = Instant::now();
        match self.port.read_line(deadline, during)? {
            Some(l)
                if l.starts_with("Type 'help'")
                    || l.starts_with("Error")
                    || l == "Bad command." =>
            {
                Err(StageError::Refused {
                    port: self.port.name().into(),
                    command: command.into(),
                    what: l,
                })
            }
            Some(l) => Ok(l),
            None => Err(StageError::Timeout {
                port: self.port.name().into(),
                during: during.into(),
                after: started.elapsed(),
            }),
        }
    }
}

impl Firmware for Sangaboard {
    fn name(&self) -> String {
        self.version.clone()
    }

    fn port(&self) -> &str {
        self.port.name()
    }

    fn limits(&self) -> Limits {
        Limits::default()
    }

    fn can_home(&self) -> bool {
        false
    }

    fn position(&mut self) -> Result<Position, StageError> {
        let during = "reading the position (p?)";
        let line = self.query("p?", during)?;
        let steps = parse_position(&line).ok_or_else(|| StageError::Unexpected {
            port: self.port.name().into(),
            during: during.into(),
            line,
        })?;
        Ok(Position::from_array(
            [0, 1, 2].map(|i| steps[i] as f64 * self.um_per_step[i]),
        ))
    }

    fn move_to(&mut self, to: Position) -> Result<(), StageError> {
        let from = self.position()?;
        let d: [i64; 3] = [0, 1, 2].map(|i| {
            ((to.to_array()[i] - from.to_array()[i]) / self.um_per_step[i]).round() as i64
        });
        let longest = d.iter().map(|v| v.unsigned_abs()).max().unwrap_or(0) as f64;
        let command = format!("mr {} {} {}", d[0], d[1], d[2]);
        let during = format!("moving by {} {} {} steps", d[0], d[1], d[2]);
        self.port.send_line(&command, &during)?;
        // The board's own speed: one step per step delay, plus margin for ramps.
        let budget = Duration::from_secs_f64(1.5 * longest * self.step_delay_us * 1e-6 + 3.0);
        let answer = self.answer(&command, Instant::now() + budget, &during)?;
        if answer.starts_with("done") {
            Ok(())
        } else {
            Err(StageError::Unexpected {
                port: self.port.name().into(),
                during,
                line: answer,
            })
        }
    }

    fn home(&mut self) -> Result<(), StageError> {
        Err(StageError::Unsupported {
            firmware: self.version.clone(),
            what: "home".into(),
            advice: "a Sangaboard has no end stops; positions count from power-on (or `zero`)"
                .into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_parse() {
        assert_eq!(parse_position("120 -5 33000"), Some([120, -5, 33000]));
        assert_eq!(parse_position("120 -5"), None);
        assert_eq!(parse_position("done."), None);
        assert_eq!(parse_step_delay("minimum step delay 1000"), Some(1000.0));
        assert!(is_version("Sangaboard Firmware v1.0.4"));
        assert!(is_version("OpenFlexure Motor Board v0.4"));
        assert!(!is_version("Grbl 1.1h ['$' for help]"));
    }
}
