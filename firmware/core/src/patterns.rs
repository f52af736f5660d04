//! On-device illumination patterns, computed from the board's nominal geometry.
//!
//! LED (r, c) sits at grid offset (p, q) = (c − c₀, r − r₀) from the centre LED, at
//! distance ρ = pitch·√(p² + q²) from the axis; its illumination NA is ρ/√(ρ² + h²).
//! Comparisons are made on NA² so no square root is needed on the Cortex-M0+.

use fpm_protocol::{BoardGeometry, DeviceError, Half, LedIndex, Param, Pattern};

/// Check a pattern's parameters.
pub fn validate(pattern: &Pattern) -> Result<(), DeviceError> {
    let na_ok = |na: f32| na.is_finite() && na > 0.0 && na <= 1.0;
    let ok = match *pattern {
        Pattern::BrightField { na } | Pattern::DarkField { na } => na_ok(na),
        Pattern::HalfCircle { na, .. } => na_ok(na),
        Pattern::Annulus { inner, outer } => {
            inner.is_finite() && inner >= 0.0 && na_ok(outer) && inner < outer
        }
        Pattern::All => true,
    };
    if ok {
        Ok(())
    } else {
        Err(DeviceError::BadParam(Param::Na))
    }
}

/// Grid offsets (p, q) of `led` from the centre LED.
pub fn grid_offset(g: &BoardGeometry, led: LedIndex) -> (i32, i32) {
    (
        led.col as i32 - g.center.col as i32,
        led.row as i32 - g.center.row as i32,
    )
}

/// The squared illumination NA of `led`.
pub fn na_squared(g: &BoardGeometry, led: LedIndex) -> f32 {
    let (p, q) = grid_offset(g, led);
    let pitch_mm = g.pitch_um as f32 * 1e-3;
    let h_mm = g.height_um as f32 * 1e-3;
    let rho2 = pitch_mm * pitch_mm * (p * p + q * q) as f32;
    rho2 / (rho2 + h_mm * h_mm)
}

/// Whether `led` belongs to a (validated) `pattern`.
pub fn contains(g: &BoardGeometry, pattern: &Pattern, led: LedIndex) -> bool {
    if !g.contains(led) {
        return false;
    }
    let na2 = na_squared(g, led);
    match *pattern {
        Pattern::BrightField { na } => na2 <= na * na,
        Pattern::DarkField { na } => na2 > na * na,
        Pattern::Annulus { inner, outer } => na2 > inner * inner && na2 <= outer * outer,
        Pattern::HalfCircle { na, half } => {
            let (p, q) = grid_offset(g, led);
            let side = match half {
                Half::Top => q < 0,
                Half::Bottom => q > 0,
                Half::Left => p < 0,
                Half::Right => p > 0,
            };
            side && na2 <= na * na
        }
        Pattern::All => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BoardConfig;

    fn g() -> BoardGeometry {
        BoardConfig::PICO_21X21.geometry
    }

    fn members(p: &Pattern) -> std::vec::Vec<LedIndex> {
        let g = g();
        let mut v = std::vec::Vec::new();
        for r in 0..g.rows {
            for c in 0..g.cols {
                if contains(&g, p, LedIndex::new(r, c)) {
                    v.push(LedIndex::new(r, c));
                }
            }
        }
        v
    }

    /// The NA of an LED computed independently, in f64 with a square root.
    fn na_f64(led: LedIndex) -> f64 {
        let (p, q) = ((led.col as f64 - 10.0) * 2.5, (led.row as f64 - 10.0) * 2.5);
        let rho = (p * p + q * q).sqrt();
        rho / (rho * rho + 92.0 * 92.0).sqrt()
    }

    #[test]
    fn bright_field_matches_an_independent_na() {
        for na in [0.05f32, 0.1, 0.25] {
            let bf = members(&Pattern::BrightField { na });
            let expect: std::vec::Vec<_> = (0..21u8)
                .flat_map(|r| (0..21u8).map(move |c| LedIndex::new(r, c)))
                .filter(|&l| na_f64(l) <= na as f64)
                .collect();
            assert_eq!(bf, expect, "NA {na}");
            assert!(bf.contains(&LedIndex::new(10, 10)));
        }
    }

    #[test]
    fn bright_and_dark_field_partition_the_board() {
        let bf = members(&Pattern::BrightField { na: 0.1 });
        let df = members(&Pattern::DarkField { na: 0.1 });
        assert_eq!(bf.len() + df.len(), 441);
        assert!(bf.iter().all(|l| !df.contains(l)));
    }

    #[test]
    fn annulus_is_the_difference_of_two_discs() {
        let outer = members(&Pattern::BrightField { na: 0.3 });
        let inner = members(&Pattern::BrightField { na: 0.1 });
        let ring = members(&Pattern::Annulus {
            inner: 0.1,
            outer: 0.3,
        });
        assert_eq!(ring.len(), outer.len() - inner.len());
        assert!(ring.iter().all(|l| outer.contains(l) && !inner.contains(l)));
    }

    #[test]
    fn dpc_halves_are_mirror_images_inside_the_disc() {
        let bf = members(&Pattern::BrightField { na: 0.1 });
        for (a, b) in [(Half::Top, Half::Bottom), (Half::Left, Half::Right)] {
            let ha = members(&Pattern::HalfCircle { na: 0.1, half: a });
            let hb = members(&Pattern::HalfCircle { na: 0.1, half: b });
            assert_eq!(ha.len(), hb.len());
            assert!(!ha.is_empty());
            assert!(ha.iter().chain(hb.iter()).all(|l| bf.contains(l)));
            // the dividing line through the centre belongs to neither half
            assert!(!ha.contains(&LedIndex::new(10, 10)));
            for l in &ha {
                let mirrored = match a {
                    Half::Top => LedIndex::new(20 - l.row, l.col),
                    _ => LedIndex::new(l.row, 20 - l.col),
                };
                assert!(hb.contains(&mirrored));
            }
        }
        let top = members(&Pattern::HalfCircle {
            na: 0.1,
            half: Half::Top,
        });
        assert!(top.iter().all(|l| l.row < 10));
    }

    #[test]
    fn bad_apertures_are_refused() {
        for p in [
            Pattern::BrightField { na: 0.0 },
            Pattern::BrightField { na: f32::NAN },
            Pattern::DarkField { na: 1.5 },
            Pattern::Annulus {
                inner: 0.3,
                outer: 0.2,
            },
            Pattern::Annulus {
                inner: -0.1,
                outer: 0.2,
            },
            Pattern::HalfCircle {
                na: f32::INFINITY,
                half: Half::Left,
            },
        ] {
            assert_eq!(validate(&p), Err(DeviceError::BadParam(Param::Na)), "{p:?}");
        }
        assert_eq!(
            validate(&Pattern::Annulus {
                inner: 0.0,
                outer: 1.0
            }),
            Ok(())
        );
        assert_eq!(validate(&Pattern::All), Ok(()));
    }
}
