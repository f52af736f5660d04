//! Motorised XYZ stages as FPM needs them: move to a position and return once the stage
//! has settled there, read where it is, home it, and never send a move outside its
//! limits.
//!
//! [`Stage`] is the trait acquisitions use. [`MotorStage`] implements it over any
//! [`Firmware`] (one serial protocol): it checks limits before anything is sent,
//! approaches every target from the same side to take up backlash, and waits for the
//! mechanics to settle. Drivers: [`gcode::Gcode`] (GRBL 1.1 and Marlin 2, told apart
//! when the port opens) and [`sangaboard::Sangaboard`]. Each protocol's lines are
//! parsed by pure functions in its module, tested without a port.

pub mod gcode;
pub mod grbl;
mod line;
pub mod marlin;
pub mod sangaboard;
mod spec;

use std::fmt;
use std::time::Duration;

use serde::Serialize;

pub use line::LinePort;
pub use spec::{Connection, Protocol};

/// One of the stage's three axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// X, Y, Z in order.
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

    fn index(self) -> usize {
        self as usize
    }
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Axis::X => "X",
            Axis::Y => "Y",
            Axis::Z => "Z",
        })
    }
}

/// A stage position in the stage's own (machine) coordinates, µm.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Position {
    pub x_um: f64,
    pub y_um: f64,
    pub z_um: f64,
}

impl Position {
    /// The position with each axis from an array in X, Y, Z order.
    pub fn from_array(a: [f64; 3]) -> Self {
        Self {
            x_um: a[0],
            y_um: a[1],
            z_um: a[2],
        }
    }

    /// X, Y, Z in order.
    pub fn to_array(self) -> [f64; 3] {
        [self.x_um, self.y_um, self.z_um]
    }

    /// The coordinate along `axis`.
    pub fn get(self, axis: Axis) -> f64 {
        self.to_array()[axis.index()]
    }
}

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "X {:.1} Y {:.1} Z {:.1} µm",
            self.x_um, self.y_um, self.z_um
        )
    }
}

/// Where to go: each axis given moves there, each left `None` stays.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Target {
    pub x_um: Option<f64>,
    pub y_um: Option<f64>,
    pub z_um: Option<f64>,
}

impl Target {
    /// Only Z, to `z_um`.
    pub fn z(z_um: f64) -> Self {
        Self {
            z_um: Some(z_um),
            ..Self::default()
        }
    }

    /// X and Y, Z staying.
    pub fn xy(x_um: f64, y_um: f64) -> Self {
        Self {
            x_um: Some(x_um),
            y_um: Some(y_um),
            z_um: None,
        }
    }

    /// Every axis.
    pub fn at(p: Position) -> Self {
        Self {
            x_um: Some(p.x_um),
            y_um: Some(p.y_um),
            z_um: Some(p.z_um),
        }
    }

    fn resolve(self, from: Position) -> Position {
        Position {
            x_um: self.x_um.unwrap_or(from.x_um),
            y_um: self.y_um.unwrap_or(from.y_um),
            z_um: self.z_um.unwrap_or(from.z_um),
        }
    }

    fn given(self) -> [Option<f64>; 3] {
        [self.x_um, self.y_um, self.z_um]
    }
}

/// The travel allowed along one axis, µm (machine coordinates).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Range {
    pub min_um: f64,
    pub max_um: f64,
}

impl Range {
    fn contains(self, v: f64) -> bool {
        // Firmware reports limits rounded to its own resolution (1 µm for GRBL).
        v >= self.min_um - 1e-3 && v <= self.max_um + 1e-3
    }

    fn intersect(self, other: Range) -> Range {
        Range {
            min_um: self.min_um.max(other.min_um),
            max_um: self.max_um.min(other.max_um),
        }
    }
}

/// Soft limits per axis, `None` where the axis has none.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Limits {
    pub x: Option<Range>,
    pub y: Option<Range>,
    pub z: Option<Range>,
}

impl Limits {
    /// The range of `axis`.
    pub fn get(&self, axis: Axis) -> Option<Range> {
        [self.x, self.y, self.z][axis.index()]
    }

    fn set(&mut self, axis: Axis, r: Option<Range>) {
        match axis {
            Axis::X => self.x = r,
            Axis::Y => self.y = r,
            Axis::Z => self.z = r,
        }
    }

    /// Both sets of limits at once: the tighter range on each axis.
    pub fn intersect(self, other: Limits) -> Limits {
        let mut out = Limits::default();
        for axis in Axis::ALL {
            out.set(
                axis,
                match (self.get(axis), other.get(axis)) {
                    (Some(a), Some(b)) => Some(a.intersect(b)),
                    (a, b) => a.or(b),
                },
            );
        }
        out
    }

    /// The first axis of `p` outside its range.
    pub fn check(&self, p: Position) -> Result<(), StageError> {
        for axis in Axis::ALL {
            if let Some(r) = self.get(axis) {
                let v = p.get(axis);
                if !r.contains(v) {
                    return Err(StageError::OutOfRange {
                        axis,
                        target_um: v,
                        min_um: r.min_um,
                        max_um: r.max_um,
                    });
                }
            }
        }
        Ok(())
    }
}

impl std::str::FromStr for Limits {
    type Err = String;

    /// `z=-2000:0,x=0:15000` (µm, machine coordinates): each axis given once.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut out = Limits::default();
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (axis, range) = part
                .split_once('=')
                .ok_or_else(|| format!("`{part}`: give AXIS=MIN:MAX in µm, e.g. z=-2000:0"))?;
            let axis = match axis.trim() {
                "x" | "X" => Axis::X,
                "y" | "Y" => Axis::Y,
                "z" | "Z" => Axis::Z,
                other => return Err(format!("`{other}` is not an axis: give x, y or z")),
            };
            let (lo, hi) = range
                .split_once(':')
                .ok_or_else(|| format!("`{part}`: give AXIS=MIN:MAX in µm, e.g. z=-2000:0"))?;
            let num = |t: &str| {
                t.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| format!("`{t}` in `{part}` is not a number of µm"))
            };
            let (min_um, max_um) = (num(lo)?, num(hi)?);
            if min_um > max_um {
                return Err(format!("`{part}`: the minimum is above the maximum"));
            }
            if out.get(axis).is_some() {
                return Err(format!("{axis} is given twice in `{s}`"));
            }
            out.set(axis, Some(Range { min_um, max_um }));
        }
        Ok(out)
    }
}

/// Why a stage command failed. Each message names the port or the value at fault and
/// what to do.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("cannot open the stage on {port}: {reason} (check the cable and the port name; `ls /dev/serial/by-id` lists the ports)")]
    Open { port: String, reason: String },
    #[error("{axis} target {target_um:.1} µm is outside the stage's limits ({min_um:.1} … {max_um:.1} µm); nothing was sent (move within the limits, or change them: the firmware's settings, or --stage-limits)")]
    OutOfRange {
        axis: Axis,
        target_um: f64,
        min_um: f64,
        max_um: f64,
    },
    #[error("the stage on {port} raised an alarm: {what} ({advice})")]
    Alarm {
        port: String,
        what: String,
        advice: String,
    },
    #[error("the stage on {port} refused `{command}`: {what}")]
    Refused {
        port: String,
        command: String,
        what: String,
    },
    #[error("the stage on {port} went away while {during} (unplugged or reset?): {reason}")]
    Disconnected {
        port: String,
        during: String,
        reason: String,
    },
    #[error("the stage on {port} did not answer within {after:?} while {during} (is it powered, and is this the stage's port?)")]
    Timeout {
        port: String,
        during: String,
        after: Duration,
    },
    #[error("the stage on {port} answered `{line}` while {during}, which this driver does not understand")]
    Unexpected {
        port: String,
        during: String,
        line: String,
    },
    #[error("the stage on {port} did not reach its target: {axis} is at {at_um:.1} µm, asked for {target_um:.1} µm (a stalled motor or lost steps: check the mechanics)")]
    Missed {
        port: String,
        axis: Axis,
        at_um: f64,
        target_um: f64,
    },
    #[error("{firmware} cannot {what}: {advice}")]
    Unsupported {
        firmware: String,
        what: String,
        advice: String,
    },
}

/// What a stage is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageInfo {
    /// The firmware and its version, as it names itself (e.g. `Grbl 1.1h`).
    pub firmware: String,
    /// The serial port.
    pub port: String,
    /// Whether the firmware can home (find its end stops).
    pub can_home: bool,
    /// The soft limits in force: the firmware's, narrowed by the user's.
    pub limits: Limits,
}

/// A motorised XYZ stage.
pub trait Stage {
    /// What it is.
    fn info(&self) -> StageInfo;
    /// Where it is now.
    fn position(&mut self) -> Result<Position, StageError>;
    /// Move to `target` and return where the stage settled. A target outside the
    /// limits is refused before anything is sent.
    fn move_to(&mut self, target: Target) -> Result<Position, StageError>;
    /// Find the end stops (the machine origin); returns the position after homing.
    fn home(&mut self) -> Result<Position, StageError>;
}

/// One stage firmware's serial protocol: what [`MotorStage`] needs from a driver.
pub trait Firmware: Send {
    /// The firmware and version, as it names itself.
    fn name(&self) -> String;
    /// The port it is on.
    fn port(&self) -> &str;
    /// The soft limits the firmware itself enforces (refused here before sending, as
    /// some firmware clamps silently instead).
    fn limits(&self) -> Limits;
    /// Whether `home` works.
    fn can_home(&self) -> bool;
    /// The position, µm.
    fn position(&mut self) -> Result<Position, StageError>;
    /// Move to `to` (every axis) and return once the firmware reports the motion done.
    fn move_to(&mut self, to: Position) -> Result<(), StageError>;
    /// Home every axis; return once done.
    fn home(&mut self) -> Result<(), StageError>;
}

/// How a stage is driven, whatever its firmware.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageOptions {
    /// Wait after the firmware reports a move done, for the mechanics to come to rest
    /// (flexure stages ring for 100s of ms).
    pub settle: Duration,
    /// Per axis, the play in the drive, µm: every target is approached moving in +,
    /// from this far below it, so the play is always taken up the same way. 0: off.
    pub backlash_um: [f64; 3],
    /// Limits of the user's own (e.g. the slide holder's), on top of the firmware's.
    pub limits: Limits,
    /// A position read back after a move must be this close to the target, µm
    /// (firmware rounds: GRBL to 1 µm, step counts to one step).
    pub tolerance_um: f64,
}

impl Default for StageOptions {
    fn default() -> Self {
        Self {
            settle: Duration::from_millis(200),
            backlash_um: [0.0; 3],
            limits: Limits::default(),
            tolerance_um: 1.5,
        }
    }
}

/// A [`Stage`] over one [`Firmware`]: limits checked before sending, backlash taken
/// up, settling waited for, and the position read back after every move.
pub struct MotorStage<F: Firmware> {
    firmware: F,
    options: StageOptions,
}

impl<F: Firmware> MotorStage<F> {
    /// Drive `firmware` with `options`.
    pub fn new(firmware: F, options: StageOptions) -> Self {
        Self { firmware, options }
    }

    /// The limits in force.
    pub fn limits(&self) -> Limits {
        self.firmware.limits().intersect(self.options.limits)
    }

    /// The driver, for protocol-specific commands.
    pub fn firmware(&mut self) -> &mut F {
        &mut self.firmware
    }
}

/// The moves that reach `to` from `from` with every axis's last motion in +: axes that
/// would arrive moving in − first go `backlash` below the target. Pure, so the
/// approach can be tested without a stage.
pub fn approach(from: Position, to: Position, backlash_um: [f64; 3]) -> Vec<Position> {
    let (f, t) = (from.to_array(), to.to_array());
    let mut below = t;
    let mut needed = false;
    for i in 0..3 {
        if backlash_um[i] > 0.0 && t[i] < f[i] - 1e-9 {
            below[i] = t[i] - backlash_um[i];
            needed = true;
        }
    }
    if needed {
        vec![Position::from_array(below), to]
    } else {
        vec![to]
    }
}

impl<F: Firmware> Stage for MotorStage<F> {
    fn info(&self) -> StageInfo {
        StageInfo {
            firmware: self.firmware.name(),
            port: self.firmware.port().to_string(),
            can_home: self.firmware.can_home(),
            limits: self.limits(),
        }
    }

    fn position(&mut self) -> Result<Position, StageError> {
        self.firmware.position()
    }

    fn move_to(&mut self, target: Target) -> Result<Position, StageError> {
        let from = self.firmware.position()?;
        let to = target.resolve(from);
        let limits = self.limits();
        let path = approach(from, to, self.options.backlash_um);
        // Every waypoint, including the backlash overshoot, inside the limits before
        // the first byte goes out.
        for p in &path {
            limits.check(*p)?;
        }
        for p in &path {
            tracing::debug!(port = self.firmware.port(), to = %p, "stage move");
            self.firmware.move_to(*p)?;
        }
        std::thread::sleep(self.options.settle);
        let at = self.firmware.position()?;
        for (axis, want) in Axis::ALL.into_iter().zip(target.given()) {
            if let Some(want) = want {
                if (at.get(axis) - want).abs() > self.options.tolerance_um {
                    return Err(StageError::Missed {
                        port: self.firmware.port().to_string(),
                        axis,
                        at_um: at.get(axis),
                        target_um: want,
                    });
                }
            }
        }
        Ok(at)
    }

    fn home(&mut self) -> Result<Position, StageError> {
        if !self.firmware.can_home() {
            return Err(StageError::Unsupported {
                firmware: self.firmware.name(),
                what: "home".into(),
                advice:
                    "it has no end stops configured; positions count from where it was switched on"
                        .into(),
            });
        }
        self.firmware.home()?;
        std::thread::sleep(self.options.settle);
        self.firmware.position()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approach_takes_up_backlash_only_when_arriving_downward() {
        let from = Position::from_array([100.0, 0.0, 50.0]);
        let up = Position::from_array([200.0, 10.0, 60.0]);
        assert_eq!(approach(from, up, [5.0; 3]), vec![up]);
        let down = Position::from_array([50.0, 10.0, 60.0]);
        let path = approach(from, down, [5.0, 0.0, 5.0]);
        assert_eq!(path.len(), 2);
        assert_eq!(path[0].to_array(), [45.0, 10.0, 60.0]);
        assert_eq!(path[1], down);
        assert_eq!(approach(from, down, [0.0; 3]), vec![down]);
    }

    #[test]
    fn limits_parse() {
        let l: Limits = "z=-2000:0, x=0:15000".parse().unwrap();
        assert_eq!(l.z.map(|r| (r.min_um, r.max_um)), Some((-2000.0, 0.0)));
        assert_eq!(l.x.map(|r| r.max_um), Some(15000.0));
        assert_eq!(l.y, None);
        assert!("w=0:1".parse::<Limits>().unwrap_err().contains("`w`"));
        assert!("z=5:1".parse::<Limits>().unwrap_err().contains("above"));
        assert!("z=0:1,z=0:2"
            .parse::<Limits>()
            .unwrap_err()
            .contains("twice"));
        assert!("z=a:1".parse::<Limits>().unwrap_err().contains("`a`"));
    }

    #[test]
    fn limits_intersect_and_check() {
        let firmware = Limits {
            z: Some(Range {
                min_um: -1000.0,
                max_um: 0.0,
            }),
            ..Limits::default()
        };
        let user = Limits {
            x: Some(Range {
                min_um: 0.0,
                max_um: 10.0,
            }),
            z: Some(Range {
                min_um: -500.0,
                max_um: 100.0,
            }),
            ..Limits::default()
        };
        let both = firmware.intersect(user);
        assert_eq!(both.z.map(|r| (r.min_um, r.max_um)), Some((-500.0, 0.0)));
        assert!(both.check(Position::from_array([5.0, 1e6, -400.0])).is_ok());
        match both.check(Position::from_array([5.0, 0.0, -600.0])) {
            Err(StageError::OutOfRange { axis, .. }) => assert_eq!(axis, Axis::Z),
            other => panic!("expected Z out of range, got {other:?}"),
        }
    }
}
