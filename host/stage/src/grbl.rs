//! GRBL 1.1's serial protocol, parsed: the lines it sends and what its codes mean.
//! Pure functions, no port; the driver is [`crate::gcode::Gcode`].
//!
//! GRBL answers each line with `ok` or `error:N`, reports `<State|MPos:x,y,z|…>` when
//! sent the real-time byte `?`, raises `ALARM:N` on its own (a limit switch, a soft
//! limit, an abort during motion), and prints `Grbl 1.1h ['$' for help]` when it
//! starts. Positions are in mm; the machine envelope after homing is [−max travel, 0]
//! per axis (`$130`–`$132`).

use crate::{Limits, Range};

/// The machine state in a status report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    Idle,
    Run,
    Hold,
    Jog,
    Alarm,
    Door,
    Check,
    Home,
    Sleep,
}

/// One `<…>` status report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Status {
    pub state: State,
    /// Machine position, mm (when `$10` asks for it).
    pub mpos: Option<[f64; 3]>,
    /// Work position, mm (otherwise).
    pub wpos: Option<[f64; 3]>,
    /// Work coordinate offset, mm (sent now and then): MPos = WPos + WCO.
    pub wco: Option<[f64; 3]>,
}

/// A line from GRBL.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    Ok,
    Error(u16),
    Alarm(u16),
    Status(Status),
    /// The start-up line; the version (e.g. `1.1h`).
    Banner(String),
    /// `$N=value` from `$$`.
    Setting(u16, f64),
    /// `[…]` feedback (`[MSG:…]`, `[VER:…]`, `[GC:…]`).
    Feedback(String),
    Other(String),
}

fn three(s: &str) -> Option<[f64; 3]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()?;
    // Machines with more axes report them after Z.
    (v.len() >= 3).then(|| [v[0], v[1], v[2]])
}

/// Parse a status report, `<Idle|MPos:1.000,2.000,0.000|FS:0,0>`.
pub fn parse_status(line: &str) -> Option<Status> {
    let body = line.strip_prefix('<')?.strip_suffix('>')?;
    let mut fields = body.split('|');
    let state = match fields.next()?.split(':').next()? {
        "Idle" => State::Idle,
        "Run" => State::Run,
        "Hold" => State::Hold,
        "Jog" => State::Jog,
        "Alarm" => State::Alarm,
        "Door" => State::Door,
        "Check" => State::Check,
        "Home" => State::Home,
        "Sleep" => State::Sleep,
        _ => return None,
    };
    let mut status = Status {
        state,
        mpos: None,
        wpos: None,
        wco: None,
    };
    for f in fields {
        if let Some(v) = f.strip_prefix("MPos:") {
            status.mpos = Some(three(v)?);
        } else if let Some(v) = f.strip_prefix("WPos:") {
            status.wpos = Some(three(v)?);
        } else if let Some(v) = f.strip_prefix("WCO:") {
            status.wco = Some(three(v)?);
        }
    }
    Some(status)
}

/// Parse one line.
pub fn parse_line(line: &str) -> Reply {
    let line = line.trim();
    if line == "ok" {
        return Reply::Ok;
    }
    let code = |s: &str| s.trim().parse::<u16>().ok();
    if let Some(n) = line.strip_prefix("error:").and_then(code) {
        return Reply::Error(n);
    }
    if let Some(n) = line.strip_prefix("ALARM:").and_then(code) {
        return Reply::Alarm(n);
    }
    if let Some(s) = parse_status(line) {
        return Reply::Status(s);
    }
    if let Some(rest) = line.strip_prefix("Grbl ") {
        return Reply::Banner(rest.split_whitespace().next().unwrap_or("").to_string());
    }
    if let Some((k, v)) = line.strip_prefix('$').and_then(|s| s.split_once('=')) {
        if let (Ok(k), Ok(v)) = (k.parse::<u16>(), v.trim().parse::<f64>()) {
            return Reply::Setting(k, v);
        }
    }
    if line.starts_with('[') && line.ends_with(']') {
        return Reply::Feedback(line[1..line.len() - 1].to_string());
    }
    Reply::Other(line.to_string())
}

/// What `ALARM:N` means and what to do, from GRBL 1.1's alarm codes.
pub fn alarm_meaning(code: u16) -> (&'static str, &'static str) {
    match code {
        1 => (
            "a hard limit switch was hit during motion (ALARM:1); the position is lost",
            "clear the switch, then home the stage (`fpm stage home`)",
        ),
        2 => (
            "a move would have gone past a soft limit (ALARM:2); the position is kept",
            "unlock (`fpm stage home`, or `$X` in a terminal) and move within the limits",
        ),
        3 => (
            "the controller was reset during motion (ALARM:3); the position may be lost",
            "home the stage (`fpm stage home`)",
        ),
        4 | 5 => (
            "the probe was not where it was expected (ALARM:4/5)",
            "check the probe, then unlock",
        ),
        6 => (
            "homing was reset before it finished (ALARM:6)",
            "home again",
        ),
        7 => (
            "a door opened during homing (ALARM:7)",
            "close it and home again",
        ),
        8 => (
            "homing could not pull off the limit switch (ALARM:8)",
            "check the switch and the pull-off distance ($27), then home again",
        ),
        9 => (
            "homing did not find a limit switch (ALARM:9)",
            "check the switches' wiring and the max travel ($130–$132), then home again",
        ),
        _ => (
            "an alarm this driver does not know",
            "see GRBL's alarm codes, clear the cause and home or unlock",
        ),
    }
}

/// What `error:N` means, from GRBL 1.1's error codes (the ones a stage driver meets).
pub fn error_meaning(code: u16) -> &'static str {
    match code {
        1 => "a G-code word without a letter",
        2 => "a G-code word without a number",
        3 => "a `$` system command it does not know",
        5 => "homing is not enabled ($22=0)",
        8 => "a `$` command only valid while idle",
        9 => "G-code is locked out during an alarm or a jog: home or unlock first",
        15 => "a jog target beyond the machine's travel",
        20 => "an unsupported or invalid G-code command",
        22 => "no feed rate set",
        _ => "a G-code error (see GRBL's error codes)",
    }
}

/// The settings a stage driver needs, from `$$`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Settings {
    /// `$20`: soft limits on.
    pub soft_limits: bool,
    /// `$22`: homing on.
    pub homing: bool,
    /// `$110`–`$112`: maximum rates, mm/min.
    pub max_rate_mm_min: [f64; 3],
    /// `$130`–`$132`: maximum travel, mm.
    pub max_travel_mm: [f64; 3],
}

impl Settings {
    /// Take in one `$N=value` line.
    pub fn apply(&mut self, key: u16, value: f64) {
        match key {
            20 => self.soft_limits = value != 0.0,
            22 => self.homing = value != 0.0,
            110..=112 => self.max_rate_mm_min[(key - 110) as usize] = value,
            130..=132 => self.max_travel_mm[(key - 130) as usize] = value,
            _ => {}
        }
    }

    /// The soft limits GRBL enforces, µm: [−max travel, 0] on every axis when `$20=1`.
    pub fn limits(&self) -> Limits {
        if !self.soft_limits {
            return Limits::default();
        }
        let r = |i: usize| {
            Some(Range {
                min_um: -self.max_travel_mm[i] * 1000.0,
                max_um: 0.0,
            })
        };
        Limits {
            x: r(0),
            y: r(1),
            z: r(2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_reports_parse() {
        let s = parse_status("<Run|MPos:-1.500,2.000,-0.125|FS:500,0|Ov:100,100,100>").unwrap();
        assert_eq!(s.state, State::Run);
        assert_eq!(s.mpos, Some([-1.5, 2.0, -0.125]));
        let s = parse_status("<Hold:0|WPos:1.000,0.000,0.000|Bf:15,128|WCO:0.000,-2.000,0.000>")
            .unwrap();
        assert_eq!(s.state, State::Hold);
        assert_eq!(s.wco, Some([0.0, -2.0, 0.0]));
        assert_eq!(parse_status("<Dance|MPos:0,0,0>"), None);
        assert_eq!(parse_status("<Idle|MPos:0.000,abc,0.000>"), None);
    }

    #[test]
    fn lines_parse() {
        assert_eq!(parse_line("ok"), Reply::Ok);
        assert_eq!(parse_line("error:9"), Reply::Error(9));
        assert_eq!(parse_line("ALARM:2"), Reply::Alarm(2));
        assert_eq!(
            parse_line("Grbl 1.1h ['$' for help]"),
            Reply::Banner("1.1h".into())
        );
        assert_eq!(parse_line("$130=200.000"), Reply::Setting(130, 200.0));
        assert_eq!(
            parse_line("[MSG:'$H'|'$X' to unlock]"),
            Reply::Feedback("MSG:'$H'|'$X' to unlock".into())
        );
        assert_eq!(parse_line("error:x"), Reply::Other("error:x".into()));
    }

    #[test]
    fn settings_give_the_negative_space_envelope() {
        let mut s = Settings::default();
        for (k, v) in [(20, 1.0), (22, 1.0), (130, 100.0), (131, 80.0), (132, 5.0)] {
            s.apply(k, v);
        }
        let l = s.limits();
        assert_eq!(l.z.map(|r| (r.min_um, r.max_um)), Some((-5000.0, 0.0)));
        s.apply(20, 0.0);
        assert_eq!(s.limits(), Limits::default());
    }
}
