//! A measured frame as the reconstruction and the calibration take it: the counts as
//! the camera stored them (8/16-bit integers or floats, never converted as a whole),
//! how they stand for light, the dark level and the exposure. This is the one place
//! where counts become intensities, for datasets read from disk and for frames
//! arriving live alike.

use crate::optics::LedIndex;
use ndarray::{s, Array2, ArrayView1, ArrayView2};

use crate::Image;

/// A frame's pixels as stored (16-bit frames stay 16-bit: a 441-frame stack of 20 MP
/// frames is 18 GB as f32, 9 GB as u16).
#[derive(Debug, Clone, PartialEq)]
pub enum Pixels {
    /// 8-bit integers.
    U8(Array2<u8>),
    /// 16-bit integers.
    U16(Array2<u16>),
    /// 32-bit floats.
    F32(Array2<f32>),
}

impl Pixels {
    /// (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        self.view().dim()
    }

    /// Bits per sample.
    pub fn bits(&self) -> u32 {
        match self {
            Pixels::U8(_) => 8,
            Pixels::U16(_) => 16,
            Pixels::F32(_) => 32,
        }
    }

    /// As floats (a copy).
    pub fn to_f32(&self) -> Image {
        self.view().region_f32(Region::whole(self.dim()), 0.0)
    }

    /// Borrow the samples.
    pub fn view(&self) -> Counts<'_> {
        match self {
            Pixels::U8(a) => Counts::U8(a.view()),
            Pixels::U16(a) => Counts::U16(a.view()),
            Pixels::F32(a) => Counts::F32(a.view()),
        }
    }
}

/// Borrowed samples: a stored frame, or a frame still in the camera's shared memory.
#[derive(Debug, Clone, Copy)]
pub enum Counts<'a> {
    /// 8-bit integers.
    U8(ArrayView2<'a, u8>),
    /// 16-bit integers.
    U16(ArrayView2<'a, u16>),
    /// 32-bit floats.
    F32(ArrayView2<'a, f32>),
}

impl<'a> Counts<'a> {
    /// `region` of the samples, borrowed as they are.
    pub fn region(self, r: Region) -> Counts<'a> {
        let cut = s![r.y0..r.y0 + r.height, r.x0..r.x0 + r.width];
        match self {
            Counts::U8(a) => Counts::U8(a.slice_move(cut)),
            Counts::U16(a) => Counts::U16(a.slice_move(cut)),
            Counts::F32(a) => Counts::F32(a.slice_move(cut)),
        }
    }
}

impl Counts<'_> {
    /// (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        match self {
            Counts::U8(a) => a.dim(),
            Counts::U16(a) => a.dim(),
            Counts::F32(a) => a.dim(),
        }
    }

    /// `region` as floats minus `offset`.
    fn region_f32(&self, r: Region, offset: f32) -> Image {
        let cut = s![r.y0..r.y0 + r.height, r.x0..r.x0 + r.width];
        match self {
            Counts::U8(a) => a.slice(cut).mapv(|v| f32::from(v) - offset),
            Counts::U16(a) => a.slice(cut).mapv(|v| f32::from(v) - offset),
            Counts::F32(a) => a.slice(cut).mapv(|v| v - offset),
        }
    }

    /// `f(sample)` over `region`, in one pass.
    fn region_map(&self, r: Region, f: impl Fn(f32) -> f32) -> Image {
        let cut = s![r.y0..r.y0 + r.height, r.x0..r.x0 + r.width];
        match self {
            Counts::U8(a) => a.slice(cut).mapv(|v| f(f32::from(v))),
            Counts::U16(a) => a.slice(cut).mapv(|v| f(f32::from(v))),
            Counts::F32(a) => a.slice(cut).mapv(f),
        }
    }

    /// The sum of `f(sample)` over the whole frame.
    fn sum_map(&self, f: impl Fn(f32) -> f32) -> f64 {
        match self {
            Counts::U8(a) => a.iter().map(|&v| f(f32::from(v)) as f64).sum(),
            Counts::U16(a) => a.iter().map(|&v| f(f32::from(v)) as f64).sum(),
            Counts::F32(a) => a.iter().map(|&v| f(v) as f64).sum(),
        }
    }
}

/// How stored values stand for light.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Response {
    /// Proportional to the light, as a sensor reads it (the format's rule).
    #[default]
    Linear,
    /// Encoded for display, as 8-bit images saved for viewing often are: a stored
    /// value v stands for the light `full_scale·(v/full_scale)^gamma`. The vendored
    /// USAF frames are (γ ≈ 2.2): read as linear, no object fits their bright-field
    /// frames, and the reconstruction rings.
    Gamma {
        /// The exponent (2.2 for sRGB-like encodings).
        gamma: f32,
        /// The stored value of full scale (255 for 8 bits).
        full_scale: f32,
    },
}

impl Response {
    /// The light a stored value stands for, in counts of the same full scale.
    pub fn decode(&self, v: f32) -> f32 {
        match *self {
            Response::Linear => v,
            Response::Gamma { gamma, full_scale } => {
                full_scale * (v.max(0.0) / full_scale).powf(gamma)
            }
        }
    }
}

/// A rectangle of a frame, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// First row.
    pub y0: usize,
    /// First column.
    pub x0: usize,
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
}

impl Region {
    /// All of a `(rows, cols)` frame.
    pub fn whole((height, width): (usize, usize)) -> Self {
        Self {
            y0: 0,
            x0: 0,
            height,
            width,
        }
    }
}

impl From<crate::tiles::Tile> for Region {
    fn from(t: crate::tiles::Tile) -> Self {
        Self {
            y0: t.y0,
            x0: t.x0,
            height: t.size,
            width: t.size,
        }
    }
}

/// A measured frame: counts, how they stand for light, the camera's dark level
/// (counts) and the exposure (ms).
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// The samples.
    pub counts: Counts<'a>,
    /// How the samples stand for light.
    pub response: Response,
    /// Counts the sensor reads with no light, as light: for a display-encoded frame,
    /// the stored dark level through [`Response::decode`].
    pub dark_level: f32,
    /// Exposure, ms; intensities are per ms so that frames of different exposures
    /// compare.
    pub exposure_ms: f32,
    /// Counts above the dark level up to which a pixel is read as no light (0: only
    /// values below the dark level are; see [`crate::background`]).
    pub floor: f32,
    /// Whether the floor is soft: light v above the dark level counts as
    /// v·(v²/(v² + floor²))² instead of being cut at the floor, so noise near the level
    /// barely counts, light well above the floor counts in full, and dim light between
    /// still counts in part ([`crate::background`]).
    pub soft_floor: bool,
    /// Counts either side of each measured pixel within which the model's light is
    /// left as it is rather than brought to the measurement (0: none; see
    /// [`Self::intensity_band`]).
    pub band: f32,
}

impl Measured<'_> {
    /// (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        self.counts.dim()
    }

    /// Counts minus the dark level over `region`, not divided by the exposure (noise
    /// may go below zero: the calibration's background estimate needs it). Decoded
    /// to light first when the frame is display-encoded ([`Response`]).
    pub fn dark_subtracted(&self, region: Region) -> Image {
        self.counts.region_map(region, |v| self.above_dark(v))
    }

    /// Row `r` as [`Self::dark_subtracted`] gives it, into `out` (one row's width):
    /// for statistics over frames too large to convert whole.
    pub fn dark_subtracted_row(&self, r: usize, out: &mut [f32]) {
        fn convert<T: Copy>(row: ArrayView1<'_, T>, out: &mut [f32], f: impl Fn(T) -> f32) {
            match row.as_slice() {
                Some(row) => out.iter_mut().zip(row).for_each(|(o, &v)| *o = f(v)),
                None => out.iter_mut().zip(row).for_each(|(o, &v)| *o = f(v)),
            }
        }
        match self.counts {
            Counts::U8(a) => convert(a.row(r), out, |v| self.above_dark(f32::from(v))),
            Counts::U16(a) => convert(a.row(r), out, |v| self.above_dark(f32::from(v))),
            Counts::F32(a) => convert(a.row(r), out, |v| self.above_dark(v)),
        }
    }

    /// A stored sample as light above the dark level, in counts.
    fn above_dark(&self, v: f32) -> f32 {
        self.response.decode(v) - self.dark_level
    }

    /// Counts above the dark level as the light they stand for: noise below the dark
    /// level, or within the floor above it, is no light (a soft floor shrinks what is
    /// near it instead).
    fn light(&self, v: f32) -> f32 {
        if self.soft_floor {
            if v > 0.0 {
                let v2 = v * v;
                let share = v2 / (v2 + self.floor * self.floor);
                v * share * share
            } else {
                0.0
            }
        } else if v > self.floor {
            v
        } else {
            0.0
        }
    }

    /// Intensity per ms over `region`, noise below the dark level (or within the
    /// floor) taken as zero: what the reconstruction's measurement is.
    pub fn intensity(&self, region: Region) -> Image {
        let per_ms = 1.0 / self.exposure_ms.max(f32::MIN_POSITIVE);
        self.counts
            .region_map(region, |v| self.light(self.above_dark(v)) * per_ms)
    }

    /// √(intensity / `clear_level`) over `region`: the amplitude EPRY imposes, with a
    /// clear sample under the reference LED at 1. One pass over the counts.
    pub fn amplitude(&self, region: Region, clear_level: f32) -> Image {
        let scale = 1.0 / (self.exposure_ms.max(f32::MIN_POSITIVE) * clear_level);
        self.counts
            .region_map(region, |v| (self.light(self.above_dark(v)) * scale).sqrt())
    }

    /// [`Self::band`] as intensity relative to `clear_level`, as [`Self::amplitude`]
    /// normalises it: what [`crate::reconstruct::Epry::update_within`] takes.
    pub fn intensity_band(&self, clear_level: f32) -> f32 {
        self.band / (self.exposure_ms.max(f32::MIN_POSITIVE) * clear_level)
    }

    /// Mean intensity per ms over the whole frame.
    pub fn mean_intensity(&self) -> f32 {
        let (h, w) = self.dim();
        let per_ms = 1.0 / self.exposure_ms.max(f32::MIN_POSITIVE);
        let sum = self.counts.sum_map(|v| self.light(self.above_dark(v)));
        (sum / (h * w).max(1) as f64) as f32 * per_ms
    }
}

/// A measured frame with the LED (row, col) that lit it.
#[derive(Debug, Clone, Copy)]
pub struct LitFrame<'a> {
    /// LED (row, col): the first of a multiplexed frame's.
    pub led: LedIndex,
    /// The other LEDs lit in the same frame (multiplexed illumination); empty for one.
    pub also: &'a [LedIndex],
    /// The frame.
    pub measured: Measured<'a>,
}

impl LitFrame<'_> {
    /// Every LED that lit the frame.
    pub fn leds(&self) -> impl Iterator<Item = LedIndex> + '_ {
        std::iter::once(self.led).chain(self.also.iter().copied())
    }

    /// Whether more than one LED lit it.
    pub fn is_multiplexed(&self) -> bool {
        !self.also.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_become_intensity_amplitude_and_mean_in_one_way() {
        let raw =
            Pixels::U16(Array2::from_shape_vec((2, 3), vec![100, 110, 140, 90, 500, 100]).unwrap());
        let m = Measured {
            counts: raw.view(),
            response: Response::Linear,
            dark_level: 100.0,
            exposure_ms: 2.0,
            floor: 0.0,
            soft_floor: false,
            band: 0.0,
        };
        let region = Region {
            y0: 0,
            x0: 1,
            height: 2,
            width: 2,
        };
        assert_eq!(
            m.dark_subtracted(region).into_raw_vec_and_offset().0,
            vec![10.0, 40.0, 400.0, 0.0]
        );
        assert_eq!(
            m.intensity(Region::whole(m.dim())).row(1).to_vec(),
            vec![0.0, 200.0, 0.0]
        );
        let a = m.amplitude(region, 5.0);
        assert!(
            (a[[0, 1]] - 2.0).abs() < 1e-6,
            "√(40/2/5) = 2, got {}",
            a[[0, 1]]
        );
        assert!((m.mean_intensity() - (10.0 + 40.0 + 400.0) / 6.0 / 2.0).abs() < 1e-4);
    }

    #[test]
    fn display_encoded_counts_are_decoded_before_anything_else() {
        let raw = Pixels::U8(Array2::from_shape_vec((1, 4), vec![0, 10, 128, 255]).unwrap());
        let response = Response::Gamma {
            gamma: 2.2,
            full_scale: 255.0,
        };
        let dark = response.decode(10.0);
        let m = Measured {
            counts: raw.view(),
            response,
            dark_level: dark,
            exposure_ms: 1.0,
            floor: 0.0,
            soft_floor: false,
            band: 0.0,
        };
        let light: Vec<f32> = [0.0f32, 10.0, 128.0, 255.0]
            .iter()
            .map(|&v| 255.0 * (v / 255.0).powf(2.2) - dark)
            .collect();
        let mut row = vec![0.0; 4];
        m.dark_subtracted_row(0, &mut row);
        let whole = Region::whole(m.dim());
        for (k, &l) in light.iter().enumerate() {
            assert!((row[k] - l).abs() < 1e-3, "{row:?} against {light:?}");
            assert!((m.dark_subtracted(whole)[[0, k]] - l).abs() < 1e-3);
            assert!((m.intensity(whole)[[0, k]] - l.max(0.0)).abs() < 1e-3);
        }
        // 128 of 255 is a fifth of full scale's light, not a half.
        assert!((m.intensity(whole)[[0, 2]] / 255.0 - 0.219).abs() < 0.01);
        let mean = light.iter().map(|l| l.max(0.0)).sum::<f32>() / 4.0;
        assert!((m.mean_intensity() - mean).abs() < 1e-3);
    }
}
