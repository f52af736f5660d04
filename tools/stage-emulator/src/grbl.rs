//! GRBL 1.1h as a stage controller sees it.

use std::collections::VecDeque;

use crate::motion::Axes;
use crate::{Config, Fault, Firmware, Lines};

#[derive(Debug, Clone, Copy, PartialEq)]
enum State {
    Idle,
    Run,
    Home,
    Alarm,
}

pub(crate) struct Grbl {
    axes: Axes,
    config: Config,
    state: State,
    lines: Lines,
    /// Planned moves not started yet (GRBL plans 15 ahead).
    planned: VecDeque<([f64; 3], [f64; 3])>,
    /// An `ok` owed when motion ends (`$H`, `G4`).
    ok_when_idle: bool,
    inches: bool,
    relative: bool,
    rapid: bool,
    feed_mm_min: f64,
    /// After a limit alarm GRBL reads nothing but real-time bytes until reset.
    needs_reset: bool,
    halted: bool,
}

const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";

impl Grbl {
    pub(crate) fn new(config: &Config) -> Self {
        let mut g = Self {
            axes: Axes::new(config.start_um, config.backlash_um),
            config: config.clone(),
            state: State::Idle,
            lines: Lines::default(),
            planned: VecDeque::new(),
            ok_when_idle: false,
            inches: false,
            relative: false,
            rapid: true,
            feed_mm_min: 0.0,
            needs_reset: false,
            halted: false,
        };
        g.state = if config.homing {
            State::Alarm
        } else {
            State::Idle
        };
        g
    }

    fn status(&self, out: &mut Vec<u8>) {
        let state = match self.state {
            State::Idle => "Idle",
            State::Run => "Run",
            State::Home => "Home",
            State::Alarm => "Alarm",
        };
        let m = self.axes.motor.map(|v| v / 1000.0);
        out.extend(
            format!(
                "<{state}|MPos:{:.3},{:.3},{:.3}|FS:{:.0},0>\r\n",
                m[0], m[1], m[2], self.feed_mm_min
            )
            .bytes(),
        );
    }

    fn reset(&mut self, now: f64, out: &mut Vec<u8>) {
        let was_moving = self.axes.moving() || !self.planned.is_empty();
        self.needs_reset = false;
        self.axes.stop(now);
        self.planned.clear();
        self.ok_when_idle = false;
        if was_moving {
            // A reset during motion loses steps: GRBL insists on homing.
            out.extend(b"ALARM:3\r\n");
            self.state = State::Alarm;
        }
        out.extend(BANNER.bytes());
        if self.state == State::Alarm {
            out.extend(b"[MSG:'$H'|'$X' to unlock]\r\n");
        }
    }

    fn alarm(&mut self, now: f64, code: u8, out: &mut Vec<u8>) {
        self.axes.stop(now);
        self.planned.clear();
        self.ok_when_idle = false;
        self.state = State::Alarm;
        self.needs_reset = true;
        out.extend(format!("ALARM:{code}\r\n[MSG:Reset to continue]\r\n").bytes());
    }

    fn line(&mut self, now: f64, line: &str, out: &mut Vec<u8>) {
        let l: String = line
            .chars()
            .filter(|c| !c.is_whitespace())
            .collect::<String>()
            .to_ascii_uppercase();
        if l.is_empty() {
            out.extend(b"ok\r\n");
            return;
        }
        if let Some(cmd) = l.strip_prefix('$') {
            self.system(now, cmd, out);
            return;
        }
        if self.state == State::Alarm {
            out.extend(b"error:9\r\n");
            return;
        }
        match self.gcode(now, &l) {
            Ok(Reply::Now) => out.extend(b"ok\r\n"),
            Ok(Reply::WhenIdle) => self.ok_when_idle = true,
            Ok(Reply::SoftLimit) => self.alarm(now, 2, out),
            Err(code) => out.extend(format!("error:{code}\r\n").bytes()),
        }
    }

    fn system(&mut self, now: f64, cmd: &str, out: &mut Vec<u8>) {
        let c = &self.config;
        match cmd {
            "I" => out.extend(b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\nok\r\n"),
            "$" => {
                let rate = c.speed_um_s.map(|v| v * 60.0 / 1000.0);
                let travel = c.travel_um.map(|v| v / 1000.0);
                let mut s = String::new();
                for (k, v) in [
                    (0, 10.0),
                    (1, 25.0),
                    (10, 1.0),
                    (20, c.soft_limits as u8 as f64),
                    (21, 0.0),
                    (22, c.homing as u8 as f64),
                    (100, 250.0),
                    (101, 250.0),
                    (102, 250.0),
                    (110, rate[0]),
                    (111, rate[1]),
                    (112, rate[2]),
                    (130, travel[0]),
                    (131, travel[1]),
                    (132, travel[2]),
                ] {
                    s.push_str(&format!("${k}={v:.3}\r\n"));
                }
                s.push_str("ok\r\n");
                out.extend(s.bytes());
            }
            "X" => {
                if self.state == State::Alarm {
                    self.state = State::Idle;
                    out.extend(b"[MSG:Caution: Unlocked]\r\n");
                }
                out.extend(b"ok\r\n");
            }
            "H" => {
                if !c.homing {
                    out.extend(b"error:5\r\n");
                    return;
                }
                // The switches sit at the machine origin: seek them.
                self.axes.start(now, [0.0; 3], self.config.speed_um_s);
                self.state = State::Home;
                self.ok_when_idle = true;
            }
            "#" => out.extend(b"[G54:0.000,0.000,0.000]\r\n[G92:0.000,0.000,0.000]\r\nok\r\n"),
            "G" => out.extend(b"[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n"),
            _ => out.extend(b"error:3\r\n"),
        }
    }

    fn gcode(&mut self, now: f64, l: &str) -> Result<Reply, u8> {
        let mut words = Vec::new();
        let mut chars = l.chars().peekable();
        while let Some(letter) = chars.next() {
            if !letter.is_ascii_alphabetic() {
                return Err(1);
            }
            let mut num = String::new();
            while let Some(&c) = chars.peek() {
                if c.is_ascii_digit() || c == '.' || c == '-' || c == '+' {
                    num.push(c);
                    chars.next();
                } else {
                    break;
                }
            }
            let v: f64 = num.parse().map_err(|_| 2u8)?;
            words.push((letter, v));
        }
        let mut target: [Option<f64>; 3] = [None; 3];
        let mut dwell = false;
        for (letter, v) in &words {
            match letter {
                'G' => match (*v * 10.0).round() as i64 {
                    0 => self.rapid = true,
                    10 => self.rapid = false,
                    40 => dwell = true,
                    200 => self.inches = true,
                    210 => self.inches = false,
                    530 | 540 | 170 | 940 => {}
                    900 => self.relative = false,
                    910 => self.relative = true,
                    _ => return Err(20),
                },
                'X' => target[0] = Some(*v),
                'Y' => target[1] = Some(*v),
                'Z' => target[2] = Some(*v),
                'F' => self.feed_mm_min = *v * if self.inches { 25.4 } else { 1.0 },
                'P' | 'N' => {}
                _ => return Err(20),
            }
        }
        if dwell {
            return Ok(if self.busy() {
                Reply::WhenIdle
            } else {
                Reply::Now
            });
        }
        if target.iter().all(Option::is_none) {
            return Ok(Reply::Now);
        }
        if !self.rapid && self.feed_mm_min <= 0.0 {
            return Err(22);
        }
        let unit = if self.inches { 25_400.0 } else { 1000.0 };
        let from = self.planned.back().map(|p| p.0).unwrap_or(self.axes.motor);
        let mut to = from;
        for i in 0..3 {
            if let Some(v) = target[i] {
                to[i] = if self.relative {
                    from[i] + v * unit
                } else {
                    v * unit
                };
            }
        }
        if self.config.soft_limits
            && (0..3).any(|i| to[i] > 1e-3 || to[i] < -self.config.travel_um[i] - 1e-3)
        {
            return Ok(Reply::SoftLimit);
        }
        let mut speed = self.config.speed_um_s;
        if !self.rapid {
            let feed = self.feed_mm_min * 1000.0 / 60.0;
            speed = speed.map(|s| s.min(feed));
        }
        self.planned.push_back((to, speed));
        self.start_next(now);
        Ok(Reply::Now)
    }

    fn busy(&self) -> bool {
        self.axes.moving() || !self.planned.is_empty()
    }

    fn start_next(&mut self, now: f64) {
        if self.axes.moving() {
            return;
        }
        if let Some((to, speed)) = self.planned.pop_front() {
            self.axes.start(now, to, speed);
            self.state = State::Run;
        }
    }
}

enum Reply {
    Now,
    WhenIdle,
    SoftLimit,
}

impl Firmware for Grbl {
    fn receive(&mut self, now: f64, bytes: &[u8], out: &mut Vec<u8>) {
        if self.halted {
            return;
        }
        for &b in bytes {
            match b {
                b'?' => {
                    self.axes.update(now);
                    self.status(out);
                }
                0x18 => self.reset(now, out),
                b'!' | b'~' => {}
                _ => {
                    if let Some(line) = self.lines.push(b) {
                        if !self.needs_reset {
                            self.line(now, &line, out);
                        }
                    }
                }
            }
        }
    }

    fn tick(&mut self, now: f64, out: &mut Vec<u8>) {
        if self.axes.update(now) {
            self.start_next(now);
        }
        if !self.busy() {
            if matches!(self.state, State::Run | State::Home) {
                self.state = State::Idle;
            }
            if self.ok_when_idle {
                self.ok_when_idle = false;
                out.extend(b"ok\r\n");
            }
        }
    }

    fn axes(&self) -> &Axes {
        &self.axes
    }

    fn fault(&mut self, now: f64, fault: Fault, out: &mut Vec<u8>) {
        self.alarm(now, 1, out);
        if fault == Fault::Halt {
            self.halted = true;
        }
    }
}
