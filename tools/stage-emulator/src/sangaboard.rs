//! The Sangaboard's firmware v1 as a stage controller sees it.

use std::collections::VecDeque;

use crate::motion::Axes;
use crate::{Config, Fault, Firmware, Lines};

pub(crate) struct Sangaboard {
    axes: Axes,
    config: Config,
    lines: Lines,
    /// Lines that arrived during a blocking move (the board reads them afterwards).
    waiting: VecDeque<String>,
    /// `done.` owed when the move ends (blocking mode).
    done_when_idle: bool,
    blocking: bool,
    halted: bool,
}

impl Sangaboard {
    pub(crate) fn new(config: &Config) -> Self {
        Self {
            axes: Axes::new(config.start_um, config.backlash_um),
            config: config.clone(),
            lines: Lines::default(),
            waiting: VecDeque::new(),
            done_when_idle: false,
            blocking: true,
            halted: false,
        }
    }

    fn steps(&self) -> [i64; 3] {
        [0, 1, 2].map(|i| (self.axes.motor[i] / self.config.um_per_step[i]).round() as i64)
    }

    fn line(&mut self, now: f64, line: &str, out: &mut Vec<u8>) {
        let l = line.trim();
        let mut say = |s: &str| {
            out.extend(s.bytes());
            out.extend(b"\r\n");
        };
        if l == "version" {
            say("Sangaboard Firmware v1.0.4");
        } else if l == "board" {
            say("Sangaboard v0.5");
        } else if l == "dt?" || l == "min_step_delay?" {
            say(&format!(
                "minimum step delay {:.0}",
                self.config.step_delay_us
            ));
        } else if l == "p?" || l == "position?" {
            let s = self.steps();
            say(&format!("{} {} {}", s[0], s[1], s[2]));
        } else if l == "moving?" {
            say(if self.axes.moving() { "true" } else { "false" });
        } else if l == "zero" {
            self.axes.set_origin([0.0; 3]);
            say("position reset to 0 0 0");
        } else if l == "stop" {
            self.axes.stop(now);
            say("stopped");
        } else if let Some(v) = l.strip_prefix("blocking_moves ") {
            self.blocking = v.trim() != "false";
            say("done.");
        } else if let Some(rest) = l
            .strip_prefix("mr ")
            .or_else(|| l.strip_prefix("move_rel "))
        {
            let d: Vec<i64> = rest
                .split_whitespace()
                .filter_map(|t| t.parse().ok())
                .collect();
            if d.len() != 3 {
                say("Error: command is mr <int> <int> <int>");
                return;
            }
            let from = self.steps();
            let to = [0, 1, 2].map(|i| (from[i] + d[i]) as f64 * self.config.um_per_step[i]);
            // Every motor steps at the board's one rate.
            let speed = self
                .config
                .um_per_step
                .map(|u| u / (self.config.step_delay_us * 1e-6));
            self.axes.start(now, to, speed);
            if self.blocking {
                self.done_when_idle = true;
            } else {
                say("done.");
            }
        } else {
            say("Type 'help' for a list of commands.");
        }
    }
}

impl Firmware for Sangaboard {
    fn receive(&mut self, now: f64, bytes: &[u8], out: &mut Vec<u8>) {
        if self.halted {
            return;
        }
        for &b in bytes {
            if let Some(line) = self.lines.push(b) {
                self.waiting.push_back(line);
            }
        }
        self.tick(now, out);
    }

    fn tick(&mut self, now: f64, out: &mut Vec<u8>) {
        if self.halted {
            return;
        }
        self.axes.update(now);
        if self.done_when_idle {
            if self.axes.moving() {
                return;
            }
            self.done_when_idle = false;
            out.extend(b"done.\r\n");
        }
        while !self.done_when_idle {
            let Some(line) = self.waiting.pop_front() else {
                break;
            };
            self.line(now, &line, out);
        }
    }

    fn axes(&self) -> &Axes {
        &self.axes
    }

    fn fault(&mut self, now: f64, _fault: Fault, _out: &mut Vec<u8>) {
        // No end stops and no alarms: a stalled board just stops answering.
        self.axes.stop(now);
        self.halted = true;
    }
}
