//! Whether the reconstruction explains its bright-field frames: each bright-field
//! frame's measured intensity regressed on the intensity the final object and pupil
//! predict for it, I_measured ≈ gain·I_model + offset.
//!
//! A bright-field frame holds the strong zero order, so a converged EPRY reproduces it
//! closely: on simulated 8- and 12-bit sets of 128² and 256² the offset is −5 % to +2 %
//! of the mean (gain 0.98–1.06). When the frames carry light that no object makes, the
//! object cannot match their contrast and the offset grows: the vendored USAF frames
//! read as linear leave 43 % of the mean intensity as offset (gain 0.57, correlation
//! 0.84), because they were saved with a display gamma (decoded with γ = 2.2: 0.6 %,
//! gain 0.99, correlation 0.98). Stray light or flare that lifts the whole frame shows
//! the same way. A sample without opaque parts hides a gamma from this fit (its frames
//! vary little, and a power law over a small range is nearly a line).

use serde::Serialize;

/// The regression's sums over the pixels of one or more frames (model intensity p,
/// measured intensity m, both in units of the clear level).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContrastSums {
    /// Pixels.
    pub n: f64,
    /// Σp.
    pub p: f64,
    /// Σm.
    pub m: f64,
    /// Σp².
    pub pp: f64,
    /// Σm².
    pub mm: f64,
    /// Σp·m.
    pub pm: f64,
    /// Frames summed.
    pub frames: usize,
}

/// The fitted line and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ContrastFit {
    /// Slope: measured over modelled contrast (1 when the model explains the frames).
    pub gain: f64,
    /// Intercept over the mean measured intensity (0 when the model explains the
    /// frames; a share of light no object makes when positive).
    pub offset_share: f64,
    /// Pearson correlation of modelled and measured intensity, pixel by pixel.
    pub correlation: f64,
    /// Bright-field frames (per tile) summed.
    pub frames: usize,
}

/// Above this offset share the report warns that the frames carry light no object
/// explains. Measured: simulated sets −0.05 to 0.02, a 256² crop of a real linear 8-bit
/// camera's frames 0.10, the vendored USAF frames read as linear 0.43.
pub const OFFSET_SHARE_WARNING: f64 = 0.15;

/// Below this correlation the line says nothing about an offset: a model that explains
/// little of the frames' variation is fitted with a flat slope (the noise in it
/// attenuates the regression), and the intercept takes up the rest. Measured: good
/// simulated weak-phase sets (frames of a few % contrast) 0.56–0.66 with offsets of
/// 0.16–0.21; the vendored USAF frames read as linear 0.84; other good sets ≥ 0.89.
pub const MIN_CORRELATION: f64 = 0.8;

impl ContrastSums {
    /// Add a pixel's modelled and measured intensity.
    pub fn push(&mut self, p: f64, m: f64) {
        self.n += 1.0;
        self.p += p;
        self.m += m;
        self.pp += p * p;
        self.mm += m * m;
        self.pm += p * m;
    }

    /// Both sets of sums together.
    pub fn merge(&mut self, other: &ContrastSums) {
        self.n += other.n;
        self.p += other.p;
        self.m += other.m;
        self.pp += other.pp;
        self.mm += other.mm;
        self.pm += other.pm;
        self.frames += other.frames;
    }

    /// The least-squares line m = gain·p + offset; None without pixels, without
    /// light, or with a model that does not vary.
    pub fn fit(&self) -> Option<ContrastFit> {
        if self.n < 2.0 || self.m <= 0.0 {
            return None;
        }
        let (mean_p, mean_m) = (self.p / self.n, self.m / self.n);
        let var_p = self.pp / self.n - mean_p * mean_p;
        let var_m = self.mm / self.n - mean_m * mean_m;
        let cov = self.pm / self.n - mean_p * mean_m;
        if var_p <= 0.0 || var_m <= 0.0 {
            return None;
        }
        let gain = cov / var_p;
        Some(ContrastFit {
            gain,
            offset_share: (mean_m - gain * mean_p) / mean_m,
            correlation: cov / (var_p * var_m).sqrt(),
            frames: self.frames,
        })
    }
}

impl ContrastFit {
    /// Whether the frames carry more light than any object explains: a large offset
    /// from a line that fits.
    pub fn is_suspect(&self) -> bool {
        self.offset_share > OFFSET_SHARE_WARNING && self.correlation >= MIN_CORRELATION
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_with_an_offset_is_recovered() {
        let mut s = ContrastSums::default();
        for k in 0..100 {
            let p = k as f64 / 50.0;
            s.push(p, 0.6 * p + 0.4);
        }
        let fit = s.fit().unwrap();
        assert!((fit.gain - 0.6).abs() < 1e-9);
        // mean m = 0.6·0.99 + 0.4 = 0.994.
        assert!((fit.offset_share - 0.4 / 0.994).abs() < 1e-9);
        assert!((fit.correlation - 1.0).abs() < 1e-9);
        assert!(fit.is_suspect());
        let weak = ContrastFit {
            correlation: 0.6,
            ..fit
        };
        assert!(
            !weak.is_suspect(),
            "a line that explains little says nothing of an offset"
        );
        let mut flat = ContrastSums::default();
        flat.push(1.0, 1.0);
        flat.push(1.0, 2.0);
        assert_eq!(flat.fit(), None, "a model that does not vary fits nothing");
    }
}
