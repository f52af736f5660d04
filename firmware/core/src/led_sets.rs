//! The LED set table (protocol 1.2): LED lists uploaded once, each lit whole by a
//! sequence step that names it. Stored as one pool of LEDs and each set's end in it, so
//! the table costs 2 bytes per LED and per set, whatever the sets' sizes.

use fpm_protocol::limits::{MAX_LED_SETS, MAX_LED_SET_LEDS};
use fpm_protocol::{BoardGeometry, DeviceError, LedIndex, LedSetDefine, LedSetsDefined, Param};
use heapless::Vec;

/// The table.
pub struct LedSets {
    pool: Vec<LedIndex, MAX_LED_SET_LEDS>,
    ends: Vec<u16, MAX_LED_SETS>,
}

impl Default for LedSets {
    fn default() -> Self {
        Self::new()
    }
}

impl LedSets {
    /// No set defined.
    pub const fn new() -> Self {
        Self {
            pool: Vec::new(),
            ends: Vec::new(),
        }
    }

    /// What the table holds.
    pub fn defined(&self) -> LedSetsDefined {
        LedSetsDefined {
            sets: self.ends.len() as u16,
            leds: self.pool.len() as u16,
        }
    }

    /// Define set `req.index` (0 clears the table first; otherwise it must be the next
    /// one). A failing request changes nothing.
    pub fn define(
        &mut self,
        req: &LedSetDefine,
        board: &BoardGeometry,
    ) -> Result<LedSetsDefined, DeviceError> {
        let defined = if req.index == 0 {
            0
        } else {
            self.ends.len() as u16
        };
        if req.index != defined {
            return Err(DeviceError::ChunkOutOfRange {
                offset: req.index,
                len: 1,
                loaded: defined,
                total: MAX_LED_SETS as u16,
            });
        }
        if req.leds.is_empty() {
            return Err(DeviceError::BadParam(Param::StepCount));
        }
        if let Some(&bad) = req.leds.iter().find(|&&l| !board.contains(l)) {
            return Err(DeviceError::BadLed {
                row: bad.row,
                col: bad.col,
            });
        }
        if req.index as usize >= MAX_LED_SETS {
            return Err(DeviceError::TooMany {
                requested: req.index as u32 + 1,
                max: MAX_LED_SETS as u32,
            });
        }
        let start = if req.index == 0 { 0 } else { self.pool.len() };
        if start + req.leds.len() > MAX_LED_SET_LEDS {
            return Err(DeviceError::TooMany {
                requested: (start + req.leds.len()) as u32,
                max: MAX_LED_SET_LEDS as u32,
            });
        }
        if req.index == 0 {
            self.pool.clear();
            self.ends.clear();
        }
        for &led in &req.leds {
            // Room was checked above.
            let _ = self.pool.push(led);
        }
        let _ = self.ends.push(self.pool.len() as u16);
        Ok(self.defined())
    }

    /// Set `index`'s LEDs, if it is defined.
    pub fn get(&self, index: u16) -> Option<&[LedIndex]> {
        let end = *self.ends.get(index as usize)? as usize;
        let start = match index {
            0 => 0,
            _ => *self.ends.get(index as usize - 1)? as usize,
        };
        self.pool.get(start..end)
    }

    /// The error for a step naming set `index` when it is not defined.
    pub fn missing(&self, index: u16) -> DeviceError {
        DeviceError::TooMany {
            requested: index as u32 + 1,
            max: self.ends.len() as u32,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BoardConfig;

    fn set(index: u16, leds: &[(u8, u8)]) -> LedSetDefine {
        LedSetDefine {
            index,
            leds: leds.iter().map(|&(r, c)| LedIndex::new(r, c)).collect(),
        }
    }

    #[test]
    fn sets_are_defined_in_order_and_read_back() {
        let board = BoardConfig::PICO_21X21.geometry;
        let mut t = LedSets::new();
        assert_eq!(
            t.define(&set(0, &[(1, 2), (3, 4)]), &board).unwrap().sets,
            1
        );
        assert_eq!(t.define(&set(1, &[(5, 6)]), &board).unwrap().leds, 3);
        assert_eq!(
            t.get(0).unwrap(),
            &[LedIndex::new(1, 2), LedIndex::new(3, 4)]
        );
        assert_eq!(t.get(1).unwrap(), &[LedIndex::new(5, 6)]);
        assert_eq!(t.get(2), None);
        // Out of order, empty, off the board: refused, nothing changed.
        assert!(matches!(
            t.define(&set(3, &[(0, 0)]), &board),
            Err(DeviceError::ChunkOutOfRange {
                offset: 3,
                loaded: 2,
                ..
            })
        ));
        assert_eq!(
            t.define(&set(2, &[]), &board),
            Err(DeviceError::BadParam(Param::StepCount))
        );
        assert_eq!(
            t.define(&set(2, &[(0, 0), (21, 0)]), &board),
            Err(DeviceError::BadLed { row: 21, col: 0 })
        );
        assert_eq!(t.defined().sets, 2);
        // Set 0 starts again.
        assert_eq!(t.define(&set(0, &[(9, 9)]), &board).unwrap().sets, 1);
        assert_eq!(t.get(0).unwrap(), &[LedIndex::new(9, 9)]);
        assert_eq!(t.get(1), None);
    }

    #[test]
    fn the_table_holds_every_led_of_the_largest_board_once_and_no_more() {
        let board = BoardGeometry {
            rows: 32,
            cols: 32,
            ..BoardConfig::PICO_21X21.geometry
        };
        let mut t = LedSets::new();
        for k in 0..16u16 {
            let leds: std::vec::Vec<(u8, u8)> = (0..64u16)
                .map(|i| ((k * 2 + i / 32) as u8, (i % 32) as u8))
                .collect();
            t.define(&set(k, &leds), &board).unwrap();
        }
        assert_eq!(t.defined().leds, 1024);
        assert!(matches!(
            t.define(&set(16, &[(0, 0)]), &board),
            Err(DeviceError::TooMany {
                requested: 1025,
                max: 1024
            })
        ));
    }
}
