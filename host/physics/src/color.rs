//! Colour from RGB LEDs: each colour channel is a light of its own wavelength band,
//! from its own die of the LED package, so it has its own LED positions and (through
//! the objective's chromatic focal shift) its own pupil. A colour acquisition is one
//! single-wavelength acquisition per channel; this module holds what the channels
//! differ by, and the sample's colour for the simulator.
//!
//! The WS2812B datasheets give dominant wavelengths of R 620–625, G 522–525 and
//! B 465–467 nm; the Waller lab's FPM code assumes 624.4, 518.0 and 476.4 nm. We take
//! the datasheets' middles for red and green (622.5, 523.5 nm) and, for blue, the
//! 470 nm every single-colour acquisition of this project has assumed (between the
//! datasheets and the Waller lab's), with typical AlInGaP/InGaN LED widths (FWHM 18,
//! 33, 25 nm); a user's own values replace them (`--colors red:0.630`, the dataset's
//! `wavelength_um`).

use ndarray::{Array2, ArrayView2};
use rustfft::num_complex::Complex32;
use serde::{Deserialize, Serialize};

use crate::fft::Fft2;

/// One colour channel of an RGB LED, as the simulator lights it and a dataset states it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Channel {
    /// Its name (`red`, `green`, `blue` or a user's own).
    pub name: String,
    /// Central (dominant) wavelength, µm.
    pub wavelength_um: f64,
    /// Full width at half maximum of the LED's spectrum, nm (0: a laser line).
    pub fwhm_nm: f64,
    /// Where this colour's die sits in the LED package, relative to the package's
    /// nominal place (which the board's grid gives), mm in the board's own axes (it
    /// turns with the board).
    pub die_offset_mm: [f64; 2],
    /// The objective's focal shift at this wavelength (chromatic defocus), µm, toward
    /// the LEDs positive as a dataset's `defocus_um`.
    pub focal_shift_um: f64,
}

/// The WS2812B's colours with the die layout we assume for a 5050 package: the three
/// dies in a row along the board's x, 0.7 mm apart, green in the middle, and an
/// achromat's focal shift of a few µm (red behind, blue in front).
pub fn ws2812b() -> Vec<Channel> {
    vec![
        Channel {
            name: "red".into(),
            wavelength_um: nm(622.5),
            fwhm_nm: 18.0,
            die_offset_mm: [-0.7, 0.0],
            focal_shift_um: 4.0,
        },
        Channel {
            name: "green".into(),
            wavelength_um: nm(523.5),
            fwhm_nm: 33.0,
            die_offset_mm: [0.0, 0.0],
            focal_shift_um: 0.0,
        },
        Channel {
            name: "blue".into(),
            wavelength_um: nm(470.0),
            fwhm_nm: 25.0,
            die_offset_mm: [0.7, 0.0],
            focal_shift_um: -4.0,
        },
    ]
}

/// `nanometres` in µm.
fn nm(nanometres: f64) -> f64 {
    nanometres / 1000.0
}

/// The named WS2812B channel (`red`, `green`, `blue`, or `r`, `g`, `b`).
pub fn ws2812b_channel(name: &str) -> Option<Channel> {
    let full = match name.to_ascii_lowercase().as_str() {
        "red" | "r" => "red",
        "green" | "g" => "green",
        "blue" | "b" => "blue",
        _ => return None,
    };
    ws2812b().into_iter().find(|c| c.name == full)
}

/// `items` (`red`, `green`, `blue`, or `r`, `g`, `b`, each optionally `NAME:UM`) as
/// WS2812B channels ([`ws2812b`]), with the wavelengths given; at least one, each once.
/// Errors name `what` (the flag or field) and the item.
pub fn parse_channels(items: &[String], what: &str) -> Result<Vec<Channel>, crate::Invalid> {
    let invalid = |message: String| crate::Invalid::new(what, message);
    let mut channels: Vec<Channel> = vec![];
    for item in items {
        let (name, wavelength) = match item.split_once(':') {
            Some((n, w)) => (n.trim(), Some(w.trim())),
            None => (item.trim(), None),
        };
        let mut channel = ws2812b_channel(name)
            .ok_or_else(|| invalid(format!("{what} {item}: {name:?} is not red, green or blue")))?;
        if let Some(w) = wavelength {
            channel.wavelength_um = w
                .parse::<f64>()
                .ok()
                .filter(|w| w.is_finite() && (0.2..=2.0).contains(w))
                .ok_or_else(|| {
                    invalid(format!(
                        "{what} {item}: {w:?} is not a wavelength in µm (0.2-2)"
                    ))
                })?;
        }
        if channels.iter().any(|c| c.name == channel.name) {
            return Err(invalid(format!("{what}: {} is given twice", channel.name)));
        }
        channels.push(channel);
    }
    if channels.is_empty() {
        return Err(invalid(format!(
            "{what}: name at least one colour (red, green, blue)"
        )));
    }
    Ok(channels)
}

impl Channel {
    /// Wavelengths (µm) and weights (summing to 1) that stand for the LED's spectrum:
    /// `samples` points of a Gaussian of the channel's FWHM, spread over ±1.5σ·√… so
    /// that their weighted variance is the spectrum's (one sample: the centre line).
    pub fn spectrum(&self, samples: usize) -> Vec<(f64, f64)> {
        let sigma_um = self.fwhm_nm / 2.3548 / 1000.0;
        if samples <= 1 || sigma_um <= 0.0 {
            return vec![(self.wavelength_um, 1.0)];
        }
        // Evenly spaced over ±2σ with Gaussian weights, then stretched so the discrete
        // spectrum has the Gaussian's variance exactly.
        let xs: Vec<f64> = (0..samples)
            .map(|i| -2.0 + 4.0 * i as f64 / (samples - 1) as f64)
            .collect();
        let ws: Vec<f64> = xs.iter().map(|x| (-0.5 * x * x).exp()).collect();
        let total: f64 = ws.iter().sum();
        let var: f64 = xs.iter().zip(&ws).map(|(x, w)| x * x * w).sum::<f64>() / total;
        let stretch = 1.0 / var.sqrt();
        xs.iter()
            .zip(&ws)
            .map(|(x, w)| (self.wavelength_um + x * stretch * sigma_um, w / total))
            .collect()
    }

    /// The channel's LED array: `board` with every LED moved by this colour's die
    /// offset (turned with the board).
    pub fn geometry(&self, board: &crate::LedGeometry) -> crate::LedGeometry {
        let (dx, dy) = self.die_offset_on(board);
        crate::LedGeometry {
            dx_mm: board.dx_mm + dx,
            dy_mm: board.dy_mm + dy,
            ..*board
        }
    }

    /// The die offset in the sample's axes for a board turned as `board` is, mm.
    pub fn die_offset_on(&self, board: &crate::LedGeometry) -> (f64, f64) {
        let (s, c) = board.theta_deg.to_radians().sin_cos();
        let [x, y] = self.die_offset_mm;
        (c * x - s * y, s * x + c * y)
    }
}

/// How strongly a stained sample's dye absorbs at `wavelength_um`, relative to its
/// absorption at 0.47 µm (the single-colour simulator's wavelength, so a sample made
/// at that wavelength is the one it always made): a haematoxylin-and-eosin-like
/// purple, absorbing most in the green (peak 0.54 µm), little in the red.
pub fn stain_absorption(wavelength_um: f64) -> f64 {
    let band = |l: f64| {
        0.15 + (-((l - 0.54) / 0.045).powi(2)).exp() + 0.35 * (-((l - 0.44) / 0.04).powi(2)).exp()
    };
    band(wavelength_um) / band(0.47)
}

/// A sample's phase at `wavelength_um` for a phase of `phase_at_047` rad at 0.47 µm:
/// the optical path is fixed (dispersion of a biological sample's index over the
/// visible is ~1 % and is left out), so phase scales as 1/λ.
pub fn phase_at(phase_at_047: f64, wavelength_um: f64) -> f64 {
    phase_at_047 * 0.47 / wavelength_um
}

/// The whitening's floor in [`register`], a share of the cross-power's mean: 0.01–0.1
/// all read the known offsets of simulated colour runs (0 did not), 1 lost one.
const WHITENING_FLOOR: f64 = 0.1;

/// Where `moving` lies against `reference` (the same scene in another colour), in
/// pixels (x, y): `moving` ≈ `reference` shifted by that much. Phase correlation over
/// the central square (≤ 1024 px, Hann-windowed, mean removed), sub-pixel by a
/// parabola through the peak. None for images under 16 px or without texture.
///
/// The cross-power is whitened with a floor of [`WHITENING_FLOOR`] × its mean: a
/// reconstruction upsampled 4× holds light only inside its synthetic aperture, and
/// whitened alike, the weak rest of its spectrum decided the peak (two aligned colour
/// channels of 128² frames read 31–35 µm apart).
pub fn register(reference: ArrayView2<'_, f32>, moving: ArrayView2<'_, f32>) -> Option<(f64, f64)> {
    let (h, w) = reference.dim();
    if moving.dim() != (h, w) {
        return None;
    }
    let n = h.min(w).min(1024) & !1;
    if n < 16 {
        return None;
    }
    let (y0, x0) = ((h - n) / 2, (w - n) / 2);
    let hann = |i: usize| 0.5 - 0.5 * (std::f32::consts::TAU * i as f32 / n as f32).cos();
    let mut fft = Fft2::new(n, n);
    let mut spectrum = |img: ArrayView2<'_, f32>| {
        let crop = img.slice(ndarray::s![y0..y0 + n, x0..x0 + n]);
        let mean = crop.mean().unwrap_or(0.0);
        let mut data: Vec<Complex32> = crop
            .indexed_iter()
            .map(|((r, c), &v)| Complex32::new((v - mean) * hann(r) * hann(c), 0.0))
            .collect();
        fft.forward(&mut data);
        data
    };
    let a = spectrum(reference);
    let b = spectrum(moving);
    let products: Vec<Complex32> = a.iter().zip(&b).map(|(a, b)| b * a.conj()).collect();
    let mean = products.iter().map(|p| p.norm() as f64).sum::<f64>() / products.len() as f64;
    let floor = (WHITENING_FLOOR * mean) as f32;
    let mut cross: Vec<Complex32> = products
        .iter()
        .map(|&p| {
            let m = p.norm() + floor;
            if m > 1e-20 {
                p / m
            } else {
                Complex32::default()
            }
        })
        .collect();
    if cross.iter().all(|c| c.norm() == 0.0) {
        return None;
    }
    fft.inverse(&mut cross);
    crate::reconstruct::refocus::peak(&cross, n)
}

/// `object` moved by (−`dx`, −`dy`) pixels (a Fourier shift: sub-pixel, the edges
/// wrapping around), which undoes a shift of (`dx`, `dy`) that [`register`] read.
pub fn shifted_back(object: &Array2<Complex32>, dx: f64, dy: f64) -> Array2<Complex32> {
    let (h, w) = object.dim();
    let mut fft = Fft2::new(w, h);
    let mut data: Vec<Complex32> = object.iter().copied().collect();
    fft.forward(&mut data);
    for r in 0..h {
        let fy = crate::reconstruct::refocus::signed(r, h) as f64 / h as f64;
        for c in 0..w {
            let fx = crate::reconstruct::refocus::signed(c, w) as f64 / w as f64;
            let phase = std::f64::consts::TAU * (fx * dx + fy * dy);
            data[r * w + c] *= Complex32::from_polar(1.0, phase as f32);
        }
    }
    fft.inverse(&mut data);
    Array2::from_shape_vec((h, w), data).unwrap_or_else(|_| object.clone())
}

/// An sRGB preview of a colour reconstruction: each channel's intensity transmission
/// |t|² divided by its clear background's (`white`, per channel), put into the display
/// primary its wavelength is nearest (red ≥ 0.58 µm, green ≥ 0.49 µm, else blue;
/// a primary no channel reaches copies its neighbours' mean, so two channels still
/// give a picture), sRGB-encoded, 8 bits, row-major RGB.
pub fn srgb_preview(channels: &[(f64, ArrayView2<'_, f32>)], white: &[f64]) -> Vec<u8> {
    let Some((_, first)) = channels.first() else {
        return vec![];
    };
    let (h, w) = first.dim();
    let primary = |l: f64| {
        if l >= 0.58 {
            0
        } else if l >= 0.49 {
            1
        } else {
            2
        }
    };
    let mut sums = vec![vec![0f64; h * w]; 3];
    let mut counts = [0usize; 3];
    for ((l, amp), white) in channels.iter().zip(white) {
        let p = primary(*l);
        counts[p] += 1;
        let white = if *white > 0.0 { *white } else { 1.0 };
        for (s, &a) in sums[p].iter_mut().zip(amp.iter()) {
            *s += (a as f64).powi(2) / white;
        }
    }
    for p in 0..3 {
        if counts[p] > 0 {
            sums[p].iter_mut().for_each(|v| *v /= counts[p] as f64);
        }
    }
    let filled: Vec<usize> = (0..3).filter(|&p| counts[p] > 0).collect();
    for p in 0..3 {
        if counts[p] == 0 {
            let mean: Vec<f64> = (0..h * w)
                .map(|i| {
                    filled.iter().map(|&q| sums[q][i]).sum::<f64>() / filled.len().max(1) as f64
                })
                .collect();
            sums[p] = mean;
        }
    }
    let encode = |v: f64| {
        let v = v.clamp(0.0, 1.0);
        let s = if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        };
        (s * 255.0).round() as u8
    };
    (0..h * w)
        .flat_map(|i| [encode(sums[0][i]), encode(sums[1][i]), encode(sums[2][i])])
        .collect()
}

/// The clear background's intensity transmission of an amplitude image: the 90th
/// percentile of |t|² (most of a slide's field is clear glass or mounting medium,
/// brighter than anything on it), the white point of [`srgb_preview`].
pub fn clear_level(amplitude: ArrayView2<'_, f32>) -> f64 {
    let mut v: Vec<f32> = amplitude
        .iter()
        .map(|a| a * a)
        .filter(|x| x.is_finite())
        .collect();
    crate::stats::quantiles(&mut v, [0.9]).map_or(1.0, |[q]| q as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registration_reads_a_known_shift_and_the_shift_back_undoes_it() {
        let (h, w) = (96, 128);
        let scene = |dx: f64, dy: f64| {
            Array2::from_shape_fn((h, w), |(r, c)| {
                let (x, y) = (c as f64 - dx, r as f64 - dy);
                let blob = |cx: f64, cy: f64, s: f64| {
                    (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
                };
                (1.0 - 0.5 * blob(60.0, 40.0, 4.0)
                    - 0.3 * blob(80.0, 55.0, 6.0)
                    - 0.4 * blob(45.0, 60.0, 3.0)) as f32
            })
        };
        let a = scene(0.0, 0.0);
        let b = scene(2.3, -1.6);
        let (dx, dy) = register(a.view(), b.view()).unwrap();
        assert!(
            (dx - 2.3).abs() < 0.15 && (dy + 1.6).abs() < 0.15,
            "{dx} {dy}"
        );
        let back = shifted_back(&b.mapv(|v| Complex32::new(v, 0.0)), dx, dy);
        let err: f32 = back
            .iter()
            .zip(a.iter())
            .skip(w * 10)
            .take(w * 70)
            .map(|(z, v)| (z.re - v).abs())
            .fold(0.0, f32::max);
        assert!(err < 0.03, "{err}");
    }

    #[test]
    fn a_clear_field_is_white_in_the_preview() {
        let clear = Array2::from_elem((4, 4), 0.9f32);
        let white = clear_level(clear.view());
        let rgb = srgb_preview(
            &[
                (0.62, clear.view()),
                (0.52, clear.view()),
                (0.47, clear.view()),
            ],
            &[white; 3],
        );
        assert!(rgb.iter().all(|&v| v == 255));
    }

    #[test]
    fn a_spectrum_keeps_its_centre_and_width() {
        let red = ws2812b_channel("red").unwrap();
        for n in [3, 5, 7] {
            let s = red.spectrum(n);
            let w: f64 = s.iter().map(|p| p.1).sum();
            let mean: f64 = s.iter().map(|p| p.0 * p.1).sum();
            let var: f64 = s.iter().map(|p| (p.0 - mean).powi(2) * p.1).sum();
            assert!((w - 1.0).abs() < 1e-12);
            assert!((mean - red.wavelength_um).abs() < 1e-12);
            let fwhm_nm = var.sqrt() * 2.3548 * 1000.0;
            assert!((fwhm_nm - red.fwhm_nm).abs() < 1e-6, "{fwhm_nm}");
        }
        assert_eq!(red.spectrum(1), vec![(red.wavelength_um, 1.0)]);
    }

    #[test]
    fn a_die_offset_turns_with_the_board() {
        let blue = ws2812b_channel("b").unwrap();
        let board = crate::LedGeometry {
            theta_deg: 90.0,
            ..crate::LedGeometry::paper()
        };
        let (x, y) = blue.die_offset_on(&board);
        assert!(x.abs() < 1e-12 && (y - 0.7).abs() < 1e-12, "{x} {y}");
        let g = blue.geometry(&board);
        let led = crate::LedIndex::new(3, 4);
        let (ax, ay, _) = board.led_position_3d_mm(led);
        let (bx, by, _) = g.led_position_3d_mm(led);
        assert!(((bx - ax) - x).abs() < 1e-12 && ((by - ay) - y).abs() < 1e-12);
    }

    #[test]
    fn the_stain_is_the_single_colour_sample_at_047_and_purple() {
        assert!((stain_absorption(0.47) - 1.0).abs() < 1e-12);
        let (r, g, b) = (
            stain_absorption(0.6225),
            stain_absorption(0.524),
            stain_absorption(0.466),
        );
        assert!(g > b && b > r, "{r} {g} {b}");
    }
}
