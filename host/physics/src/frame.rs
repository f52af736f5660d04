//! A measured frame as the reconstruction and the calibration take it: the counts as
//! the camera stored them (8/16-bit integers or floats, never converted as a whole),
//! the dark level and the exposure. This is the one place where counts become
//! intensities, for datasets read from disk and for frames arriving live alike.

use crate::optics::LedIndex;
use ndarray::{s, Array2, ArrayView2};

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

    /// `f(sample − offset)` over `region`, in one pass.
    fn region_map(&self, r: Region, offset: f32, f: impl Fn(f32) -> f32) -> Image {
        let cut = s![r.y0..r.y0 + r.height, r.x0..r.x0 + r.width];
        match self {
            Counts::U8(a) => a.slice(cut).mapv(|v| f(f32::from(v) - offset)),
            Counts::U16(a) => a.slice(cut).mapv(|v| f(f32::from(v) - offset)),
            Counts::F32(a) => a.slice(cut).mapv(|v| f(v - offset)),
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

/// A measured frame: counts, the camera's dark level (counts) and the exposure (ms).
#[derive(Debug, Clone, Copy)]
pub struct Measured<'a> {
    /// The samples.
    pub counts: Counts<'a>,
    /// Counts the sensor reads with no light.
    pub dark_level: f32,
    /// Exposure, ms; intensities are per ms so that frames of different exposures
    /// compare.
    pub exposure_ms: f32,
    /// Counts above the dark level up to which a pixel is read as no light (0: only
    /// values below the dark level are; see [`crate::background`]).
    pub floor: f32,
}

impl Measured<'_> {
    /// (rows, cols).
    pub fn dim(&self) -> (usize, usize) {
        self.counts.dim()
    }

    /// Counts minus the dark level over `region`, not divided by the exposure (noise
    /// may go below zero: the calibration's background estimate needs it).
    pub fn dark_subtracted(&self, region: Region) -> Image {
        self.counts.region_f32(region, self.dark_level)
    }

    /// Counts above the dark level as the light they stand for: noise below the dark
    /// level, or within the floor above it, is no light.
    fn light(&self, v: f32) -> f32 {
        if v > self.floor {
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
            .region_map(region, self.dark_level, |v| self.light(v) * per_ms)
    }

    /// √(intensity / `clear_level`) over `region`: the amplitude EPRY imposes, with a
    /// clear sample under the reference LED at 1. One pass over the counts.
    pub fn amplitude(&self, region: Region, clear_level: f32) -> Image {
        let scale = 1.0 / (self.exposure_ms.max(f32::MIN_POSITIVE) * clear_level);
        self.counts
            .region_map(region, self.dark_level, |v| (self.light(v) * scale).sqrt())
    }

    /// Mean intensity per ms over the whole frame.
    pub fn mean_intensity(&self) -> f32 {
        let (h, w) = self.dim();
        let per_ms = 1.0 / self.exposure_ms.max(f32::MIN_POSITIVE);
        let sum: f64 = match self.counts {
            Counts::U8(a) => a
                .iter()
                .map(|&v| self.light(f32::from(v) - self.dark_level) as f64)
                .sum(),
            Counts::U16(a) => a
                .iter()
                .map(|&v| self.light(f32::from(v) - self.dark_level) as f64)
                .sum(),
            Counts::F32(a) => a
                .iter()
                .map(|&v| self.light(v - self.dark_level) as f64)
                .sum(),
        };
        (sum / (h * w).max(1) as f64) as f32 * per_ms
    }
}

/// A measured frame with the LED (row, col) that lit it.
#[derive(Debug, Clone, Copy)]
pub struct LitFrame<'a> {
    /// LED (row, col).
    pub led: LedIndex,
    /// The frame.
    pub measured: Measured<'a>,
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
            dark_level: 100.0,
            exposure_ms: 2.0,
            floor: 0.0,
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
}
