//! Multiplexed illumination: which LEDs light each frame when several are lit at once
//! (Tian, Li, Ramchandran & Waller, Biomed. Opt. Express 5, 2376, 2014).
//!
//! Every LED is lit in exactly one frame. Bright-field and dark-field LEDs are never
//! mixed (a bright-field LED is 10–1000× brighter, so the exposure a mixed frame
//! allows leaves its dark-field LEDs in the noise); within each, LEDs of similar
//! illumination NA (so similar brightness) share frames, and which of them share is
//! random, so that one frame's LEDs sit at scattered angles whose spectra overlap
//! little (Tian et al.'s random patterns). The bright field is multiplexed less than
//! the dark field, by default not at all: bright-field LEDs' windows all hold the
//! object's strong low frequencies and overlap almost wholly, and summed they could
//! not be told apart (128² cells: four LEDs per frame everywhere 0.123 complex NRMSE
//! against 0.085 one LED each; the bright field alone and the dark field four at a
//! time 0.076, in 144 frames instead of 441; docs/results.md).

use crate::optics::{LedGeometry, LedIndex, System};
use rand::seq::SliceRandom;
use rand::SeedableRng;

/// How many LEDs share a frame, in the dark field and in the bright field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Multiplex {
    /// Dark-field LEDs per frame.
    pub dark_field: usize,
    /// Bright-field LEDs per frame.
    pub bright_field: usize,
}

impl Multiplex {
    /// One LED per frame.
    pub const ONE: Multiplex = Multiplex {
        dark_field: 1,
        bright_field: 1,
    };

    /// `k` dark-field LEDs per frame, the bright field one at a time (the default of
    /// `--multiplex K`).
    pub const fn dark_field(k: usize) -> Self {
        Self {
            dark_field: k,
            bright_field: 1,
        }
    }

    /// Whether every frame has one LED.
    pub fn is_one(&self) -> bool {
        self.dark_field <= 1 && self.bright_field <= 1
    }

    /// Both counts within 1..=`max`, or which one is not.
    pub fn check(&self, max: usize) -> Result<(), crate::Invalid> {
        for (name, k) in [
            ("multiplex", self.dark_field),
            ("multiplex_bright", self.bright_field),
        ] {
            if !(1..=max).contains(&k) {
                return Err(crate::Invalid::new(
                    name,
                    format!("{name} {k}: light 1 to {max} LEDs per frame"),
                ));
            }
        }
        Ok(())
    }
}

/// Sets covering every LED of `geometry` once, seen from the field's centre: bright
/// field and dark field apart, each sorted by illumination NA and cut into annuli of 4k
/// LEDs (k: `per_frame`'s count for that class), each annulus shuffled (by `seed`) and
/// cut into sets of k. One LED per frame gives the LEDs nearest the axis first.
pub fn sets(
    geometry: &LedGeometry,
    system: &System,
    per_frame: Multiplex,
    seed: u64,
) -> Vec<Vec<LedIndex>> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x4D55_4C54);
    let leds = geometry.leds();
    let order = geometry.nearest_first(&leds, (0.0, 0.0), system);
    let (bright, dark): (Vec<LedIndex>, Vec<LedIndex>) = order
        .iter()
        .map(|&i| leds[i])
        .partition(|&led| geometry.is_bright_field(led, 0.0, 0.0, system));
    let mut out = vec![];
    for (class, k) in [
        (bright, per_frame.bright_field.max(1)),
        (dark, per_frame.dark_field.max(1)),
    ] {
        for annulus in class.chunks(4 * k) {
            let mut annulus = annulus.to_vec();
            if k > 1 {
                annulus.shuffle(&mut rng);
            }
            out.extend(annulus.chunks(k).map(<[LedIndex]>::to_vec));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_led_is_lit_once_and_bright_and_dark_field_never_share_a_frame() {
        let (g, s) = (LedGeometry::paper(), System::paper());
        for k in [1, 2, 4, 8, 16] {
            let sets = sets(
                &g,
                &s,
                Multiplex {
                    dark_field: k,
                    bright_field: k,
                },
                7,
            );
            let mut all: Vec<LedIndex> = sets.iter().flatten().copied().collect();
            assert_eq!(all.len(), 441, "k = {k}");
            all.sort();
            all.dedup();
            assert_eq!(all.len(), 441, "k = {k}: an LED lit twice");
            assert!(sets.iter().all(|set| !set.is_empty() && set.len() <= k));
            for set in &sets {
                let bright = set
                    .iter()
                    .filter(|&&l| g.is_bright_field(l, 0.0, 0.0, &s))
                    .count();
                assert!(bright == 0 || bright == set.len(), "k = {k}: {set:?} mixes");
            }
            // Few sets are short: at most one per annulus of each class.
            let full = sets.iter().filter(|set| set.len() == k).count();
            assert!(full * k >= 441 * 3 / 4, "k = {k}: {full} full sets");
        }
        assert_eq!(sets(&g, &s, Multiplex::ONE, 7)[0], vec![g.center]);
        // By default the bright field stays one LED per frame.
        let dark_only = sets(&g, &s, Multiplex::dark_field(4), 7);
        for set in &dark_only {
            if g.is_bright_field(set[0], 0.0, 0.0, &s) {
                assert_eq!(set.len(), 1);
            }
        }
        assert!(dark_only.iter().any(|set| set.len() == 4));
    }
}
