//! The clear background's phase taken flat (`fpm reconstruct --flatten-background`).
//!
//! EPRY recovers the slowest phase of a field poorly: an offset, ramps and bowls across
//! a tile (modes below a frequency bin, which hardly change any frame) and, more
//! weakly, phase varying over tens of µm, which only the few frames whose disc edge
//! lies near the pupil's edge see. These modes end wherever the field's edges and the
//! geometry push them. Measured on the demo's simulated sample with the true geometry
//! given: a centred board came back at complex NRMSE 0.052, the demo's shifted board
//! at 0.177, and nearly all the difference was such phase, up to ~1 rad.
//!
//! For a sample on clear glass, the glass pins them: it has one phase. So the terms
//! are fitted to the phase of the clear background alone (pixels at the clear
//! amplitude, the objects clipped as outliers), first over the whole field, then over
//! overlapping blocks whose fits are blended, and divided out. A sample without clear
//! glass has nothing to pin them with, and its own slow phase would be taken off
//! instead: simulated confluent phase samples (no glass) went from NRMSE 0.14–0.17 to
//! 0.44–0.71. So it is the user's choice, off by default.

use ndarray::Array2;

use crate::optics::LedGeometry;
use rustfft::num_complex::Complex32;

/// The low-order terms, in coordinates x, y ∈ [−½, ½] across the field: offset, the
/// two ramps, defocus (x² + y²) and the two astigmatisms (x² − y², xy).
pub const TERMS: [&str; 6] = [
    "offset", "ramp_x", "ramp_y", "defocus", "astig_0", "astig_45",
];

/// Pixels whose amplitude is within this fraction of the clear level are candidates
/// for the background (on the demo's sample: 0.05 and 0.10 flattened alike, 0.20 let
/// in the objects' rims and left a third of the error).
pub const CLEAR_TOLERANCE: f32 = 0.05;

/// Each quadrant of the field needs this fraction of its pixels in the background
/// for the quadratic terms; with fewer, only offset and ramps are fitted (they need
/// only [`MIN_CLEAR_FRACTION`] overall).
pub const MIN_QUADRANT_FRACTION: f64 = 0.05;

/// How the background's phase is treated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Flatten {
    /// Keep the phase EPRY settled on.
    Keep,
    /// Flatten over blocks sized from the LED array ([`auto_block_um`]).
    Auto,
    /// Flatten over blocks of this side, µm.
    BlockUm(f64),
}

impl Flatten {
    /// The block side in µm for `geometry` (None: keep).
    pub fn block_um(self, geometry: &LedGeometry, wavelength_um: f64) -> Option<f64> {
        match self {
            Flatten::Keep => None,
            Flatten::Auto => Some(auto_block_um(geometry, wavelength_um)),
            Flatten::BlockUm(um) => Some(um),
        }
    }
}

/// Blocks span this many periods of the LED spacing in frequency (see
/// [`auto_block_um`]).
pub const BLOCK_LED_PERIODS: f64 = 3.0;

/// The block side from the LED array. Neighbouring LEDs light the sample at
/// frequencies Δf = pitch/(λ·h) apart; phase varying at a frequency q shows only in
/// the frames whose disc edge lies within q of the pupil's edge, and below about Δf/2
/// there are few of them. A block's six terms reach about 1.5 cycles across it, so
/// blocks of 3/Δf take off that band: 52 µm for the paper's array (2.5 mm at 92 mm,
/// λ = 0.47 µm). Measured on a simulated 512² field of cells on glass
/// (`fpm simulate acquisition --size 512`, 10 passes, 2× upsampling, tiles of 448):
/// complex NRMSE 0.071 kept, 0.053 with one fit per tile, 0.016 with these blocks.
pub fn auto_block_um(geometry: &LedGeometry, wavelength_um: f64) -> f64 {
    let spacing = geometry.pitch_mm / (wavelength_um * geometry.height_mm);
    if spacing > 0.0 && spacing.is_finite() {
        BLOCK_LED_PERIODS / spacing
    } else {
        f64::INFINITY
    }
}

/// The weight of "no correction" in the blend of block fits, against 1 for a block
/// that is all background, at its centre.
const NO_CORRECTION_WEIGHT: f64 = 0.05;

/// Fits read the background on a grid of at most this many points a side.
const FIT_GRID: usize = 96;

/// Below this fraction of the field in the background nothing is fitted.
pub const MIN_CLEAR_FRACTION: f64 = 0.10;

/// What [`flatten_background_phase`] did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Flattening {
    /// Fits tried: the whole field's, then each block's (a field up to 1.5 blocks
    /// wide has only the first).
    pub blocks: usize,
    /// Blocks with enough clear background for offset and ramps.
    pub fitted: usize,
    /// Of those, blocks with enough in every quadrant for the quadratic terms too.
    pub quadratic: usize,
    /// Mean over the fitted blocks of the fraction of their pixels at the clear
    /// amplitude (the background's candidates, before the objects are clipped).
    pub clear_fraction: f64,
    /// Largest phase taken off anywhere apart from each fit's offset, rad (the whole
    /// field's fit and the blocks' added: a bound).
    pub peak_rad: f64,
    /// Median over the fitted blocks of the background's spread about its fit (robust,
    /// 1.48·MAD), rad.
    pub residual_rad: f64,
}

impl Flattening {
    /// Several fields' flattenings as one (blocks summed, the worst peak, the median
    /// of their residuals weighted by blocks).
    pub fn combined<'a>(all: impl IntoIterator<Item = &'a Flattening>) -> Self {
        let mut out = Self::default();
        let mut residuals = vec![];
        let mut clear = 0.0;
        for f in all {
            clear += f.clear_fraction * f.fitted as f64;
            out.blocks += f.blocks;
            out.fitted += f.fitted;
            out.quadratic += f.quadratic;
            out.peak_rad = out.peak_rad.max(f.peak_rad);
            residuals.extend(std::iter::repeat_n(f.residual_rad, f.fitted));
        }
        out.residual_rad = median(&mut residuals);
        out.clear_fraction = clear / out.fitted.max(1) as f64;
        out
    }
}

/// The low-order phase of one block's clear background.
struct BlockFit {
    /// Coefficients of [`TERMS`] (zero beyond `terms`).
    model: [f64; 6],
    terms: usize,
    spread: f64,
    /// Fraction of the block at the clear amplitude.
    candidates: f64,
    /// Fraction of the block the fit kept as background.
    used: f64,
}

impl BlockFit {
    fn at(&self, r: usize, c: usize, rows: usize, cols: usize) -> f64 {
        let b = basis(r, c, rows, cols);
        (0..self.terms).map(|j| self.model[j] * b[j]).sum()
    }
}

fn basis(r: usize, c: usize, rows: usize, cols: usize) -> [f64; 6] {
    let x = (c as f64 + 0.5) / cols as f64 - 0.5;
    let y = (r as f64 + 0.5) / rows as f64 - 0.5;
    [1.0, x, y, x * x + y * y, x * x - y * y, x * y]
}

/// Fit the low-order phase of `field`'s clear background and divide it out (see the
/// module's doc), over blocks of side `block` pixels: a field up to 1.5 blocks is
/// one block; a larger one is cut into blocks overlapping by half, whose fits are
/// blended. A block with too little clear background gets no fit of its own (its
/// neighbours' reach into it; a field with none is left as it is).
pub fn flatten_background_phase(field: &mut Array2<Complex32>, block: usize) -> Flattening {
    let (rows, cols) = field.dim();
    let block = block.max(16);
    // Coarse to fine: the whole field's terms first, so that each block only corrects
    // what is left, and a block with little background has little to extrapolate.
    // A field whose whole has no clear background to fit is left as it is, blocks
    // and all: a block of a sample that fills the field can look like glass.
    let whole = flatten_whole(field);
    if whole.fitted == 0 || (rows <= block * 3 / 2 && cols <= block * 3 / 2) {
        return whole;
    }
    let fine = flatten_blocks(field, block);
    Flattening {
        blocks: whole.blocks + fine.blocks,
        fitted: whole.fitted + fine.fitted,
        quadratic: whole.quadratic + fine.quadratic,
        clear_fraction: if fine.fitted > 0 {
            fine.clear_fraction
        } else {
            whole.clear_fraction
        },
        peak_rad: whole.peak_rad + fine.peak_rad,
        residual_rad: if fine.fitted > 0 {
            fine.residual_rad
        } else {
            whole.residual_rad
        },
    }
}

/// One fit over the whole field, taken off.
fn flatten_whole(field: &mut Array2<Complex32>) -> Flattening {
    let (rows, cols) = field.dim();
    let mut out = Flattening {
        blocks: 1,
        ..Flattening::default()
    };
    let Some(fit) = fit_block(field.view()) else {
        return out;
    };
    out.fitted = 1;
    out.quadratic = usize::from(fit.terms == 6);
    out.residual_rad = fit.spread;
    out.clear_fraction = fit.candidates;
    for ((r, c), v) in field.indexed_iter_mut() {
        let m = fit.at(r, c, rows, cols);
        out.peak_rad = out.peak_rad.max((m - fit.model[0]).abs());
        *v *= Complex32::from_polar(1.0, -m as f32);
    }
    out
}

/// Fits over blocks of side `block` overlapping by half, blended and taken off.
fn flatten_blocks(field: &mut Array2<Complex32>, block: usize) -> Flattening {
    let (rows, cols) = field.dim();
    let blocks = crate::tiles::plan(cols, rows, block, block / 2);
    let fits: Vec<Option<BlockFit>> = blocks
        .iter()
        .map(|b| fit_block(field.slice(ndarray::s![b.y0..b.y0 + b.size, b.x0..b.x0 + b.size])))
        .collect();
    let mut out = Flattening {
        blocks: blocks.len(),
        ..Flattening::default()
    };
    let mut residuals = vec![];
    // The fits are blended as phases, not phasors: two neighbours a turn apart (one
    // block's ramp can alias by 2π over mostly objects) would cancel as phasors and
    // leave a jump. Each block is first moved by whole turns onto what is placed.
    let mut phase_sum = Array2::<f64>::zeros((rows, cols));
    let mut weight = Array2::<f64>::zeros((rows, cols));
    let side = blocks.first().map_or(block, |b| b.size);
    let window: Vec<f64> = (0..side)
        .map(|i| {
            (std::f64::consts::PI * (i as f64 + 0.5) / side as f64)
                .sin()
                .powi(2)
        })
        .collect();
    let turn = std::f64::consts::TAU;
    for (b, fit) in blocks.iter().zip(&fits) {
        let Some(fit) = fit else { continue };
        out.fitted += 1;
        out.quadratic += usize::from(fit.terms == 6);
        out.clear_fraction += fit.candidates;
        residuals.push(fit.spread);
        let model = Array2::from_shape_fn((b.size, b.size), |(r, c)| fit.at(r, c, b.size, b.size));
        let (mut shift, mut overlap) = (0.0, 0.0);
        for ((r, c), m) in model.indexed_iter() {
            let w = weight[(b.y0 + r, b.x0 + c)];
            if w > 0.0 {
                shift += w * (phase_sum[(b.y0 + r, b.x0 + c)] / w - m);
                overlap += w;
            }
        }
        let turns = if overlap > 0.0 {
            (shift / overlap / turn).round() * turn
        } else {
            0.0
        };
        // A block that is mostly objects extrapolates its fit over them: its
        // neighbours, with more background, count for more there.
        let trust = fit.used * fit.used;
        for ((r, c), m) in model.indexed_iter() {
            out.peak_rad = out.peak_rad.max((m - fit.model[0]).abs());
            let w = trust * window[r] * window[c];
            phase_sum[(b.y0 + r, b.x0 + c)] += w * (m + turns);
            weight[(b.y0 + r, b.x0 + c)] += w;
        }
    }
    out.residual_rad = median(&mut residuals);
    out.clear_fraction /= out.fitted.max(1) as f64;
    // Where no block with background reaches (or only the tail of one), the
    // correction fades to none: the whole field's fit has been taken off already.
    for ((v, p), w) in field.iter_mut().zip(&phase_sum).zip(&weight) {
        *v *= Complex32::from_polar(1.0, -(p / (w + NO_CORRECTION_WEIGHT)) as f32);
    }
    out
}

/// The clear background's low-order phase in one block, or None when too little of
/// it is background.
fn fit_block(field: ndarray::ArrayView2<'_, Complex32>) -> Option<BlockFit> {
    let (rows, cols) = field.dim();
    if rows < 4 || cols < 4 {
        return None;
    }
    let clear = clear_amplitude(field)?;
    let candidate: Vec<bool> = field
        .iter()
        .map(|v| (v.norm() - clear).abs() <= CLEAR_TOLERANCE * clear)
        .collect();
    // Clear glass is a peak in the amplitudes: at least as many pixels within the
    // tolerance as in the two bands beside it (each twice as wide). Amplitudes spread
    // evenly (a sample that fills the block) give half as many.
    let beside = field
        .iter()
        .filter(|v| {
            let d = (v.norm() - clear).abs();
            d > CLEAR_TOLERANCE * clear && d <= 3.0 * CLEAR_TOLERANCE * clear
        })
        .count();
    if candidate.iter().filter(|&&c| c).count() < beside {
        return None;
    }
    let quadrant_fraction = quadrant_fractions(&candidate, rows, cols)
        .into_iter()
        .fold(1.0, f64::min);
    let overall = candidate.iter().filter(|&&c| c).count() as f64 / candidate.len() as f64;
    let terms = if quadrant_fraction >= MIN_QUADRANT_FRACTION {
        6
    } else if overall >= MIN_CLEAR_FRACTION {
        3
    } else {
        return None;
    };
    // The fit reads the candidates on a grid of at most ~96² points: six smooth terms
    // need no more, and a block can hold 100 k pixels.
    let stride = rows.max(cols).div_ceil(FIT_GRID).max(1);
    let points: Vec<([f64; 6], Complex32)> = field
        .indexed_iter()
        .filter(|((r, c), _)| r % stride == 0 && c % stride == 0 && candidate[r * cols + c])
        .map(|((r, c), v)| (basis(r, c, rows, cols), *v))
        .collect();
    // Start flat, and from the background's median phase step between neighbours (so
    // that ramps of many turns, a board placed far from where it was assumed, unwrap);
    // keep whichever fits the background closer. On sparse, noisy background the
    // median step can point at an alias, which the flat start avoids.
    let ramps = median_ramps(field, &candidate, stride);
    let flat = robust_fit(&points, terms, [0.0; 6]);
    let ramped = robust_fit(&points, terms, [0.0, ramps.0, ramps.1, 0.0, 0.0, 0.0]);
    let (model, spread, kept) = match (flat, ramped) {
        (Some(f), Some(r)) if r.1 < 0.8 * f.1 => r,
        (Some(f), _) => f,
        (None, r) => r?,
    };
    let used = kept as f64 * (stride * stride) as f64 / (rows * cols) as f64;
    if used < MIN_CLEAR_FRACTION / 2.0 {
        return None;
    }
    Some(BlockFit {
        model,
        terms,
        spread,
        candidates: overall,
        used,
    })
}

/// The first `terms` of [`TERMS`] fitted to the phase of `points` (basis values and
/// field value), from `start`: corrections are fitted to the wrapped residual, so that
/// a model reaching past ±π unwraps itself, and the objects (anything off the
/// background's phase) are clipped at 3σ of the residual after each round. Returns the
/// model, the spread (1.48·MAD) and how many points it kept.
fn robust_fit(
    points: &[([f64; 6], Complex32)],
    terms: usize,
    start: [f64; 6],
) -> Option<([f64; 6], f64, usize)> {
    let mut model = start;
    let mut keep = vec![true; points.len()];
    let mut spread = f64::INFINITY;
    let residual = |model: &[f64; 6], (b, v): &([f64; 6], Complex32)| -> f64 {
        let m: f64 = (0..terms).map(|j| model[j] * b[j]).sum();
        (v * Complex32::from_polar(1.0, -m as f32)).arg() as f64
    };
    for _round in 0..6 {
        let mut normal = [[0.0f64; 6]; 6];
        let mut rhs = [0.0f64; 6];
        for (point, _) in points.iter().zip(&keep).filter(|(_, &k)| k) {
            let d = residual(&model, point);
            let b = &point.0;
            for i in 0..terms {
                rhs[i] += b[i] * d;
                for j in 0..terms {
                    normal[i][j] += b[i] * b[j];
                }
            }
        }
        let normal = nalgebra::DMatrix::from_fn(terms, terms, |i, j| normal[i][j]);
        let step = normal
            .lu()
            .solve(&nalgebra::DVector::from_column_slice(&rhs[..terms]))?;
        for j in 0..terms {
            model[j] += step[j];
        }
        let deviations: Vec<f64> = points.iter().map(|p| residual(&model, p).abs()).collect();
        let mut kept: Vec<f64> = deviations
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(d, _)| *d)
            .collect();
        if kept.is_empty() {
            return None;
        }
        spread = 1.4826 * median(&mut kept);
        let limit = 3.0 * spread.max(0.01);
        for (k, d) in keep.iter_mut().zip(&deviations) {
            *k = *d <= limit;
        }
    }
    Some((model, spread, keep.iter().filter(|&&k| k).count()))
}

fn median(v: &mut [f64]) -> f64 {
    crate::stats::median(v).unwrap_or(0.0)
}

/// The amplitude of the clear background: the most common amplitude (clear glass is
/// one sharp peak, the objects a broad spread), from a histogram over [0, 2·median].
fn clear_amplitude(field: ndarray::ArrayView2<'_, Complex32>) -> Option<f32> {
    const BINS: usize = 256;
    let mut amplitudes: Vec<f32> = field.iter().map(|v| v.norm()).collect();
    let top = 2.0 * crate::stats::median(&mut amplitudes)?;
    if !(top > 0.0 && top.is_finite()) {
        return None;
    }
    let mut histogram = [0usize; BINS];
    for a in &amplitudes {
        let bin = (a / top * BINS as f32) as usize;
        if bin < BINS {
            histogram[bin] += 1;
        }
    }
    // Smooth over ±2 bins so that noise does not pick a spike.
    let smoothed: Vec<usize> = (0..BINS)
        .map(|i| {
            histogram[i.saturating_sub(2)..(i + 3).min(BINS)]
                .iter()
                .sum()
        })
        .collect();
    let peak = (0..BINS).max_by_key(|&i| smoothed[i])?;
    Some((peak as f32 + 0.5) / BINS as f32 * top)
}

/// The median phase step between horizontal and between vertical neighbours that are
/// both background candidates, as ramps over the whole field (rad per field width and
/// height).
/// (Steps from the pixels on a grid of `stride`, each to its next neighbour.)
fn median_ramps(
    field: ndarray::ArrayView2<'_, Complex32>,
    candidate: &[bool],
    stride: usize,
) -> (f64, f64) {
    let (rows, cols) = field.dim();
    let step = |a: Complex32, b: Complex32| (b * a.conj()).arg() as f64;
    let mut along_x = vec![];
    let mut along_y = vec![];
    for r in (0..rows).step_by(stride) {
        for c in (0..cols).step_by(stride) {
            let i = r * cols + c;
            if !candidate[i] {
                continue;
            }
            if c + 1 < cols && candidate[i + 1] {
                along_x.push(step(field[(r, c)], field[(r, c + 1)]));
            }
            if r + 1 < rows && candidate[i + cols] {
                along_y.push(step(field[(r, c)], field[(r + 1, c)]));
            }
        }
    }
    (
        median(&mut along_x) * cols as f64,
        median(&mut along_y) * rows as f64,
    )
}

/// Fraction of each quadrant's pixels that are set.
fn quadrant_fractions(mask: &[bool], rows: usize, cols: usize) -> [f64; 4] {
    let mut set = [0usize; 4];
    let mut all = [0usize; 4];
    for r in 0..rows {
        for c in 0..cols {
            let q = usize::from(r >= rows / 2) * 2 + usize::from(c >= cols / 2);
            all[q] += 1;
            set[q] += usize::from(mask[r * cols + c]);
        }
    }
    [0, 1, 2, 3].map(|q| set[q] as f64 / all[q].max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: usize = 192;

    /// Clear glass of amplitude 0.9 with discs (amplitude 0.6, phase `object_rad`) on a
    /// grid, the whole field carrying `background(x, y)` (x, y ∈ [−½, ½]), and a little
    /// deterministic noise.
    fn sample(
        object_rad: f32,
        background: impl Fn(f64, f64) -> f64,
    ) -> (Array2<Complex32>, Vec<bool>) {
        let mut inside = vec![false; N * N];
        let field = Array2::from_shape_fn((N, N), |(r, c)| {
            let (cx, cy) = ((c % 32) as f64 - 16.0, (r % 32) as f64 - 16.0);
            let disc = cx.hypot(cy) < 8.0;
            inside[r * N + c] = disc;
            let x = (c as f64 + 0.5) / N as f64 - 0.5;
            let y = (r as f64 + 0.5) / N as f64 - 0.5;
            let noise = 0.02 * (((r * 7919 + c * 104_729) % 1000) as f32 / 500.0 - 1.0);
            let (amp, phase) = if disc { (0.6, object_rad) } else { (0.9, 0.0) };
            Complex32::from_polar(amp, phase + noise + background(x, y) as f32)
        });
        (field, inside)
    }

    /// RMS of the glass's phase about its mean, and the mean phase of the objects
    /// against the glass's, rad.
    fn glass_and_objects(field: &Array2<Complex32>, inside: &[bool]) -> (f64, f64) {
        let mean = |want: bool| {
            let s: Complex32 = field
                .iter()
                .zip(inside)
                .filter(|(_, &i)| i == want)
                .map(|(v, _)| v / v.norm())
                .sum();
            s / s.norm()
        };
        let (glass, objects) = (mean(false), mean(true));
        let (mut sum, mut count) = (0.0, 0usize);
        for (v, _) in field.iter().zip(inside).filter(|(_, &i)| !i) {
            let d = (v * glass.conj()).arg() as f64;
            sum += d * d;
            count += 1;
        }
        (
            (sum / count as f64).sqrt(),
            (objects * glass.conj()).arg() as f64,
        )
    }

    #[test]
    fn a_bowl_and_a_tilt_under_the_glass_come_off_and_the_objects_keep_their_phase() {
        let (mut field, inside) = sample(1.0, |x, y| 2.0 * x - 1.5 * y + 3.0 * (x * x + y * y));
        let before = glass_and_objects(&field, &inside);
        let done = flatten_background_phase(&mut field, N);
        let (glass, objects) = glass_and_objects(&field, &inside);
        assert!(before.0 > 0.5, "the test's bowl is there: {before:?}");
        assert!(glass < 0.03, "glass {glass:.3} rad RMS after {done:?}");
        assert!(
            (objects - 1.0).abs() < 0.03,
            "objects at {objects:.3} rad, not 1"
        );
        assert_eq!((done.fitted, done.quadratic), (1, 1), "{done:?}");
    }

    #[test]
    fn a_ramp_of_many_turns_unwraps() {
        // 9 turns across the field: the flat start would lock onto an alias.
        let (mut field, inside) = sample(0.5, |x, _| 9.0 * std::f64::consts::TAU * x);
        let done = flatten_background_phase(&mut field, N);
        let (glass, objects) = glass_and_objects(&field, &inside);
        assert!(glass < 0.03, "glass {glass:.3} rad RMS after {done:?}");
        assert!((objects - 0.5).abs() < 0.03, "objects at {objects:.3} rad");
    }

    #[test]
    fn blocks_follow_a_background_that_no_quadratic_fits() {
        let wavy = |x: f64, y: f64| 0.8 * (std::f64::consts::TAU * 1.5 * x).sin() * (1.0 + y);
        let (whole, inside) = sample(1.0, wavy);
        let mut one = whole.clone();
        flatten_background_phase(&mut one, N);
        let mut blocks = whole;
        let done = flatten_background_phase(&mut blocks, N / 3);
        let (g1, _) = glass_and_objects(&one, &inside);
        let (gb, objects) = glass_and_objects(&blocks, &inside);
        assert!(done.blocks > 1, "{done:?}");
        assert!(gb < 0.5 * g1, "blocks leave {gb:.3} rad, one fit {g1:.3}");
        assert!((objects - 1.0).abs() < 0.05, "objects at {objects:.3} rad");
    }

    #[test]
    fn a_field_without_clear_background_is_left_as_it_is() {
        // Amplitude spread evenly over 0.2..1: no level holds a tenth of the field.
        let field = Array2::from_shape_fn((N, N), |(r, c)| {
            let a = 0.2 + 0.8 * ((r * 31 + c * 17) % 97) as f32 / 97.0;
            Complex32::from_polar(a, (r as f32 * 0.05).sin())
        });
        let mut flattened = field.clone();
        let done = flatten_background_phase(&mut flattened, N / 3);
        assert_eq!(done.fitted, 0, "{done:?}");
        assert_eq!(flattened, field);
    }

    #[test]
    fn the_auto_block_is_three_led_periods_in_frequency() {
        let um = auto_block_um(&LedGeometry::paper(), 0.47);
        // Δf = 2.5 / (0.47 · 92) cycles/µm.
        assert!((um - 3.0 * 0.47 * 92.0 / 2.5).abs() < 1e-9, "{um}");
    }
}
