//! The calibration's charts: how the feature moved under each LED against the fitted
//! model (at the sample, µm), and where the fitted array sits against the nominal one
//! (in the illumination plane, mm).

use fpm_physics::calibrate::{Calibration, LedStatus};
use fpm_physics::{LedGeometry, System};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::{bright_field_radius_mm, palette, Chart, FONT};

/// What a status means, for legends and tables.
pub fn status_label(status: LedStatus) -> &'static str {
    match status {
        LedStatus::Used => "used in the fit",
        LedStatus::NotBrightField => "left out: dark-field",
        LedStatus::NearPupilEdge => "left out: near the pupil edge",
        LedStatus::FeatureLost => "left out: feature lost",
        LedStatus::Saturated => "left out: saturated",
        LedStatus::Outlier => "left out: outlier",
    }
}

/// The colour of a status.
pub fn status_colour(status: LedStatus) -> RGBColor {
    match status {
        LedStatus::Used => palette::BLUE,
        LedStatus::NotBrightField => palette::DARK,
        LedStatus::NearPupilEdge => palette::ORANGE,
        LedStatus::FeatureLost | LedStatus::Saturated => palette::PURPLE,
        LedStatus::Outlier => palette::VERMILION,
    }
}

const ALL_STATUSES: [LedStatus; 6] = [
    LedStatus::Used,
    LedStatus::NotBrightField,
    LedStatus::NearPupilEdge,
    LedStatus::FeatureLost,
    LedStatus::Saturated,
    LedStatus::Outlier,
];

/// Measured (bias-corrected) against fitted shifts of the feature, µm at the sample,
/// with the residuals drawn magnified.
pub struct Residuals<'a> {
    /// The calibration.
    pub cal: &'a Calibration,
    /// The optics (the magnification is stated on the plot).
    pub system: &'a System,
}

/// One LED's shifts on the residual plot.
struct ShiftPoint {
    corrected: (f64, f64),
    fitted: (f64, f64),
    status: LedStatus,
}

impl Residuals<'_> {
    fn points(&self) -> Vec<ShiftPoint> {
        self.cal
            .leds
            .iter()
            .filter_map(|l| {
                let m = l.measured_um?;
                let b = l.bias_um.unwrap_or([0.0, 0.0]);
                Some(ShiftPoint {
                    corrected: (m[0] - b[0], m[1] - b[1]),
                    fitted: (l.fitted_um[0], l.fitted_um[1]),
                    status: l.status,
                })
            })
            .collect()
    }

    /// How many times the residual vectors are magnified: a round number (1, 2 or 5
    /// × 10ᵏ) that makes the largest used residual about a twelfth of the plot.
    pub fn gain(&self) -> f64 {
        let points = self.points();
        let (xs, ys) = self.extent(&points);
        let worst = points
            .iter()
            .filter(|p| p.status == LedStatus::Used)
            .map(|p| (p.corrected.0 - p.fitted.0).hypot(p.corrected.1 - p.fitted.1))
            .fold(0.0, f64::max);
        let span = (xs.1 - xs.0).max(ys.1 - ys.0);
        nice_gain(span / 12.0 / worst.max(1e-9))
    }

    /// The data's x and y ranges.
    fn extent(&self, points: &[ShiftPoint]) -> ((f64, f64), (f64, f64)) {
        let range = |values: &mut dyn Iterator<Item = f64>| {
            values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            })
        };
        (
            range(&mut points.iter().flat_map(|p| [p.corrected.0, p.fitted.0])),
            range(&mut points.iter().flat_map(|p| [p.corrected.1, p.fitted.1])),
        )
    }
}

/// The largest 1, 2 or 5 × 10ᵏ not above `g` (at least 1).
fn nice_gain(g: f64) -> f64 {
    if !(g.is_finite() && g > 1.0) {
        return 1.0;
    }
    let decade = 10f64.powf(g.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|&x| x <= g * (1.0 + 1e-9))
        .unwrap_or(decade)
}

impl Chart for Residuals<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let points = self.points();
        let (xs, ys) = self.extent(&points);
        let gain = self.gain();
        let s = self.system;
        let (title, notes) = area.split_vertically(44);
        title.titled(
            &format!(
                "Feature shift under each LED, defocus {:+.0} µm",
                self.cal.defocus_um
            ),
            (FONT, 22).into_font().style(FontStyle::Bold),
        )?;
        let (notes, plot) = notes.split_vertically(44);
        notes.draw_text(
            &format!(
                "Sample plane, µm (objective {:.1}×: one {:.2} µm camera pixel = {:.3} µm). Residuals drawn ×{gain:.0}; rms {:.3} µm.",
                s.magnification, s.pixel_size_um, s.sample_pixel_um(), self.cal.rms_residual_um
            ),
            &(FONT, 14).into_font().color(&BLACK),
            (12, 4),
        )?;
        let mut chart = super::plane(
            &plot,
            None,
            super::square_with_legend_room(xs, ys),
            ("shift x at the sample (µm)", "shift y at the sample (µm)"),
        )?;
        // Fitted model: open circles.
        chart
            .draw_series(
                points
                    .iter()
                    .map(|p| Circle::new(p.fitted, 7, status_colour(p.status).stroke_width(2))),
            )?
            .label("fitted model (○)")
            .legend(|(x, y)| Circle::new((x + 10, y), 6, palette::BLUE.stroke_width(2)));
        // Measured shifts: crosses, one series per status for the legend.
        for status in ALL_STATUSES {
            let of: Vec<&ShiftPoint> = points.iter().filter(|p| p.status == status).collect();
            if of.is_empty() {
                continue;
            }
            let colour = status_colour(status);
            chart
                .draw_series(
                    of.iter()
                        .map(|p| Cross::new(p.corrected, 6, colour.stroke_width(2))),
                )?
                .label(format!("measured, {} ({})", status_label(status), of.len()))
                .legend(move |(x, y)| Cross::new((x + 10, y), 5, colour.stroke_width(2)));
        }
        // Residuals of the LEDs in the fit, magnified from the fitted point (a left-out
        // LED's cross and circle show its disagreement at true scale).
        chart
            .draw_series(
                points
                    .iter()
                    .filter(|p| p.status == LedStatus::Used)
                    .map(|p| {
                        let tip = (
                            p.fitted.0 + gain * (p.corrected.0 - p.fitted.0),
                            p.fitted.1 + gain * (p.corrected.1 - p.fitted.1),
                        );
                        PathElement::new(vec![p.fitted, tip], palette::VERMILION.stroke_width(2))
                    }),
            )?
            .label(format!(
                "residual of a used LED (measured − fitted) ×{gain:.0}"
            ))
            .legend(|(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 20, y)],
                    palette::VERMILION.stroke_width(2),
                )
            });
        super::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    }
}

/// The fitted array against the nominal one in the illumination plane, with the LEDs
/// of the calibration marked by what became of them and the bright-field disc.
pub struct LedGrid<'a> {
    /// The calibration.
    pub cal: &'a Calibration,
    /// The nominal array.
    pub nominal: &'a LedGeometry,
    /// The optics (the bright-field disc).
    pub system: &'a System,
}

impl Chart for LedGrid<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let fitted = self.cal.geometry(self.nominal);
        let bright_radius = bright_field_radius_mm(self.system.na, fitted.height_mm);
        let in_cal: Vec<(f64, f64)> = self
            .cal
            .leds
            .iter()
            .map(|l| fitted.led_position_mm(l.led))
            .collect();
        let reach = in_cal
            .iter()
            .map(|p| p.0.abs().max(p.1.abs()))
            .fold(bright_radius, f64::max)
            + 1.5 * self.nominal.pitch_mm;
        let ranges = super::square_with_legend_room((-reach, reach), (-reach, reach));
        let ((x0, x1), (y0, y1)) = ranges;
        let mut chart = super::plane(
            area,
            Some("LED array: fitted against nominal (illumination plane)"),
            ranges,
            super::LED_PLANE_AXES,
        )?;
        let visible = |p: &(f64, f64)| (x0..=x1).contains(&p.0) && (y0..=y1).contains(&p.1);
        let leds = self.nominal.leds();
        chart
            .draw_series(
                leds.iter()
                    .map(|&l| self.nominal.led_position_mm(l))
                    .filter(visible)
                    .map(|p| Circle::new(p, 4, palette::GREY.stroke_width(1))),
            )?
            .label("nominal grid")
            .legend(|(x, y)| Circle::new((x + 10, y), 4, palette::GREY.stroke_width(1)));
        chart
            .draw_series(
                leds.iter()
                    .map(|&l| fitted.led_position_mm(l))
                    .filter(visible)
                    .map(|p| Circle::new(p, 2, palette::BLUE.filled())),
            )?
            .label(format!(
                "fitted: Δx {:+.3} mm, Δy {:+.3} mm, θ {:+.2}°, h {:.2} mm",
                self.cal.placement.dx_mm,
                self.cal.placement.dy_mm,
                self.cal.placement.theta_deg,
                self.cal.placement.height_mm
            ))
            .legend(|(x, y)| Circle::new((x + 10, y), 3, palette::BLUE.filled()));
        super::draw_bright_field_disc(
            &mut chart,
            bright_radius,
            format!(
                "bright-field inside: NA {:.2} at h {:.1} mm",
                self.system.na, fitted.height_mm
            ),
        )?;
        for status in ALL_STATUSES {
            let of: Vec<(f64, f64)> = self
                .cal
                .leds
                .iter()
                .zip(&in_cal)
                .filter(|(l, _)| l.status == status)
                .map(|(_, &p)| p)
                .collect();
            if of.is_empty() {
                continue;
            }
            let colour = status_colour(status);
            chart
                .draw_series(of.iter().map(|&p| {
                    Rectangle::new(
                        square(p, 0.18 * self.nominal.pitch_mm),
                        colour.stroke_width(2),
                    )
                }))?
                .label(format!(
                    "calibration LED, {} ({})",
                    status_label(status),
                    of.len()
                ))
                .legend(move |(x, y)| {
                    Rectangle::new([(x + 5, y - 5), (x + 15, y + 5)], colour.stroke_width(2))
                });
        }
        super::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    }
}

fn square((x, y): (f64, f64), half: f64) -> [(f64, f64); 2] {
    [(x - half, y - half), (x + half, y + half)]
}

/// Draw the residual chart to `path` (SVG for `.svg`, else PNG); returns how many
/// times the residuals are magnified on it.
pub fn write_residual_plot(
    cal: &fpm_physics::calibrate::Calibration,
    system: &fpm_physics::System,
    path: &std::path::Path,
) -> anyhow::Result<f64> {
    let chart = Residuals { cal, system };
    crate::charts::Figure::render(&chart)?.write_as(path)?;
    Ok(chart.gain())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_gains_are_round_numbers() {
        assert_eq!(nice_gain(365.0), 200.0);
        assert_eq!(nice_gain(560.0), 500.0);
        assert_eq!(nice_gain(0.3), 1.0);
        assert_eq!(nice_gain(f64::INFINITY), 1.0);
    }
}
