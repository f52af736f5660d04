//! Multiplexed illumination: which LEDs light each frame when several are lit at once
//! (Tian, Li, Ramchandran & Waller, Biomed. Opt. Express 5, 2376, 2014).
//!
//! Every LED is lit in exactly one frame. Bright-field and dark-field LEDs are never
//! mixed (a bright-field LED is 10–1000× brighter, so the exposure a mixed frame
//! allows leaves its dark-field LEDs in the noise); within each, LEDs of similar
//! illumination NA (so similar brightness) share frames, and which of them share is
//! random, so that one frame's LEDs sit at scattered angles whose spectra overlap
//! little (Tian et al.'s random patterns).

use crate::optics::{LedGeometry, LedIndex, System};
use rand::seq::SliceRandom;
use rand::SeedableRng;

/// Sets of at most `k` LEDs (`k` ≥ 1) covering every LED of `geometry` once, seen from
/// the field's centre: bright field and dark field apart, each sorted by illumination
/// NA and cut into annuli of 4·`k` LEDs, each annulus shuffled (by `seed`) and cut into
/// sets of `k`. `k` = 1 gives one LED per set, nearest the axis first.
pub fn sets(geometry: &LedGeometry, system: &System, k: usize, seed: u64) -> Vec<Vec<LedIndex>> {
    let k = k.max(1);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x4D55_4C54);
    let leds = geometry.leds();
    let order = geometry.nearest_first(&leds, (0.0, 0.0), system);
    let (bright, dark): (Vec<LedIndex>, Vec<LedIndex>) = order
        .iter()
        .map(|&i| leds[i])
        .partition(|&led| geometry.is_bright_field(led, 0.0, 0.0, system));
    let mut out = vec![];
    for class in [bright, dark] {
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
            let sets = sets(&g, &s, k, 7);
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
        assert_eq!(sets(&g, &s, 1, 7)[0], vec![g.center]);
    }
}
