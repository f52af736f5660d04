//! A scale bar for image previews: a bar of a round length in µm with its label, drawn
//! into the bottom-left corner on a dark plate so it reads on any image.

use crate::text;

/// The bar's length, µm: the largest 1, 2 or 5 × 10ᵏ that is at most a fifth of
/// `field_um` (None for a field that is not a positive length).
pub fn bar_length_um(field_um: f64) -> Option<f64> {
    if !(field_um.is_finite() && field_um > 0.0) {
        return None;
    }
    let target = field_um / 5.0;
    let decade = 10f64.powf(target.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|&l| l <= target * (1.0 + 1e-9))
}

/// The label of a bar `length_um` long ("50 µm", "0.5 µm").
pub fn label(length_um: f64) -> String {
    if length_um >= 1.0 {
        format!("{length_um:.0} µm")
    } else {
        let text = format!("{length_um:.3}");
        format!("{} µm", text.trim_end_matches('0'))
    }
}

/// Draw a scale bar into the 8-bit grey image `pixels` (`width × height`, row-major)
/// whose pixels are `pixel_um` apart in the sample plane. Images too small for a
/// legible bar are left as they are.
pub fn draw(pixels: &mut [u8], width: usize, height: usize, pixel_um: f64) {
    let Some(length_um) = bar_length_um(width as f64 * pixel_um) else {
        return;
    };
    let bar = (length_um / pixel_um).round() as usize;
    let text = label(length_um);
    // Glyph scale: about 1/60 of the shorter side per glyph height.
    let s = (width.min(height) / 120).max(1);
    let glyph_h = text::height(s);
    let text_w = text::width(&text, s);
    let margin = 2 * s;
    let plate_w = bar.max(text_w) + 2 * margin;
    let plate_h = glyph_h + 3 * margin + 2 * s;
    if plate_w + margin > width || plate_h + margin > height || bar < 4 {
        return;
    }
    let (x0, y0) = (margin, height - margin - plate_h);
    text::fill(pixels, width, height, (x0, y0), (plate_w, plate_h), 0);
    // The label, then the bar under it.
    let (tx, ty) = (x0 + margin, y0 + margin);
    text::draw(pixels, width, height, (tx, ty), &text, s, 255);
    let by = ty + glyph_h + margin;
    text::fill(pixels, width, height, (tx, by), (bar, 2 * s), 255);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bar_is_a_round_length_near_a_fifth_of_the_field() {
        assert_eq!(bar_length_um(307.2), Some(50.0));
        assert_eq!(bar_length_um(1000.0), Some(200.0));
        assert_eq!(bar_length_um(40.0), Some(5.0));
        assert_eq!(bar_length_um(4.0), Some(0.5));
        assert_eq!(bar_length_um(0.0), None);
        assert_eq!(label(50.0), "50 µm");
        assert_eq!(label(0.5), "0.5 µm");
    }

    /// The bar is drawn white, exactly as long as its length in pixels, on a dark plate
    /// in the bottom-left corner; the rest of the image is untouched.
    #[test]
    fn the_bar_spans_its_length_in_pixels() {
        let (w, h, pixel_um) = (512, 384, 0.15);
        let mut img = vec![128u8; w * h];
        draw(&mut img, w, h, pixel_um);
        // 76.8 µm wide: a 10 µm bar, 66.7 → 67 pixels, in the lowest white rows
        // (the label is above it).
        let white = |y: usize| {
            img[y * w..(y + 1) * w]
                .iter()
                .filter(|&&v| v == 255)
                .count()
        };
        let last = (0..h).rev().find(|&y| white(y) > 0).unwrap();
        assert_eq!(white(last), (10.0 / pixel_um).round() as usize);
        assert!(last > h * 3 / 4, "bar at row {last}");
        assert!(
            img[..w * h / 2].iter().all(|&v| v == 128),
            "top half untouched"
        );
        // Too small an image: left alone.
        let mut tiny = vec![7u8; 16 * 16];
        draw(&mut tiny, 16, 16, 1.0);
        assert!(tiny.iter().all(|&v| v == 7));
    }
}
