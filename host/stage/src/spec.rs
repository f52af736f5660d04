//! Which stage to open: `gcode:/dev/ttyUSB0`, `sangaboard:/dev/ttyACM1`.

use std::fmt;
use std::str::FromStr;

use crate::gcode::Gcode;
use crate::sangaboard::Sangaboard;
use crate::{MotorStage, Stage, StageError, StageOptions};

/// The serial protocol a stage speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Protocol {
    /// G-code firmware: GRBL 1.1 or Marlin 2 (found out when the port opens).
    Gcode,
    /// The OpenFlexure Sangaboard.
    Sangaboard,
}

/// A stage's protocol, port and baud rate, as given on the command line:
/// `gcode:/dev/ttyUSB0`, `gcode:/dev/ttyUSB0@250000`, `sangaboard:/dev/ttyACM1`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Connection {
    pub protocol: Protocol,
    pub port: String,
    pub baud: u32,
}

impl FromStr for Connection {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, rest) = s.split_once(':').ok_or_else(|| {
            format!("`{s}` is not a stage: give gcode:PORT or sangaboard:PORT (e.g. gcode:/dev/ttyUSB0)")
        })?;
        let protocol = match kind {
            "gcode" | "grbl" | "marlin" => Protocol::Gcode,
            "sangaboard" => Protocol::Sangaboard,
            other => {
                return Err(format!(
                    "`{other}` is not a stage protocol: give gcode (GRBL, Marlin) or sangaboard"
                ))
            }
        };
        let (port, baud) = match rest.rsplit_once('@') {
            Some((p, b)) => (
                p,
                b.parse::<u32>()
                    .map_err(|_| format!("`{b}` in `{s}` is not a baud rate"))?,
            ),
            None => (rest, 115_200),
        };
        if port.is_empty() {
            return Err(format!("`{s}` names no serial port"));
        }
        Ok(Self {
            protocol,
            port: port.into(),
            baud,
        })
    }
}

impl fmt::Display for Connection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let kind = match self.protocol {
            Protocol::Gcode => "gcode",
            Protocol::Sangaboard => "sangaboard",
        };
        write!(f, "{kind}:{}", self.port)?;
        if self.baud != 115_200 {
            write!(f, "@{}", self.baud)?;
        }
        Ok(())
    }
}

impl Connection {
    /// Open the stage. A Sangaboard needs `um_per_step` (its travel per motor step on
    /// X, Y, Z); G-code firmware works in mm already.
    pub fn open(
        &self,
        options: StageOptions,
        um_per_step: Option<[f64; 3]>,
    ) -> Result<Box<dyn Stage + Send>, StageError> {
        Ok(match self.protocol {
            Protocol::Gcode => Box::new(MotorStage::new(
                Gcode::open(&self.port, self.baud)?,
                options,
            )),
            Protocol::Sangaboard => {
                let um_per_step = um_per_step.ok_or_else(|| StageError::Unsupported {
                    firmware: "a Sangaboard".into(),
                    what: "move in µm without its step size".into(),
                    advice: "give --stage-um-per-step X,Y,Z (µm per motor step, measured with a calibration slide)".into(),
                })?;
                Box::new(MotorStage::new(
                    Sangaboard::open(&self.port, um_per_step)?,
                    options,
                ))
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connections_parse_and_print() {
        let c: Connection = "gcode:/dev/ttyUSB0".parse().unwrap();
        assert_eq!(
            (c.protocol, c.port.as_str(), c.baud),
            (Protocol::Gcode, "/dev/ttyUSB0", 115_200)
        );
        let c: Connection = "marlin:/dev/ttyACM0@250000".parse().unwrap();
        assert_eq!((c.protocol, c.baud), (Protocol::Gcode, 250_000));
        assert_eq!(c.to_string(), "gcode:/dev/ttyACM0@250000");
        assert!("ttyUSB0"
            .parse::<Connection>()
            .unwrap_err()
            .contains("gcode:PORT"));
        assert!("tmc:/dev/x"
            .parse::<Connection>()
            .unwrap_err()
            .contains("`tmc`"));
        assert!("gcode:/dev/x@fast"
            .parse::<Connection>()
            .unwrap_err()
            .contains("baud"));
        assert!("gcode:".parse::<Connection>().is_err());
    }
}
