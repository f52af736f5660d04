//! Plots a person can read, drawn with `plotters`: each chart is drawn once per
//! backend, into a PNG (text from the embedded DejaVu Sans, so no system fonts are
//! needed) and into an SVG (text left to the viewer's fonts).
//!
//! A chart is a [`Chart`]: a pure function from its data to drawing calls on any
//! backend. [`Figure::render`] runs it on both backends; the callers write the files
//! or embed the PNG in an HTML report.

pub mod acquisition;
pub mod calibration;
pub mod reconstruction;

use std::path::Path;
use std::sync::Once;

use anyhow::{anyhow, Context, Result};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

/// The font family every chart uses.
pub const FONT: &str = "sans-serif";

/// Palette shared by the charts (colour-blind safe: Okabe–Ito).
pub mod palette {
    use plotters::style::RGBColor;
    /// Used, in the fit, calibrated.
    pub const BLUE: RGBColor = RGBColor(0, 114, 178);
    /// Near the pupil edge.
    pub const ORANGE: RGBColor = RGBColor(230, 159, 0);
    /// Outliers, residuals.
    pub const VERMILION: RGBColor = RGBColor(213, 94, 0);
    /// Feature lost, saturated.
    pub const PURPLE: RGBColor = RGBColor(204, 121, 167);
    /// Bright-field region, the NA circle.
    pub const GREEN: RGBColor = RGBColor(0, 158, 115);
    /// Nominal, context.
    pub const GREY: RGBColor = RGBColor(150, 150, 150);
    /// Dark-field.
    pub const DARK: RGBColor = RGBColor(60, 60, 60);
}

/// Something that can draw itself on any plotters backend.
pub trait Chart {
    /// Canvas size, pixels (PNG) or user units (SVG); the plane charts' by default.
    fn size(&self) -> (u32, u32) {
        (760, 700)
    }
    /// Draw onto `area` (already cleared to white).
    fn draw<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>;
}

/// A drawn chart: PNG bytes and SVG text.
pub struct Figure {
    /// The PNG file's bytes.
    pub png: Vec<u8>,
    /// The SVG document.
    pub svg: String,
}

impl Figure {
    /// Draw `chart` on both backends.
    pub fn render(chart: &impl Chart) -> Result<Self> {
        register_font();
        let (w, h) = chart.size();
        let mut rgb = vec![255u8; w as usize * h as usize * 3];
        {
            let area = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
            area.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
            chart.draw(&area).map_err(|e| anyhow!("drawing: {e}"))?;
            area.present().map_err(|e| anyhow!("{e}"))?;
        }
        let mut svg = String::new();
        {
            let area = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
            area.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
            chart.draw(&area).map_err(|e| anyhow!("drawing: {e}"))?;
            area.present().map_err(|e| anyhow!("{e}"))?;
        }
        Ok(Self {
            png: encode_png_rgb(w, h, &rgb)?,
            svg,
        })
    }

    /// Write `stem.png` and `stem.svg` into `dir`.
    pub fn write(&self, dir: &Path, stem: &str) -> Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for (ext, bytes) in [("png", &self.png[..]), ("svg", self.svg.as_bytes())] {
            let path = dir.join(format!("{stem}.{ext}"));
            std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
        }
        Ok(())
    }

    /// Write the PNG or the SVG to `path`, by its extension (`.svg`, else PNG).
    pub fn write_as(&self, path: &Path) -> Result<()> {
        let svg = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
        let bytes = if svg { self.svg.as_bytes() } else { &self.png };
        std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
    }
}

/// PNG bytes of an 8-bit RGB image.
pub fn encode_png_rgb(width: u32, height: u32, rgb: &[u8]) -> Result<Vec<u8>> {
    let mut bytes = vec![];
    let mut enc = png::Encoder::new(&mut bytes, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(rgb)?;
    w.finish()?;
    Ok(bytes)
}

/// Give the PNG backend its font (once per process).
fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for (style, bytes) in [
            (FontStyle::Normal, dejavu::sans::regular()),
            (FontStyle::Bold, dejavu::sans::bold()),
        ] {
            if plotters::style::register_font(FONT, style, bytes).is_err() {
                tracing::warn!("the embedded DejaVu Sans did not load: PNG charts lose their text");
            }
        }
    });
}

/// Axis-range helper: `[lo, hi]` widened by `margin` of its span (or by 1 when empty).
pub fn padded(lo: f64, hi: f64, margin: f64) -> (f64, f64) {
    let span = hi - lo;
    if !(span.is_finite() && span > 0.0) {
        let c = if lo.is_finite() { lo } else { 0.0 };
        return (c - 1.0, c + 1.0);
    }
    (lo - margin * span, hi + margin * span)
}

/// Square axis ranges (the same span on x and y, so directions and circles are true)
/// around data within `xs` and `ys`, padded, with the top fifth left empty for the
/// legend.
pub fn square_with_legend_room(xs: (f64, f64), ys: (f64, f64)) -> ((f64, f64), (f64, f64)) {
    let span = (xs.1 - xs.0).max(ys.1 - ys.0);
    let span = if span.is_finite() && span > 0.0 {
        span
    } else {
        2.0
    };
    let half = 0.5 * 1.12 * span;
    let (cx, cy) = (0.5 * (xs.0 + xs.1), 0.5 * (ys.0 + ys.1));
    let room = 0.25 * span;
    (
        (cx - half - room / 2.0, cx + half + room / 2.0),
        (cy - half, cy + half + room),
    )
}

/// Points of a circle of `radius` about the origin, for outlines.
pub fn circle_path(radius: f64) -> Vec<(f64, f64)> {
    (0..=180)
        .map(|k| {
            let a = k as f64 / 180.0 * std::f64::consts::TAU;
            (radius * a.cos(), radius * a.sin())
        })
        .collect()
}

/// A plane chart in mm or µm.
pub type Plane<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// A square plane chart on `area` over `ranges` ((x0, x1), (y0, y1)), with a bold
/// `caption` (if any), light grid and the axes described by `descs` (x, y).
pub fn plane<'a, DB: DrawingBackend + 'a>(
    area: &'a DrawingArea<DB, Shift>,
    caption: Option<&str>,
    ((x0, x1), (y0, y1)): ((f64, f64), (f64, f64)),
    (x_desc, y_desc): (&str, &str),
) -> Result<Plane<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    let mut builder = ChartBuilder::on(area);
    if let Some(caption) = caption {
        builder.caption(caption, (FONT, 20).into_font().style(FontStyle::Bold));
    }
    let mut chart = builder
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style((FONT, 15))
        .label_style((FONT, 13))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    Ok(chart)
}

/// The axes of the illumination plane.
pub const LED_PLANE_AXES: (&str, &str) = ("x (mm, from the optical axis)", "y (mm)");

/// Radius in the LED plane, mm, inside which an LED at height `height_mm` is
/// bright-field for an objective of numerical aperture `na` (on axis).
pub fn bright_field_radius_mm(na: f64, height_mm: f64) -> f64 {
    height_mm * na.clamp(0.0, 0.999).asin().tan()
}

/// Draw the disc inside which LEDs are bright-field (`radius`, mm) with its legend.
pub fn draw_bright_field_disc<'a, DB: DrawingBackend + 'a>(
    chart: &mut Plane<'a, DB>,
    radius: f64,
    label: String,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .draw_series(std::iter::once(PathElement::new(
            circle_path(radius),
            palette::GREEN.stroke_width(2),
        )))?
        .label(label)
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], palette::GREEN.stroke_width(2))
        });
    Ok(())
}

/// Draw the legend of `chart`'s labelled series at `position`.
pub fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(palette::GREY)
        .label_font((FONT, 13))
        .draw()
}

/// A cyclic colour for a phase in radians (hue around the circle), for phase maps.
pub fn phase_colour(phase: f64) -> RGBColor {
    let hue = (phase.rem_euclid(std::f64::consts::TAU)) / std::f64::consts::TAU;
    let (r, g, b) = HSLColor(hue, 0.75, 0.5).rgb();
    RGBColor(r, g, b)
}

/// A grey for a value in [0, 1] (clamped).
pub fn grey(value: f64) -> RGBColor {
    let v = (value.clamp(0.0, 1.0) * 255.0).round() as u8;
    RGBColor(v, v, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Cross;
    impl Chart for Cross {
        fn size(&self) -> (u32, u32) {
            (200, 120)
        }
        fn draw<DB: DrawingBackend>(
            &self,
            area: &DrawingArea<DB, Shift>,
        ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
            let mut chart = ChartBuilder::on(area)
                .caption("shift (µm)", (FONT, 16))
                .x_label_area_size(20)
                .y_label_area_size(30)
                .build_cartesian_2d(0.0..1.0, 0.0..1.0)?;
            chart.configure_mesh().draw()?;
            chart.draw_series(LineSeries::new([(0.0, 0.0), (1.0, 1.0)], &BLACK))?;
            Ok(())
        }
    }

    #[test]
    fn a_chart_renders_to_png_with_text_and_to_svg() {
        let f = Figure::render(&Cross).unwrap();
        let decoder = png::Decoder::new(std::io::Cursor::new(&f.png));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (200, 120));
        // The caption's glyphs put dark pixels into the top rows (the font loaded).
        let top_dark = buf[..200 * 3 * 18].iter().filter(|&&v| v < 128).count();
        assert!(top_dark > 20, "no text drawn in the caption: {top_dark}");
        assert!(f.svg.contains("<svg") && f.svg.contains("shift (µm)"));
    }

    #[test]
    fn the_bright_field_disc_follows_na_and_height() {
        let r = bright_field_radius_mm(0.1, 60.0);
        assert!((r - 60.0 * 0.1 / (1.0f64 - 0.01).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn ranges_are_padded_and_never_empty() {
        assert_eq!(padded(0.0, 10.0, 0.1), (-1.0, 11.0));
        assert_eq!(padded(3.0, 3.0, 0.1), (2.0, 4.0));
        assert_eq!(padded(f64::NAN, f64::NAN, 0.1), (-1.0, 1.0));
    }
}
