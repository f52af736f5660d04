//! h without trusting the stage: the bright-field/dark-field boundary.
//!
//! The defocus shifts fix only z/h, so h is as good as the stage's z. Which LEDs light
//! the field directly does not depend on z at all: a point x of the sample sees LED i
//! in bright field when its light arrives within the objective's NA,
//! ρ/√(ρ² + h_i²) < NA with ρ = |x − LED i| laterally, i.e. when
//! h_i > ρ·√(1 − NA²)/NA. The array's lateral placement (Δx, Δy, θ and the tilt) comes
//! from the shifts without z, so for every block of every in-focus frame the h at
//! which it turns bright is known, and whether it is lit is measured: h is where the
//! two agree best. An LED whose edge crosses the field draws that edge inside the
//! frame and pins h to a fraction of the field's width; the others bracket it between
//! the last bright and the first dark LED. h is then as accurate as the NA: 1 % of
//! NA is 1 % of h.
//!
//! A block is lit when its mean, per ms, is more than half the same block of the
//! reference (a frame under an LED near the axis). Comparing block by block takes the
//! sample's own light and dark out; the threshold at half keeps the dark-field light
//! that the sample scatters next to the edge, and the bright-field light it loses
//! there, from changing a block's state.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::frame::{LitFrame, Region};
use crate::optics::{LedGeometry, LedIndex, System};
use crate::Image;

/// The blocks a frame is read in, and their centres in the sample plane.
#[derive(Debug, Clone, PartialEq)]
pub struct Blocks {
    /// Side, pixels.
    pub side_px: usize,
    /// Blocks across and down.
    pub across: usize,
    /// Blocks down.
    pub down: usize,
    /// Centre of each block (row-major), µm.
    pub centres_um: Vec<(f64, f64)>,
}

impl Blocks {
    /// Whole blocks of `side_px` over a `(height, width)` frame (a remainder at the
    /// right and bottom is left out).
    pub fn new(system: &System, (height, width): (usize, usize), side_px: usize) -> Self {
        let side_px = side_px.max(1);
        let (across, down) = (width / side_px, height / side_px);
        let centre = |k: usize| (k * side_px) as f64 + (side_px as f64 - 1.0) / 2.0;
        let centres_um = (0..down * across)
            .map(|k| system.pixel_to_sample(centre(k % across), centre(k / across), width, height))
            .collect();
        Self {
            side_px,
            across,
            down,
            centres_um,
        }
    }

    /// The mean of each block of `image`, row-major.
    pub fn means(&self, image: &Image) -> Vec<f64> {
        let s = self.side_px;
        let n = (s * s) as f64;
        (0..self.down * self.across)
            .map(|k| {
                let (r0, c0) = ((k / self.across) * s, (k % self.across) * s);
                let block = image.slice(ndarray::s![r0..r0 + s, c0..c0 + s]);
                block.iter().map(|&v| v as f64).sum::<f64>() / n
            })
            .collect()
    }
}

/// Which blocks of a frame are lit: its block means (per ms) over the reference's,
/// above [`LIT_RATIO`]. `None` where the reference block is too dark to compare
/// (below a tenth of the reference's median block).
pub fn lit_blocks(frame_means: &[f64], reference_means: &[f64]) -> Vec<Option<bool>> {
    let floor = 0.1 * crate::image::median(reference_means.iter().map(|&v| v as f32)) as f64;
    frame_means
        .iter()
        .zip(reference_means)
        .map(|(&f, &r)| (r > floor && r > 0.0).then_some(f > LIT_RATIO * r))
        .collect()
}

/// A block is lit above this share of the reference's same block.
pub const LIT_RATIO: f64 = 0.5;

/// One frame, read block by block.
#[derive(Debug, Clone, PartialEq)]
pub struct LitFrameBlocks {
    /// The LED.
    pub led: LedIndex,
    /// Per block: lit, dark, or not readable.
    pub lit: Vec<Option<bool>>,
}

/// h from the boundary.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoundaryHeight {
    /// h, mm.
    pub height_mm: f64,
    /// 1σ, mm: the best range's width, how far the edges the single frames draw
    /// disagree, and the optics' blur of the edge (not the NA's error).
    pub sigma_mm: f64,
    /// The range of h that fits the blocks best, mm.
    pub best_range_mm: [f64; 2],
    /// Blocks whose state the best h gets wrong (of all readable ones).
    pub mismatched_blocks: usize,
    /// Frames with a block whose state changes within the search range: the ones
    /// that decide h.
    pub deciding_frames: usize,
    /// Frames the edge crosses at the best h (partly bright).
    pub partly_bright: usize,
}

/// The edge in a frame is blurred by the optics over about λ/NA; h is not known
/// better than this many µm of the edge's position (times √(1 − NA²)/NA).
fn edge_blur_um(system: &System) -> f64 {
    system.wavelength_um / system.na
}

/// √(1 − NA²)/NA = 1/tan(asin NA): an LED at lateral distance d from the chief ray
/// is at the pupil's edge at distance d times this.
fn edge_ratio(system: &System) -> f64 {
    (1.0 - system.na * system.na).sqrt() / system.na
}

/// The board height (mm) above which the LED at `led_mm` (x, y; `depth` mm below the
/// board's plane) is bright at block centre `at_um`: where its lateral distance from
/// the chief ray, at the LED's own distance D = h + depth, is D·tan(asin NA)
/// (`ratio` = √(1 − NA²)/NA). A telecentric chief ray goes straight down: D =
/// ratio·|x − x_led|. One aimed at an entrance pupil p above the sample has moved by
/// x·D/p at the LED, so D = ratio·|a + b·D| with a = x − x_led, b = x/p: a quadratic,
/// (1 − ratio²|b|²)·D² − 2·ratio²(a·b)·D − ratio²|a|² = 0, whose positive root is the
/// one that tends to the telecentric D as p grows. Points so far out that
/// ratio·|x|/p ≥ 1 see the chief ray's cone outrun the LEDs: never bright.
/// This runs for every block of every frame and every pupil distance tried
/// ([`fit_entrance_pupil`]), so it is one square root, not an iteration.
fn turns_bright_at_mm(
    system: &System,
    led_mm: (f64, f64),
    depth: f64,
    at_um: (f64, f64),
    ratio: f64,
) -> f64 {
    let (x, y) = (at_um.0 * 1e-3, at_um.1 * 1e-3);
    let (ax, ay) = (x - led_mm.0, y - led_mm.1);
    let (r2, a2) = (ratio * ratio, ax * ax + ay * ay);
    let distance = match system.entrance_pupil_mm {
        None => ratio * a2.sqrt(),
        Some(p) => {
            let (bx, by) = (x / p, y / p);
            let ab = ax * bx + ay * by;
            let lead = 1.0 - r2 * (bx * bx + by * by);
            if lead <= 0.0 {
                return f64::INFINITY;
            }
            (r2 * ab + (r2 * r2 * ab * ab + lead * r2 * a2).sqrt()) / lead
        }
    };
    distance - depth
}

/// Per readable block of `frame`: the h at which the block turns bright, and whether
/// it is lit (computed as it is read: a full frame set of them takes GB).
fn frame_thresholds<'a>(
    system: &'a System,
    geometry: &LedGeometry,
    blocks: &'a Blocks,
    frame: &'a LitFrameBlocks,
) -> impl Iterator<Item = (f64, bool)> + Clone + 'a {
    let ratio = edge_ratio(system);
    let (lx, ly, lh) = geometry.led_position_3d_mm(frame.led);
    let depth = lh - geometry.height_mm;
    blocks
        .centres_um
        .iter()
        .zip(&frame.lit)
        .filter_map(move |(&at, lit)| {
            lit.map(|l| (turns_bright_at_mm(system, (lx, ly), depth, at, ratio), l))
        })
}

/// [`best_range`] over every block of every frame, `None` unless it lies strictly
/// inside `search_mm` (else the frames bound h on one side only).
fn bounded_best_range(
    blocks: impl Iterator<Item = (f64, bool)>,
    (lo, hi): (f64, f64),
) -> Option<(f64, f64, usize)> {
    let (best_lo, best_hi, mismatched) = best_range(blocks, lo, hi)?;
    (best_lo > lo && best_hi < hi).then_some((best_lo, best_hi, mismatched))
}

/// Estimate h (mm) within `search_mm` from `frames` read in `blocks`, with the lateral
/// placement, rotation and tilt of `geometry` (its h is not used). `None` when no
/// block changes state inside the search range, or the best range touches its edge
/// (the frames bound h on one side only).
pub fn estimate(
    system: &System,
    geometry: &LedGeometry,
    blocks: &Blocks,
    frames: &[LitFrameBlocks],
    search_mm: (f64, f64),
) -> Option<BoundaryHeight> {
    let ratio = edge_ratio(system);
    // Per frame and block: (the h at which the block turns bright, whether it is lit).
    let thresholds: Vec<Vec<(f64, bool)>> = frames
        .iter()
        .map(|f| frame_thresholds(system, geometry, blocks, f).collect())
        .collect();
    let (lo, hi) = search_mm;
    let (best_lo, best_hi, mismatched) =
        bounded_best_range(thresholds.iter().flatten().copied(), search_mm)?;
    let height_mm = 0.5 * (best_lo + best_hi);
    // Each frame the edge crosses gives its own h: their spread shows how well the
    // edges are read.
    let single: Vec<f64> = thresholds
        .iter()
        .filter(|t| t.iter().any(|&(h, _)| h < height_mm) && t.iter().any(|&(h, _)| h > height_mm))
        .filter_map(|t| {
            let (a, b, _) = best_range(t.iter().copied(), lo, hi)?;
            (a > lo && b < hi).then_some(0.5 * (a + b))
        })
        .collect();
    let blur_mm = edge_blur_um(system) * 1e-3 * ratio;
    let spread_mm = if single.len() >= 3 {
        let mean = single.iter().sum::<f64>() / single.len() as f64;
        let var =
            single.iter().map(|h| (h - mean).powi(2)).sum::<f64>() / (single.len() - 1) as f64;
        (var / single.len() as f64).sqrt()
    } else {
        0.0
    };
    let sigma_mm = ((best_hi - best_lo) / 12f64.sqrt())
        .hypot(spread_mm)
        .hypot(blur_mm);
    let deciding_frames = thresholds
        .iter()
        .filter(|t| t.iter().any(|&(h, _)| h > lo && h < hi))
        .count();
    Some(BoundaryHeight {
        height_mm,
        sigma_mm,
        best_range_mm: [best_lo, best_hi],
        mismatched_blocks: mismatched,
        deciding_frames,
        partly_bright: single.len(),
    })
}

/// The range of h in (`lo`, `hi`) where the fewest blocks disagree with the rule
/// "lit ⇔ h above the block's threshold", and that fewest. The hull of all ranges that
/// tie.
fn best_range(
    blocks: impl Iterator<Item = (f64, bool)>,
    lo: f64,
    hi: f64,
) -> Option<(f64, f64, usize)> {
    // At h = lo: lit blocks above lo disagree, dark blocks below lo disagree. One pass
    // (each threshold is computed as it is read, for every block of every frame and,
    // in the entrance pupil's fit, for each of 42 candidates).
    let mut wrong = 0usize;
    let mut events: Vec<(f64, bool)> = vec![];
    for (t, lit) in blocks {
        wrong += usize::from(if lit { t >= lo } else { t < lo });
        if t > lo && t < hi {
            events.push((t, lit));
        }
    }
    if events.is_empty() {
        return None;
    }
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Walk up in h: passing a lit block's threshold fixes it, a dark one's breaks it.
    let mut ranges: Vec<(f64, f64, usize)> = Vec::with_capacity(events.len() + 1);
    let mut start = lo;
    for (t, lit) in events {
        ranges.push((start, t, wrong));
        wrong = if lit { wrong - 1 } else { wrong + 1 };
        start = t;
    }
    ranges.push((start, hi, wrong));
    let fewest = ranges.iter().map(|r| r.2).min()?;
    let first = ranges.iter().find(|r| r.2 == fewest)?.0;
    let last = ranges.iter().rev().find(|r| r.2 == fewest)?.1;
    Some((first, last, fewest))
}

/// What the edges say about the objective's entrance pupil: the distance whose
/// bright/dark-field rule ([`crate::optics::System::chief_ray_frequency`]) gets the
/// fewest blocks wrong, beside the system as given. Telecentric and every distance
/// from 10 mm to 1 m (steps of 12 %) are tried, each with its own best h; a tie keeps
/// the nearer to telecentric. Only a field of view wide against h·NA/p tells them
/// apart (a 614 µm field at p = 40 mm: 2330 blocks off against 6515 telecentric; a
/// 230 µm one at p = 20 mm: no clear minimum).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PupilFromBoundary {
    /// The best entrance pupil distance, mm (None: telecentric).
    pub entrance_pupil_mm: Option<f64>,
    /// h at that distance, mm.
    pub height_mm: f64,
    /// Blocks its rule gets wrong.
    pub mismatched_blocks: usize,
    /// Blocks the rule of the system as given gets wrong.
    pub mismatched_blocks_as_given: usize,
}

impl PupilFromBoundary {
    /// Whether the best distance fits clearly better than the system as given: a
    /// tenth fewer blocks wrong.
    pub fn fits_better(&self, given: Option<f64>) -> bool {
        self.entrance_pupil_mm != given
            && (self.mismatched_blocks as f64) < 0.9 * self.mismatched_blocks_as_given as f64
    }
}

/// See [`PupilFromBoundary`]; `as_given` is [`estimate`] with `system` itself (the
/// candidate equal to it is not estimated again). `None` when the edges bound h for
/// no candidate.
pub fn fit_entrance_pupil(
    system: &System,
    geometry: &LedGeometry,
    blocks: &Blocks,
    frames: &[LitFrameBlocks],
    search_mm: (f64, f64),
    as_given: &BoundaryHeight,
) -> Option<PupilFromBoundary> {
    let candidates = std::iter::once(None).chain(
        (0..=40)
            .rev()
            .map(|k| Some(10.0 * 100f64.powf(k as f64 / 40.0))),
    );
    // Each candidate needs only its best h and how many blocks it gets wrong (not the
    // spread that makes a full estimate's σ); they are independent, so in parallel.
    let candidates: Vec<Option<f64>> = candidates.collect();
    let fits: Vec<Option<(f64, usize)>> = candidates
        .par_iter()
        .map(|&p| {
            if p == system.entrance_pupil_mm {
                return Some((as_given.height_mm, as_given.mismatched_blocks));
            }
            let trial = System {
                entrance_pupil_mm: p,
                ..*system
            };
            let all = frames
                .iter()
                .flat_map(|f| frame_thresholds(&trial, geometry, blocks, f));
            let (lo, hi, wrong) = bounded_best_range(all, search_mm)?;
            Some((0.5 * (lo + hi), wrong))
        })
        .collect();
    // The first of the fewest (min_by_key keeps the first), in the candidates' order:
    // telecentric, then far to near.
    let (entrance_pupil_mm, (height_mm, mismatched_blocks)) = candidates
        .into_iter()
        .zip(fits)
        .filter_map(|(p, fit)| Some((p, fit?)))
        .min_by_key(|&(_, (_, wrong))| wrong)?;
    Some(PupilFromBoundary {
        entrance_pupil_mm,
        height_mm,
        mismatched_blocks,
        mismatched_blocks_as_given: as_given.mismatched_blocks,
    })
}

/// Read in-focus `frames` in blocks of `side_px` against the frame under
/// `reference_led` and estimate h within `search_mm` (see [`estimate`]). `None` when
/// the reference frame is missing or the blocks do not bracket h.
pub fn from_frames(
    system: &System,
    geometry: &LedGeometry,
    frames: &[LitFrame<'_>],
    reference_led: LedIndex,
    side_px: usize,
    search_mm: (f64, f64),
) -> Option<BoundaryHeight> {
    BlockReader::from_frames(system, frames, reference_led, side_px)?
        .estimate(system, geometry, search_mm)
}

/// [`from_frames`] one frame at a time, for frames that are not all in memory at once:
/// the reference frame first, then each frame kept only as its lit blocks.
pub struct BlockReader {
    blocks: Blocks,
    dim: (usize, usize),
    reference_means: Vec<f64>,
    read: Vec<LitFrameBlocks>,
}

impl BlockReader {
    /// All of in-focus `frames` read against the one under `reference_led` (None when
    /// it is missing).
    pub fn from_frames(
        system: &System,
        frames: &[LitFrame<'_>],
        reference_led: LedIndex,
        side_px: usize,
    ) -> Option<Self> {
        let reference = frames
            .iter()
            .find(|f| f.led == reference_led && !f.is_multiplexed())?;
        let mut reader = Self::new(system, reference, side_px);
        // Each frame's blocks apart (the frames are independent), in the frames' order.
        reader.read = frames
            .par_iter()
            .filter_map(|f| reader.blocks_of(f))
            .collect();
        Some(reader)
    }

    /// Blocks of `side_px` against `reference` (the frame under the reference LED).
    pub fn new(system: &System, reference: &LitFrame<'_>, side_px: usize) -> Self {
        let dim = reference.measured.dim();
        let blocks = Blocks::new(system, dim, side_px);
        let reference_means = blocks.means(&reference.measured.intensity(Region::whole(dim)));
        Self {
            blocks,
            dim,
            reference_means,
            read: vec![],
        }
    }

    /// Frame `f` (one of a size other than the reference's, or lit by several LEDs,
    /// is left out: an edge is one LED's).
    pub fn read(&mut self, f: &LitFrame<'_>) {
        if let Some(blocks) = self.blocks_of(f) {
            self.read.push(blocks);
        }
    }

    /// Frame `f`'s blocks, lit or not (None: a frame [`Self::read`] leaves out).
    fn blocks_of(&self, f: &LitFrame<'_>) -> Option<LitFrameBlocks> {
        if f.measured.dim() != self.dim || f.is_multiplexed() {
            return None;
        }
        let means = self
            .blocks
            .means(&f.measured.intensity(Region::whole(self.dim)));
        Some(LitFrameBlocks {
            led: f.led,
            lit: lit_blocks(&means, &self.reference_means),
        })
    }

    /// The estimate from the frames read (see [`estimate`]).
    pub fn estimate(
        &self,
        system: &System,
        geometry: &LedGeometry,
        search_mm: (f64, f64),
    ) -> Option<BoundaryHeight> {
        estimate(system, geometry, &self.blocks, &self.read, search_mm)
    }

    /// The entrance pupil the frames read fit best (see [`fit_entrance_pupil`]), beside
    /// `as_given`, this reader's [`Self::estimate`] with `system`.
    pub fn fit_entrance_pupil(
        &self,
        system: &System,
        geometry: &LedGeometry,
        search_mm: (f64, f64),
        as_given: &BoundaryHeight,
    ) -> Option<PupilFromBoundary> {
        fit_entrance_pupil(
            system,
            geometry,
            &self.blocks,
            &self.read,
            search_mm,
            as_given,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks lit by the rule itself at a known h (the wave-optics test is in
    /// `tests/calibration_boundary.rs`): the estimate brackets it; nothing changes in
    /// a window far from it, so there is no estimate there.
    #[test]
    fn the_rule_inverts() {
        let system = System::paper();
        let truth = LedGeometry::paper().placed(0.7, -0.4, 3.0, 91.3);
        let blocks = Blocks::new(&system, (256, 256), 8);
        let frames: Vec<LitFrameBlocks> = truth
            .leds()
            .into_iter()
            .map(|led| LitFrameBlocks {
                led,
                lit: blocks
                    .centres_um
                    .iter()
                    .map(|&(x, y)| Some(truth.is_bright_field(led, x, y, &system)))
                    .collect(),
            })
            .collect();
        let guess = truth.placed(0.7, -0.4, 3.0, 80.0);
        let b = estimate(&system, &guess, &blocks, &frames, (70.0, 110.0)).expect("bracketed");
        assert!(
            b.best_range_mm[0] <= 91.3 && b.best_range_mm[1] >= 91.3,
            "{b:?}"
        );
        assert_eq!(b.mismatched_blocks, 0);
        assert!((b.height_mm - 91.3).abs() < 2.0 * b.sigma_mm, "{b:?}");
        assert!(b.deciding_frames > 10);
        assert!(estimate(&system, &guess, &blocks, &frames, (60.0, 61.0)).is_none());
    }
}
