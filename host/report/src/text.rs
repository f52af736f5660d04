//! Text and filled rectangles on 8-bit grey pictures (scale bars, colour bars,
//! comparison panels), in the embedded DejaVu Sans the charts use, anti-aliased.

use std::sync::OnceLock;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};

/// The font, parsed once; None only if the embedded font could not be read (then text
/// is left out and the picture is still written).
fn font() -> Option<&'static FontRef<'static>> {
    static FONT: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::try_from_slice(dejavu::sans::bold()).ok())
        .as_ref()
}

/// The font size at `scale`, pixels: `scale` 1 is small print on a 120-pixel picture.
fn px(scale: usize) -> PxScale {
    PxScale::from(10.0 * scale as f32)
}

/// Height of a line of text at `scale`, pixels (ascent to descent).
pub fn height(scale: usize) -> usize {
    font().map_or(0, |f| {
        let f = f.as_scaled(px(scale));
        (f.ascent() - f.descent()).ceil() as usize
    })
}

/// Width of `text` at `scale`, pixels.
pub fn width(text: &str, scale: usize) -> usize {
    font().map_or(0, |f| {
        let f = f.as_scaled(px(scale));
        text.chars()
            .map(|c| f.h_advance(f.glyph_id(c)))
            .sum::<f32>()
            .ceil() as usize
    })
}

/// Set the `(w, h)` rectangle at `(x, y)` of the grey image `pixels` (`width × height`)
/// to `value`, clipped to the image.
pub fn fill(
    pixels: &mut [u8],
    width: usize,
    height: usize,
    (x, y): (usize, usize),
    (w, h): (usize, usize),
    value: u8,
) {
    for row in y..(y + h).min(height) {
        for col in x..(x + w).min(width) {
            pixels[row * width + col] = value;
        }
    }
}

/// Draw `text` with the top-left corner of its line at `(x, y)` at `scale`, in grey
/// `value` blended over what is there by the glyphs' coverage, clipped to the image.
pub fn draw(
    pixels: &mut [u8],
    width: usize,
    height: usize,
    (x, y): (usize, usize),
    text: &str,
    scale: usize,
    value: u8,
) {
    let Some(font) = font() else { return };
    let f = font.as_scaled(px(scale));
    let mut pen = x as f32;
    let baseline = y as f32 + f.ascent();
    for c in text.chars() {
        let glyph = f
            .glyph_id(c)
            .with_scale_and_position(px(scale), ab_glyph::point(pen, baseline));
        pen += f.h_advance(glyph.id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let bounds = outline.px_bounds();
        outline.draw(|gx, gy, coverage| {
            let (col, row) = (
                bounds.min.x as i64 + gx as i64,
                bounds.min.y as i64 + gy as i64,
            );
            if col < 0 || row < 0 || col as usize >= width || row as usize >= height {
                return;
            }
            let p = &mut pixels[row as usize * width + col as usize];
            let c = coverage.clamp(0.0, 1.0);
            *p = (*p as f32 * (1.0 - c) + value as f32 * c).round() as u8;
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every character of the labels in use has an outline (none drawn blank).
    #[test]
    fn every_label_character_is_drawn() {
        for text in [
            "Truth",
            "Nominal",
            "Calibrated",
            "Amplitude",
            "Phase",
            "rad",
            "0123456789.-µm",
        ] {
            for c in text.chars() {
                let mut img = vec![0u8; 40 * 40];
                draw(&mut img, 40, 40, (4, 4), &c.to_string(), 2, 255);
                assert!(img.iter().any(|&v| v > 128), "{c:?} of {text} drew nothing");
            }
        }
    }

    #[test]
    fn text_is_clipped_to_the_image_and_measured() {
        let mut img = vec![0u8; 20 * 10];
        draw(&mut img, 20, 10, (15, 5), "88", 2, 255);
        assert!(img.contains(&255) || img.iter().any(|&v| v > 100));
        assert!(width("888", 1) > width("8", 1));
        assert!(height(2) > height(1));
    }
}
