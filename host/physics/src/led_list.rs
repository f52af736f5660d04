//! LEDs placed where a list says, not on a grid or rings: domes, hand-placed LEDs, and
//! datasets from other labs that state each frame's LED position or illumination NA
//! (docs/dataset.md §1.2, "Listed LEDs").
//!
//! A list is interned for the life of the process ([`LedList::new`]): it keeps
//! [`crate::LedGeometry`] a `Copy` value, as every physics function passes it, and a
//! process meets few distinct lists of a few kB each (the same list loaded again is
//! found, not stored twice).

use std::sync::Mutex;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

// The protocol's type itself (optics re-exports it): taken from optics, the two modules
// imported each other.
use fpm_protocol::LedIndex;

/// One LED of a list: its id (what frames name it by) and its place in the array's own
/// frame, mm (x, y in the board's plane; z along its normal, + away from the sample).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListedLed {
    /// The LED's id, (row, col): any pair, unique in the list.
    pub led: LedIndex,
    /// mm.
    pub x_mm: f64,
    /// mm.
    pub y_mm: f64,
    /// mm, + away from the sample (0 on a flat board).
    #[serde(default)]
    pub z_mm: f64,
}

/// A list of LEDs, sorted by id, each id once; cheap to copy.
#[derive(Clone, Copy)]
pub struct LedList(&'static [ListedLed]);

/// Every list this process has made, to find one again instead of storing it twice.
static INTERNED: Mutex<Vec<&'static [ListedLed]>> = Mutex::new(Vec::new());

impl LedList {
    /// The list of `leds` (in any order), or what is wrong with it: none, an id twice
    /// or a coordinate that is not finite.
    pub fn new(mut leds: Vec<ListedLed>) -> Result<Self, crate::Invalid> {
        let invalid = |message: String| crate::Invalid::new("leds", message);
        if leds.is_empty() {
            return Err(invalid("the list holds no LED".into()));
        }
        if let Some(bad) = leds
            .iter()
            .find(|l| !(l.x_mm.is_finite() && l.y_mm.is_finite() && l.z_mm.is_finite()))
        {
            return Err(invalid(format!(
                "LED {} has a position that is not finite",
                bad.led
            )));
        }
        leds.sort_by_key(|l| (l.led.row, l.led.col));
        if let Some(pair) = leds.windows(2).find(|w| w[0].led == w[1].led) {
            return Err(invalid(format!("LED {} is listed twice", pair[0].led)));
        }
        let mut interned = INTERNED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(found) = interned.iter().find(|l| **l == leds.as_slice()) {
            return Ok(Self(found));
        }
        let stored: &'static [ListedLed] = Box::leak(leds.into_boxed_slice());
        interned.push(stored);
        Ok(Self(stored))
    }

    /// Every LED, by id.
    pub fn leds(&self) -> &'static [ListedLed] {
        self.0
    }

    /// LED `led`, if listed.
    pub fn get(&self, led: LedIndex) -> Option<&'static ListedLed> {
        self.0
            .binary_search_by_key(&(led.row, led.col), |l| (l.led.row, l.led.col))
            .ok()
            .map(|k| &self.0[k])
    }

    /// The listed LED nearest the list's origin in the board's plane (the first by id
    /// among equals): the centre LED's role on a grid.
    pub fn nearest_origin(&self) -> LedIndex {
        let r2 = |l: &ListedLed| l.x_mm * l.x_mm + l.y_mm * l.y_mm;
        self.0
            .iter()
            .min_by(|a, b| r2(a).total_cmp(&r2(b)))
            .map_or(LedIndex::new(0, 0), |l| l.led)
    }

    /// The median distance from each LED to its nearest neighbour in the board's plane,
    /// mm (1 for a single LED): the array's pitch where heuristics need one.
    pub fn typical_spacing_mm(&self) -> f64 {
        let mut nearest: Vec<f64> = self
            .0
            .iter()
            .map(|a| {
                self.0
                    .iter()
                    .filter(|b| b.led != a.led)
                    .map(|b| (a.x_mm - b.x_mm).hypot(a.y_mm - b.y_mm))
                    .fold(f64::INFINITY, f64::min)
            })
            .filter(|d| d.is_finite() && *d > 0.0)
            .collect();
        if nearest.is_empty() {
            return 1.0;
        }
        nearest.sort_by(f64::total_cmp);
        nearest[nearest.len() / 2]
    }

    /// Whether any LED sits off the board's plane.
    pub fn is_flat(&self) -> bool {
        self.0.iter().all(|l| l.z_mm == 0.0)
    }
}

impl PartialEq for LedList {
    fn eq(&self, other: &Self) -> bool {
        self.0 == other.0
    }
}

impl std::fmt::Debug for LedList {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LedList({} LEDs)", self.0.len())
    }
}

impl Serialize for LedList {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.0.serialize(s)
    }
}

impl<'de> Deserialize<'de> for LedList {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Self::new(Vec::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn led(r: u8, c: u8, x_mm: f64, y_mm: f64) -> ListedLed {
        ListedLed {
            led: LedIndex::new(r, c),
            x_mm,
            y_mm,
            z_mm: 0.0,
        }
    }

    #[test]
    fn a_list_is_sorted_by_id_found_by_id_and_stored_once() {
        let leds = vec![
            led(0, 2, 4.0, 0.0),
            led(0, 0, 0.5, 0.0),
            led(0, 1, 2.0, 0.1),
        ];
        let a = LedList::new(leds.clone()).unwrap();
        let ids: Vec<u8> = a.leds().iter().map(|l| l.led.col).collect();
        assert_eq!(ids, [0, 1, 2]);
        assert_eq!(a.get(LedIndex::new(0, 1)).map(|l| l.y_mm), Some(0.1));
        assert!(a.get(LedIndex::new(1, 1)).is_none());
        assert_eq!(a.nearest_origin(), LedIndex::new(0, 0));
        // Nearest neighbours 1.5, 1.5 (0.1 off: √2.26) and 2.0: the median.
        assert!((a.typical_spacing_mm() - 2.26f64.sqrt()).abs() < 1e-12);
        let b = LedList::new(leds).unwrap();
        assert!(
            std::ptr::eq(a.leds(), b.leds()),
            "the same list twice is stored once"
        );
    }

    #[test]
    fn a_list_with_an_id_twice_or_no_led_is_refused_by_name() {
        let twice = LedList::new(vec![led(3, 4, 0.0, 0.0), led(3, 4, 1.0, 0.0)]);
        assert_eq!(twice.unwrap_err().to_string(), "LED (3, 4) is listed twice");
        assert!(LedList::new(Vec::new()).is_err());
        let nan = LedList::new(vec![led(0, 0, f64::NAN, 0.0)])
            .unwrap_err()
            .to_string();
        assert!(nan.contains("not finite"), "{nan}");
    }
}
