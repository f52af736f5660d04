//! The mechanics every emulated stage shares: three axes moving together in a straight
//! line at a set speed, and play (backlash) between the motors and what they move.

/// A straight move in progress, µm and seconds.
#[derive(Debug, Clone, Copy)]
struct Move {
    from: [f64; 3],
    to: [f64; 3],
    start: f64,
    end: f64,
}

/// Three motor-driven axes, µm.
#[derive(Debug, Clone)]
pub struct Axes {
    /// Where the motors are (what the firmware counts).
    pub motor: [f64; 3],
    /// Where the carriage is: it follows the motor through a dead band of width
    /// `backlash`, so reversing loses that much travel before the carriage moves.
    pub mechanical: [f64; 3],
    backlash: [f64; 3],
    current: Option<Move>,
}

impl Axes {
    /// At rest at `at`, the play centred.
    pub fn new(at: [f64; 3], backlash: [f64; 3]) -> Self {
        Self {
            motor: at,
            mechanical: at,
            backlash,
            current: None,
        }
    }

    /// Start moving to `to` at `speed` µm/s per axis (the slowest axis sets the time).
    pub fn start(&mut self, now: f64, to: [f64; 3], speed: [f64; 3]) {
        self.update(now);
        let mut time: f64 = 0.0;
        for i in 0..3 {
            time = time.max((to[i] - self.motor[i]).abs() / speed[i].max(1e-9));
        }
        self.current = Some(Move {
            from: self.motor,
            to,
            start: now,
            end: now + time,
        });
    }

    /// Bring the motors to `now`; true if a move ended.
    pub fn update(&mut self, now: f64) -> bool {
        let Some(m) = self.current else {
            return false;
        };
        let f = if m.end > m.start {
            ((now - m.start) / (m.end - m.start)).clamp(0.0, 1.0)
        } else {
            1.0
        };
        for i in 0..3 {
            self.motor[i] = m.from[i] + f * (m.to[i] - m.from[i]);
        }
        self.take_up_play();
        if f >= 1.0 {
            self.current = None;
            return true;
        }
        false
    }

    /// Stop where the motors are now.
    pub fn stop(&mut self, now: f64) {
        self.update(now);
        self.current = None;
    }

    /// Whether a move is under way.
    pub fn moving(&self) -> bool {
        self.current.is_some()
    }

    /// Set the motor count without moving (homing's zeroing, `zero`).
    pub fn set_origin(&mut self, at: [f64; 3]) {
        for ((mech, motor), new) in self.mechanical.iter_mut().zip(self.motor).zip(at) {
            *mech += new - motor;
        }
        self.motor = at;
    }

    fn take_up_play(&mut self) {
        for i in 0..3 {
            let half = self.backlash[i] / 2.0;
            self.mechanical[i] =
                self.mechanical[i].clamp(self.motor[i] - half, self.motor[i] + half);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_take_distance_over_speed_and_reversals_lose_the_play() {
        let mut a = Axes::new([0.0; 3], [0.0, 0.0, 4.0]);
        a.start(0.0, [0.0, 0.0, 100.0], [1.0, 1.0, 50.0]);
        assert!(!a.update(1.0));
        assert!((a.motor[2] - 50.0).abs() < 1e-9);
        assert!(a.update(2.0));
        assert!((a.mechanical[2] - 98.0).abs() < 1e-9);
        a.start(2.0, [0.0, 0.0, 90.0], [1.0; 3]);
        a.update(100.0);
        // Down 10 µm: the first 4 µm of motor travel only cross the play.
        assert!((a.mechanical[2] - 92.0).abs() < 1e-9);
    }
}
