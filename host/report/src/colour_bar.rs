//! A grey colour bar for 8-bit grey previews: a strip appended on the right with the
//! grey ramp from `lo` (black, bottom) to `hi` (white, top), its end and middle values
//! and the unit, so a phase preview can be read in radians.

use crate::text;

/// The image `pixels` (`width × height`, row-major) with the colour bar appended on the
/// right; returns the new pixels and width. Images too small for legible labels come
/// back unchanged.
pub fn append(
    pixels: &[u8],
    width: usize,
    height: usize,
    (lo, hi): (f32, f32),
    unit: &str,
) -> (Vec<u8>, usize) {
    let s = (width.min(height) / 120).max(1);
    let labels = [hi, 0.5 * (lo + hi), lo].map(|v| format!("{v:.2}"));
    let text_w = labels
        .iter()
        .map(|l| text::width(l, s))
        .chain([text::width(unit, s)])
        .max()
        .unwrap_or(0);
    let glyph_h = text::height(s);
    let margin = 3 * s;
    let bar_w = 6 * s;
    let strip = margin + bar_w + margin + text_w + margin;
    let (top, bottom) = (margin + glyph_h + margin, height.saturating_sub(margin));
    if bottom <= top + 3 * glyph_h || height < 48 {
        return (pixels.to_vec(), width);
    }
    let new_w = width + strip;
    let mut out = vec![255u8; new_w * height];
    for row in 0..height {
        out[row * new_w..row * new_w + width]
            .copy_from_slice(&pixels[row * width..(row + 1) * width]);
    }
    // The ramp: white at the top, black at the bottom, inside a one-pixel black frame.
    let bar_x = width + margin;
    let span = (bottom - top - 1).max(1) as f32;
    for row in top..bottom {
        let value = (255.0 * (1.0 - (row - top) as f32 / span)).round() as u8;
        text::fill(&mut out, new_w, height, (bar_x, row), (bar_w, 1), value);
    }
    for (at, size) in [
        ((bar_x - 1, top - 1), (bar_w + 2, 1)),
        ((bar_x - 1, bottom), (bar_w + 2, 1)),
        ((bar_x - 1, top - 1), (1, bottom - top + 2)),
        ((bar_x + bar_w, top - 1), (1, bottom - top + 2)),
    ] {
        text::fill(&mut out, new_w, height, at, size, 0);
    }
    // The unit above the bar, the values beside its top, middle and bottom.
    text::draw(&mut out, new_w, height, (bar_x, margin), unit, s, 0);
    let text_x = bar_x + bar_w + margin;
    let rows = [top, (top + bottom) / 2 - glyph_h / 2, bottom - glyph_h];
    for (label, y) in labels.iter().zip(rows) {
        text::draw(&mut out, new_w, height, (text_x, y), label, s, 0);
    }
    (out, new_w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_ramp_runs_from_white_at_the_top_to_black_at_the_bottom() {
        let (w, h) = (256, 256);
        let img = vec![128u8; w * h];
        let pi = std::f32::consts::PI;
        let (out, new_w) = append(&img, w, h, (-pi, pi), "rad");
        assert!(new_w > w + 20);
        // The image is kept as it was.
        assert!((0..h).all(|y| out[y * new_w..y * new_w + w].iter().all(|&v| v == 128)));
        // Down the middle of the ramp the grey falls monotonically from 255 to 0.
        let s = 2;
        let x = w + 3 * s + 3 * s;
        let column: Vec<u8> = (0..h).map(|y| out[y * new_w + x]).collect();
        // Below the black frame's top line (under the unit's label), down to the bottom.
        let top = 3 * s + text::height(s) + 3 * s - 1;
        assert_eq!(column[top], 0, "the frame's top line");
        let inside: Vec<u8> = column[top + 1..]
            .iter()
            .copied()
            .take_while(|&v| v != 0)
            .chain([0])
            .collect();
        assert_eq!(inside[0], 255, "white at the top");
        assert!(inside.len() > h / 2, "ramp of {} rows", inside.len());
        assert!(inside.windows(2).all(|p| p[1] <= p[0]));
        // A tiny image is left alone.
        let (same, same_w) = append(&[9u8; 16 * 16], 16, 16, (0.0, 1.0), "rad");
        assert_eq!((same_w, same.len()), (16, 256));
    }
}
