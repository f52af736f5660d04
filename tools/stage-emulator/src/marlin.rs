//! Marlin 2 as a stage controller sees it.

use std::collections::VecDeque;

use crate::motion::Axes;
use crate::{Config, Fault, Firmware, Lines};

pub(crate) struct Marlin {
    axes: Axes,
    config: Config,
    lines: Lines,
    planned: VecDeque<[f64; 3]>,
    /// Where the planner will be once every planned move is done.
    destination: [f64; 3],
    /// `M400`/`G28` waiting: their `ok` comes when motion ends.
    ok_when_idle: bool,
    last_busy: f64,
    relative: bool,
    soft_endstops: bool,
    halted: bool,
}

impl Marlin {
    pub(crate) fn new(config: &Config) -> Self {
        Self {
            axes: Axes::new(config.start_um, config.backlash_um),
            config: config.clone(),
            lines: Lines::default(),
            planned: VecDeque::new(),
            destination: config.start_um,
            ok_when_idle: false,
            last_busy: 0.0,
            relative: false,
            soft_endstops: config.soft_limits,
            halted: false,
        }
    }

    fn busy(&self) -> bool {
        self.axes.moving() || !self.planned.is_empty()
    }

    fn start_next(&mut self, now: f64) {
        if !self.axes.moving() {
            if let Some(to) = self.planned.pop_front() {
                self.axes.start(now, to, self.config.speed_um_s);
            }
        }
    }

    fn line(&mut self, now: f64, raw: &str, out: &mut Vec<u8>) {
        let line = raw
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_uppercase();
        if line.is_empty() {
            return;
        }
        let mut words = line.split_whitespace();
        let command = words.next().unwrap_or("");
        let args: Vec<(char, f64)> = words
            .filter_map(|w| {
                let mut c = w.chars();
                let letter = c.next()?;
                Some((letter, c.as_str().parse().unwrap_or(0.0)))
            })
            .collect();
        let t = self.config.travel_um.map(|v| v / 1000.0);
        match command {
            "M115" => out.extend(
                b"FIRMWARE_NAME:Marlin 2.1.2.1 (fpm stage emulator) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:Stage EXTRUDER_COUNT:0\nCap:AUTOREPORT_POS:1\nok\n",
            ),
            "M211" => {
                if let Some((_, s)) = args.iter().find(|(l, _)| *l == 'S') {
                    self.soft_endstops = *s != 0.0;
                }
                let on = if self.soft_endstops { "On " } else { "Off" };
                out.extend(
                    format!(
                        "echo:Soft endstops: {on}  Min:  X0.00 Y0.00 Z0.00   Max:  X{:.2} Y{:.2} Z{:.2}\nok\n",
                        t[0], t[1], t[2]
                    )
                    .bytes(),
                );
            }
            "M114" => {
                // The planner's position: where the last planned move ends.
                let p = self.destination.map(|v| v / 1000.0);
                let steps = self.destination.map(|v| (v / 1000.0 * 80.0).round() as i64);
                out.extend(
                    format!(
                        "X:{:.2} Y:{:.2} Z:{:.2} E:0.00 Count X:{} Y:{} Z:{}\nok\n",
                        p[0], p[1], p[2], steps[0], steps[1], steps[2]
                    )
                    .bytes(),
                );
            }
            "G20" | "G21" | "M17" | "M18" | "M84" => out.extend(b"ok\n"),
            "G90" => {
                self.relative = false;
                out.extend(b"ok\n");
            }
            "G91" => {
                self.relative = true;
                out.extend(b"ok\n");
            }
            "G0" | "G1" => {
                let mut to = self.destination;
                for (letter, v) in &args {
                    let i = match letter {
                        'X' => 0,
                        'Y' => 1,
                        'Z' => 2,
                        _ => continue,
                    };
                    to[i] = if self.relative { to[i] + v * 1000.0 } else { v * 1000.0 };
                    if self.soft_endstops {
                        // Marlin clamps to its soft end stops and says nothing.
                        to[i] = to[i].clamp(0.0, self.config.travel_um[i]);
                    }
                }
                self.destination = to;
                self.planned.push_back(to);
                self.start_next(now);
                out.extend(b"ok\n");
            }
            "M400" => {
                if self.busy() {
                    self.ok_when_idle = true;
                    self.last_busy = now;
                } else {
                    out.extend(b"ok\n");
                }
            }
            "G28" => {
                self.destination = [0.0; 3];
                self.planned.push_back([0.0; 3]);
                self.start_next(now);
                self.ok_when_idle = true;
                self.last_busy = now;
            }
            "M112" => self.halt(now, out),
            _ => out.extend(format!("echo:Unknown command: \"{}\"\nok\n", raw.trim()).bytes()),
        }
    }

    fn halt(&mut self, now: f64, out: &mut Vec<u8>) {
        self.axes.stop(now);
        self.planned.clear();
        self.ok_when_idle = false;
        self.halted = true;
        out.extend(b"Error:Printer halted. kill() called!\n");
    }
}

impl Firmware for Marlin {
    fn receive(&mut self, now: f64, bytes: &[u8], out: &mut Vec<u8>) {
        for &b in bytes {
            if self.halted {
                return;
            }
            if let Some(line) = self.lines.push(b) {
                self.line(now, &line, out);
            }
        }
    }

    fn tick(&mut self, now: f64, out: &mut Vec<u8>) {
        if self.halted {
            return;
        }
        if self.axes.update(now) {
            self.start_next(now);
        }
        if self.ok_when_idle {
            if !self.busy() {
                self.ok_when_idle = false;
                out.extend(b"ok\n");
            } else if now - self.last_busy >= 2.0 {
                // The host keep-alive: a long command is still running.
                self.last_busy = now;
                out.extend(b"echo:busy: processing\n");
            }
        }
    }

    fn axes(&self) -> &Axes {
        &self.axes
    }

    fn fault(&mut self, now: f64, fault: Fault, out: &mut Vec<u8>) {
        match fault {
            Fault::LimitSwitch => {
                // Motion stops where the switch closed; the planner takes that position.
                self.axes.stop(now);
                self.planned.clear();
                self.destination = self.axes.motor;
                let p = self.axes.motor.map(|v| v / 1000.0);
                out.extend(
                    format!(
                        "echo:endstops hit:  X:{:.2} Y:{:.2} Z:{:.2}\n",
                        p[0], p[1], p[2]
                    )
                    .bytes(),
                );
            }
            Fault::Halt => self.halt(now, out),
        }
    }
}
