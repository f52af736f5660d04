//! The reconstruction's charts: the error per pass (per tile), the recovered pupil
//! with the objective's NA circle, and the LED positions the wave vectors came from.

use fpm_physics::{LedGeometry, System};
use ndarray::Array2;
use plotters::coord::Shift;
use plotters::prelude::*;
use rustfft::num_complex::Complex32;

use super::{grey, padded, palette, phase_colour, Chart, FONT};
use fpm_host::reconstruction::Report;

/// Relative amplitude error of the frames after each pass: every tile thin, their mean
/// bold.
pub struct ErrorPerPass<'a> {
    /// The run's report.
    pub report: &'a Report,
}

impl Chart for ErrorPerPass<'_> {
    fn size(&self) -> (u32, u32) {
        (760, 480)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let r = self.report;
        let finite = |v: &&f64| v.is_finite() && **v > 0.0;
        let all: Vec<f64> = r
            .tiles
            .iter()
            .flat_map(|t| t.error_per_pass.iter())
            .chain(&r.error_per_pass)
            .filter(finite)
            .copied()
            .collect();
        let lo = all.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = all.iter().copied().fold(0.0, f64::max);
        // Linear: the errors of a run span a few times, not decades.
        let (lo, hi) = if all.is_empty() {
            (0.0, 1.0)
        } else {
            padded(lo, hi, 0.15)
        };
        let lo = lo.max(0.0);
        // Enough decimals that ten ticks over the range read apart.
        let digits = (-((hi - lo) / 10.0).log10()).ceil().clamp(2.0, 6.0) as usize;
        let passes = r.passes.max(1) as f64;
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!(
                    "Convergence: {} frame(s), {} tile(s), {}× upsampling",
                    r.frames,
                    r.tiles.len(),
                    r.upsample
                ),
                (FONT, 20).into_font().style(FontStyle::Bold),
            )
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(0.5..passes + 0.5, lo..hi)?;
        chart
            .configure_mesh()
            .x_desc("pass")
            .y_desc("relative amplitude error of the frames")
            .axis_desc_style((FONT, 15))
            .label_style((FONT, 13))
            .x_labels(r.passes.clamp(2, 12))
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.digits$}"))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        let line = |errors: &[f64]| -> Vec<(f64, f64)> {
            errors
                .iter()
                .enumerate()
                .filter(|(_, e)| e.is_finite() && **e > 0.0)
                .map(|(k, &e)| ((k + 1) as f64, e))
                .collect()
        };
        if r.tiles.len() > 1 {
            let mut first = true;
            for t in &r.tiles {
                let series = chart.draw_series(LineSeries::new(
                    line(&t.error_per_pass),
                    palette::GREY.stroke_width(1),
                ))?;
                if first {
                    series
                        .label(format!("each of the {} tiles", r.tiles.len()))
                        .legend(|(x, y)| {
                            PathElement::new(
                                vec![(x, y), (x + 20, y)],
                                palette::GREY.stroke_width(1),
                            )
                        });
                    first = false;
                }
            }
        }
        chart
            .draw_series(
                LineSeries::new(line(&r.error_per_pass), palette::BLUE.stroke_width(3))
                    .point_size(4),
            )?
            .label(if r.tiles.len() > 1 {
                "mean over tiles"
            } else {
                "the whole field"
            })
            .legend(|(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], palette::BLUE.stroke_width(3))
            });
        super::draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        Ok(())
    }
}

/// The recovered pupil, amplitude and phase, in units of NA (spatial frequency × λ),
/// with the objective's NA circle and a colour bar for the phase.
pub struct Pupil<'a> {
    /// Centred pupil of one tile (zero frequency at the middle).
    pub pupil: &'a Array2<Complex32>,
    /// The optics.
    pub system: &'a System,
}

/// Cells per side of the drawn pupil maps (the pupil is sampled onto them).
const PUPIL_CELLS: usize = 64;

impl Pupil<'_> {
    /// NA units per pupil bin along (x, y).
    fn bin_na(&self) -> (f64, f64) {
        let (h, w) = self.pupil.dim();
        let dx = self.system.sample_pixel_um();
        let lambda = self.system.wavelength_um;
        (lambda / (w as f64 * dx), lambda / (h as f64 * dx))
    }

    /// The pupil at (`nx`, `ny`) in NA units, nearest bin (zero outside the array).
    fn at(&self, nx: f64, ny: f64) -> Complex32 {
        let (h, w) = self.pupil.dim();
        let (bx, by) = self.bin_na();
        let col = (nx / bx).round() as i64 + (w / 2) as i64;
        let row = (ny / by).round() as i64 + (h / 2) as i64;
        if col < 0 || row < 0 || col >= w as i64 || row >= h as i64 {
            return Complex32::new(0.0, 0.0);
        }
        self.pupil[[row as usize, col as usize]]
    }
}

impl Chart for Pupil<'_> {
    fn size(&self) -> (u32, u32) {
        (900, 470)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let na = self.system.na;
        let reach = 1.3 * na;
        let cell = 2.0 * reach / PUPIL_CELLS as f64;
        let centres: Vec<f64> = (0..PUPIL_CELLS)
            .map(|k| -reach + (k as f64 + 0.5) * cell)
            .collect();
        let samples: Vec<((f64, f64), Complex32)> = centres
            .iter()
            .flat_map(|&y| centres.iter().map(move |&x| (x, y)))
            .map(|(x, y)| ((x, y), self.at(x, y)))
            .collect();
        let peak = samples
            .iter()
            .map(|(_, c)| c.norm() as f64)
            .fold(0.0, f64::max)
            .max(f64::MIN_POSITIVE);
        let (title, body) = area.split_vertically(40);
        title.titled(
            &format!("Recovered pupil (one tile), objective NA {na:.2}"),
            (FONT, 20).into_font().style(FontStyle::Bold),
        )?;
        let (maps, bar) = body.split_horizontally(770);
        let panels = maps.split_evenly((1, 2));
        let circle = super::circle_path(na);
        for (panel, phase) in panels.iter().zip([false, true]) {
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    if phase {
                        "phase (rad)"
                    } else {
                        "amplitude (relative)"
                    },
                    (FONT, 15),
                )
                .margin(8)
                .x_label_area_size(38)
                .y_label_area_size(52)
                .build_cartesian_2d(-reach..reach, -reach..reach)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("NA x")
                .y_desc("NA y")
                .axis_desc_style((FONT, 13))
                .label_style((FONT, 11))
                .x_labels(5)
                .y_labels(5)
                .draw()?;
            chart.draw_series(samples.iter().map(|&((x, y), c)| {
                let a = c.norm() as f64 / peak;
                let colour = if !phase {
                    grey(a)
                } else if a < 0.05 {
                    WHITE
                } else {
                    phase_colour(c.arg() as f64)
                };
                let h = cell / 2.0;
                Rectangle::new([(x - h, y - h), (x + h, y + h)], colour.filled())
            }))?;
            chart.draw_series(std::iter::once(PathElement::new(
                circle.clone(),
                palette::GREEN.stroke_width(2),
            )))?;
        }
        // The phase colour bar, −π at the bottom to +π at the top.
        let mut scale = ChartBuilder::on(&bar)
            .margin_top(34)
            .margin_bottom(46)
            .margin_right(40)
            .y_label_area_size(62)
            .build_cartesian_2d(0.0..1.0, -std::f64::consts::PI..std::f64::consts::PI)?;
        scale
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("phase (rad)")
            .axis_desc_style((FONT, 12))
            .label_style((FONT, 11))
            .y_labels(7)
            .y_label_formatter(&|y| format!("{y:.1}"))
            .draw()?;
        let steps = 64;
        let step = std::f64::consts::TAU / steps as f64;
        scale.draw_series((0..steps).map(|k| {
            let p = -std::f64::consts::PI + k as f64 * step;
            Rectangle::new(
                [(0.0, p), (1.0, p + step)],
                phase_colour(p + step / 2.0).filled(),
            )
        }))?;
        Ok(())
    }
}

/// The LED positions the wave vectors came from against the nominal grid, in the
/// illumination plane, with the bright-field disc.
pub struct LedPositions<'a> {
    /// The dataset's nominal array.
    pub nominal: &'a LedGeometry,
    /// The array used (calibrated, stored on the board, or the nominal itself).
    pub used: &'a LedGeometry,
    /// Where `used` came from.
    pub source: &'a str,
    /// The optics.
    pub system: &'a System,
}

impl Chart for LedPositions<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        let leds = self.nominal.leds();
        let nominal: Vec<(f64, f64)> = leds
            .iter()
            .map(|&l| self.nominal.led_position_mm(l))
            .collect();
        let used: Vec<(f64, f64)> = leds.iter().map(|&l| self.used.led_position_mm(l)).collect();
        let (lo, hi) = nominal
            .iter()
            .chain(&used)
            .flat_map(|p| [p.0, p.1])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let bright = super::bright_field_radius_mm(self.system.na, self.used.height_mm);
        let mut chart = super::plane(
            area,
            Some("LED positions used for the wave vectors"),
            super::square_with_legend_room((lo, hi), (lo, hi)),
            super::LED_PLANE_AXES,
        )?;
        chart
            .draw_series(
                nominal
                    .iter()
                    .map(|&p| Circle::new(p, 5, palette::GREY.stroke_width(1))),
            )?
            .label("nominal (dataset.toml)")
            .legend(|(x, y)| Circle::new((x + 10, y), 5, palette::GREY.stroke_width(1)));
        let g = self.used;
        chart
            .draw_series(
                used.iter()
                    .map(|&p| Cross::new(p, 4, palette::BLUE.stroke_width(2))),
            )?
            .label(format!(
                "used, {}: Δx {:+.3} mm, Δy {:+.3} mm, θ {:+.2}°, h {:.2} mm",
                self.source, g.dx_mm, g.dy_mm, g.theta_deg, g.height_mm
            ))
            .legend(|(x, y)| Cross::new((x + 10, y), 4, palette::BLUE.stroke_width(2)));
        super::draw_bright_field_disc(
            &mut chart,
            bright,
            format!("bright-field inside (NA {:.2})", self.system.na),
        )?;
        super::draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    }
}
