//! The acquisition's chart: which LEDs of the array have a labelled frame.

use fpm_physics::{LedGeometry, LedIndex, System};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::{palette, Chart};

/// Every LED at its position under the geometry used, filled where its frame is in
/// the dataset, a red cross where it is missing; the bright-field disc for reference.
pub struct Coverage<'a> {
    /// The array (positions as used for the acquisition).
    pub geometry: &'a LedGeometry,
    /// LEDs without a frame.
    pub missing: &'a [LedIndex],
    /// The optics.
    pub system: &'a System,
}

impl Chart for Coverage<'_> {
    fn size(&self) -> (u32, u32) {
        (700, 660)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let leds = self.geometry.leds();
        let at = |l: &LedIndex| self.geometry.led_position_mm(*l);
        let (lo, hi) = leds
            .iter()
            .map(at)
            .flat_map(|p| [p.0, p.1])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let got = leds.len() - self.missing.len();
        let caption = format!("Frames in the dataset: {got} of {} LEDs", leds.len());
        let mut chart = super::plane(
            area,
            Some(&caption),
            super::square_with_legend_room((lo, hi), (lo, hi)),
            super::LED_PLANE_AXES,
        )?;
        chart
            .draw_series(
                leds.iter()
                    .filter(|l| !self.missing.contains(l))
                    .map(|l| Circle::new(at(l), 4, palette::BLUE.filled())),
            )?
            .label(format!("labelled frame ({got})"))
            .legend(|(x, y)| Circle::new((x + 10, y), 4, palette::BLUE.filled()));
        chart
            .draw_series(
                self.missing
                    .iter()
                    .map(|l| Cross::new(at(l), 6, palette::VERMILION.stroke_width(3))),
            )?
            .label(format!("missing ({})", self.missing.len()))
            .legend(|(x, y)| Cross::new((x + 10, y), 5, palette::VERMILION.stroke_width(3)));
        let r = super::bright_field_radius_mm(self.system.na, self.geometry.height_mm);
        super::draw_bright_field_disc(
            &mut chart,
            r,
            format!("bright-field inside (NA {:.2})", self.system.na),
        )?;
        super::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    }
}
