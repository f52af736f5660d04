//! LED scans: which LEDs a capture sequence lights, and in which order.

use fpm_firmware::patterns;
use fpm_protocol::{BoardGeometry, Illumination, LedIndex, Pattern, Rgb, Step};

/// Which LEDs a scan visits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Selection {
    /// Every LED on the board.
    All,
    /// The LEDs of an on-device pattern (e.g. bright-field at the objective's NA).
    Pattern(Pattern),
}

/// The order of a scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Order {
    /// Increasing distance from the centre LED (the order EPRY updates in).
    Nearest,
    /// Row by row, left to right.
    Raster,
}

/// One step per selected LED, in `order`, each lit in `color`.
pub fn scan_steps(g: &BoardGeometry, selection: Selection, order: Order, color: Rgb) -> Vec<Step> {
    let mut leds: Vec<LedIndex> = (0..g.rows)
        .flat_map(|r| (0..g.cols).map(move |c| LedIndex::new(r, c)))
        .filter(|&led| match selection {
            Selection::All => true,
            Selection::Pattern(p) => patterns::contains(g, &p, led),
        })
        .collect();
    if order == Order::Nearest {
        // The one nearest-first rule (EPRY's, the acquisition's): by illumination
        // frequency, which for a board at its nominal place grows with the distance
        // from the centre LED whatever the optics; ties keep raster order.
        let geometry = crate::board_geometry::nominal(g);
        let order = geometry.nearest_first(&leds, (0.0, 0.0), &fpm_physics::System::paper());
        leds = order.into_iter().map(|k| leds[k]).collect();
    }
    leds.into_iter()
        .map(|led| Step {
            illumination: Illumination::Led(led),
            color,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_first_starts_at_the_centre_and_never_moves_outwards_then_in() {
        let g = fpm_firmware::BoardConfig::PICO_21X21.geometry;
        let steps = scan_steps(&g, Selection::All, Order::Nearest, Rgb::WHITE);
        assert_eq!(steps.len(), 441);
        assert_eq!(
            steps[0].illumination,
            Illumination::Led(LedIndex::new(10, 10))
        );
        let radius = |s: &Step| match s.illumination {
            Illumination::Led(l) => {
                let (p, q) = patterns::grid_offset(&g, l);
                p * p + q * q
            }
            _ => unreachable!(),
        };
        assert!(steps.windows(2).all(|w| radius(&w[0]) <= radius(&w[1])));
        let mut seen: Vec<_> = steps.iter().map(|s| s.illumination).collect();
        seen.dedup();
        assert_eq!(seen.len(), 441);
    }

    #[test]
    fn a_bright_field_scan_is_the_pattern() {
        let g = fpm_firmware::BoardConfig::PICO_21X21.geometry;
        let p = Pattern::BrightField { na: 0.1 };
        let steps = scan_steps(&g, Selection::Pattern(p), Order::Raster, Rgb::WHITE);
        let expected = (0..21u8)
            .flat_map(|r| (0..21u8).map(move |c| LedIndex::new(r, c)))
            .filter(|l| patterns::contains(&g, &p, *l))
            .count();
        assert_eq!(steps.len(), expected);
        assert!(steps.len() > 1 && steps.len() < 441);
    }
}
