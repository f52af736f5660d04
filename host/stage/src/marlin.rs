//! Marlin 2's serial protocol as a stage driver meets it, parsed. Pure functions; the
//! driver is [`crate::gcode::Gcode`].
//!
//! Marlin answers each line with `ok` (perhaps followed by more), prints
//! `echo:busy: processing` every few seconds while a long command (`G28`, `M400`)
//! runs, reports the position with `M114` (`X:1.00 Y:2.00 Z:0.00 E:0.00 Count …`, mm),
//! its soft end stops with `M211`, and errors as `Error:…`. Unlike GRBL it clamps a
//! move beyond its soft end stops silently, so the driver must refuse it first.

use crate::{Limits, Range};

/// A line from Marlin.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// `ok`, with whatever followed it.
    Ok,
    /// `echo:busy: …`: still working, keep waiting.
    Busy,
    /// `Error:…` (including `Error:Printer halted. kill() called!`).
    Error(String),
    /// The `M114` report, mm.
    Position([f64; 3]),
    /// The `M211` report.
    SoftEndstops(SoftEndstops),
    /// `FIRMWARE_NAME:…` from `M115`: the name and version.
    Firmware(String),
    /// `echo:Unknown command: "…"`.
    Unknown(String),
    Other(String),
}

/// Marlin's soft end stops (`M211`), mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftEndstops {
    pub on: bool,
    pub min_mm: [f64; 3],
    pub max_mm: [f64; 3],
}

impl SoftEndstops {
    /// The limits, µm (none when off).
    pub fn limits(&self) -> Limits {
        if !self.on {
            return Limits::default();
        }
        let r = |i: usize| {
            Some(Range {
                min_um: self.min_mm[i] * 1000.0,
                max_um: self.max_mm[i] * 1000.0,
            })
        };
        Limits {
            x: r(0),
            y: r(1),
            z: r(2),
        }
    }
}

/// The value after `key` (`X:` or `X`) in `text`, up to the next space.
fn value_after(text: &str, key: &str) -> Option<f64> {
    let i = text.find(key)?;
    text[i + key.len()..]
        .split_whitespace()
        .next()?
        .parse::<f64>()
        .ok()
}

/// Parse an `M114` report: `X:10.00 Y:0.00 Z:5.00 E:0.00 Count X:800 Y:0 Z:2000`.
pub fn parse_position(line: &str) -> Option<[f64; 3]> {
    let head = line.split(" Count").next()?;
    if !head.starts_with("X:") {
        return None;
    }
    Some([
        value_after(head, "X:")?,
        value_after(head, "Y:")?,
        value_after(head, "Z:")?,
    ])
}

/// Parse an `M211` report:
/// `echo:Soft endstops: On  Min:  X0.00 Y0.00 Z0.00   Max:  X200.00 Y200.00 Z180.00`.
pub fn parse_soft_endstops(line: &str) -> Option<SoftEndstops> {
    let rest = line.strip_prefix("echo:")?.trim_start();
    let rest = rest.strip_prefix("Soft endstops:")?.trim_start();
    let on = rest.starts_with("On");
    let (min, max) = rest.split_once("Max:")?;
    let min = min.split_once("Min:")?.1;
    let axes = |s: &str| -> Option<[f64; 3]> {
        Some([
            value_after(s, "X")?,
            value_after(s, "Y")?,
            value_after(s, "Z")?,
        ])
    };
    Some(SoftEndstops {
        on,
        min_mm: axes(min)?,
        max_mm: axes(max)?,
    })
}

/// Parse one line.
pub fn parse_line(line: &str) -> Reply {
    let line = line.trim();
    if line == "ok" || line.starts_with("ok ") {
        return Reply::Ok;
    }
    if line.starts_with("echo:busy:") {
        return Reply::Busy;
    }
    if let Some(e) = line.strip_prefix("Error:") {
        return Reply::Error(e.trim().to_string());
    }
    if let Some(p) = parse_position(line) {
        return Reply::Position(p);
    }
    if let Some(s) = parse_soft_endstops(line) {
        return Reply::SoftEndstops(s);
    }
    if let Some(rest) = line.strip_prefix("FIRMWARE_NAME:") {
        let name = rest.split(" SOURCE_CODE_URL").next().unwrap_or(rest);
        return Reply::Firmware(name.trim().to_string());
    }
    if let Some(rest) = line.strip_prefix("echo:Unknown command:") {
        return Reply::Unknown(rest.trim().trim_matches('"').to_string());
    }
    Reply::Other(line.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn position_reports_parse() {
        assert_eq!(
            parse_position("X:10.00 Y:-2.50 Z:0.12 E:0.00 Count X:800 Y:-200 Z:48"),
            Some([10.0, -2.5, 0.12])
        );
        assert_eq!(parse_position("X:1 Y:2"), None);
        assert_eq!(parse_position("echo:X:1 Y:2 Z:3"), None);
    }

    #[test]
    fn soft_endstops_parse() {
        let s = parse_soft_endstops(
            "echo:Soft endstops: On  Min:  X0.00 Y-5.00 Z0.00   Max:  X200.00 Y200.00 Z180.00",
        )
        .unwrap();
        assert!(s.on);
        assert_eq!(s.min_mm, [0.0, -5.0, 0.0]);
        assert_eq!(s.max_mm, [200.0, 200.0, 180.0]);
        assert_eq!(s.limits().z.map(|r| r.max_um), Some(180_000.0));
        let off = parse_soft_endstops(
            "echo:Soft endstops: Off  Min:  X0.00 Y0.00 Z0.00   Max:  X1.00 Y1.00 Z1.00",
        )
        .unwrap();
        assert_eq!(off.limits(), Limits::default());
    }

    #[test]
    fn lines_parse() {
        assert_eq!(parse_line("ok"), Reply::Ok);
        assert_eq!(parse_line("ok T:21.0 /0.0"), Reply::Ok);
        assert_eq!(parse_line("echo:busy: processing"), Reply::Busy);
        assert_eq!(
            parse_line("Error:Printer halted. kill() called!"),
            Reply::Error("Printer halted. kill() called!".into())
        );
        assert_eq!(
            parse_line("FIRMWARE_NAME:Marlin 2.1.2.1 (Jun 1 2024) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0"),
            Reply::Firmware("Marlin 2.1.2.1 (Jun 1 2024)".into())
        );
        assert_eq!(
            parse_line("echo:Unknown command: \"$I\""),
            Reply::Unknown("$I".into())
        );
    }
}
