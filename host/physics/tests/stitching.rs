//! Stitching a field from tiles should add as little error as it can to the tiles' own:
//! each tile's EPRY leaves the object with an unknown global phase, which the blend
//! takes off against what neighbours placed, over the part of the overlap where both
//! tiles were constrained by the data. On a simulated field of 4 × 4 tiles (cells and
//! bars on clear glass), the stitched image, scored with one global phase, is compared
//! with each tile scored with its own, with the phase as EPRY left it and with the
//! clear background flattened (`--flatten-background`).
//!
//! Issue 13 asks for stitching within 1.1× of the tiles' own error and a step across
//! tile borders below what the sample and noise give. Kept, measured here: 1.29×
//! (0.079 against 0.061; 1.69× while the blend used the tiles' worst part, before
//! [`fpm_physics::reconstruct::tiled::TileMargins`] sized the margins from the PSF),
//! and a border step ([`seam_steps`]) of 0.087 rad rms against 0.064 rad across the
//! middle of a tile. What is left is each tile's slow phase (a bowl across the field,
//! ramps per tile), which the frames hardly determine. Flattened: 1.05× (0.037
//! against 0.035) and 0.019 against 0.017 rad, with no bowl left. The bounds below
//! guard each against getting worse.

use fpm_physics::frame::LitFrame;
use fpm_physics::reconstruct::{tiled, Flatten, Settings};
use fpm_physics::simulate::{acquire_in_focus, Camera, ObjectField};
use fpm_physics::{LedGeometry, System};
use rustfft::num_complex::Complex32;

/// ‖r·c − t‖ / ‖t‖ with c the best complex factor, over `r`, `t`.
fn nrmse(r: &[Complex32], t: &[Complex32]) -> f64 {
    let dot = |a: &[Complex32], b: &[Complex32]| -> (f64, f64) {
        a.iter().zip(b).fold((0.0, 0.0), |(re, im), (x, y)| {
            let p = x.conj() * y;
            (re + p.re as f64, im + p.im as f64)
        })
    };
    let (re, im) = dot(r, t);
    let rr: f64 = r.iter().map(|v| v.norm_sqr() as f64).sum();
    let (cre, cim) = (re / rr, im / rr);
    let err: f64 = r
        .iter()
        .zip(t)
        .map(|(v, w)| {
            let (vr, vi) = (v.re as f64, v.im as f64);
            let (er, ei) = (
                vr * cre - vi * cim - w.re as f64,
                vr * cim + vi * cre - w.im as f64,
            );
            er * er + ei * ei
        })
        .sum();
    let tt: f64 = t.iter().map(|v| v.norm_sqr() as f64).sum();
    (err / tt).sqrt()
}

#[test]
fn stitching_tiles_adds_little_to_their_own_error() {
    let system = System::paper();
    let geometry = LedGeometry::paper();
    let size = 384;
    let object = ObjectField::test_sample(&system, size, 48, 2, 11);
    let camera = Camera::realistic();
    let frames = acquire_in_focus(&system, &geometry, &object, &camera, 6);
    let lit: Vec<LitFrame> = frames.iter().map(|f| f.lit(&camera)).collect();
    let truth = object.crop_to_camera();
    let stitch = |flatten: Flatten| {
        let settings = Settings {
            upsample: 2,
            flatten,
            ..Settings::default()
        };
        let out = tiled::reconstruct(&system, &geometry, &lit, settings, 8, Some(160), &|_, _| {})
            .expect("reconstructs");
        eprintln!("{flatten:?}:");
        measure(&out, &truth)
    };
    // (border step against the middle of a tile, stitched against the tiles' own)
    let kept = stitch(Flatten::Keep);
    kept.within_bounds("kept", 2.0, 1.4);
    let flat = stitch(Flatten::Auto);
    flat.within_bounds("flattened", 1.3, 1.1);
    assert!(
        flat.stitched < 0.7 * kept.stitched,
        "flattening the clear background leaves {:.3} against {:.3} kept",
        flat.stitched,
        kept.stitched
    );
}

/// What [`measure`] finds.
struct Stitched {
    /// RMS over tiles of each tile's NRMSE on its inner part, its own phase off.
    own_rms: f64,
    /// The stitched image's NRMSE over the same parts, one global phase off.
    stitched: f64,
    /// RMS phase step across tile borders, and across the middle of a tile, rad.
    seams: f64,
    within: f64,
}

impl Stitched {
    /// Assert the border step within `seam_factor` of the step across a tile's middle
    /// and the stitched image within `stitch_factor` of the tiles' own NRMSE.
    fn within_bounds(&self, label: &str, seam_factor: f64, stitch_factor: f64) {
        assert!(
            self.seams <= seam_factor * self.within,
            "{label}: tile borders step by {:.3} rad against {:.3} rad inside tiles",
            self.seams,
            self.within
        );
        assert!(
            self.stitched <= stitch_factor * self.own_rms,
            "{label}: stitching adds error: {:.3} against the tiles' own {:.3}",
            self.stitched,
            self.own_rms
        );
    }
}

/// Score `out` against `truth` (printing each tile, the bowl and the seams).
fn measure(out: &tiled::TiledOutcome, truth: &ndarray::Array2<Complex32>) -> Stitched {
    assert!(
        out.layout.tiles.len() >= 9,
        "a field of several tiles each way: {} tiles",
        out.layout.tiles.len()
    );
    let side = out.layout.size;
    let mut own = vec![];
    let (mut all_r, mut all_t) = (vec![], vec![]);
    for t in &out.tiles {
        // Each tile's inner part, where the blend gives it full weight.
        let m = side / 8;
        let region = ndarray::s![
            2 * (t.tile.y0 + m)..2 * (t.tile.y0 + side - m),
            2 * (t.tile.x0 + m)..2 * (t.tile.x0 + side - m)
        ];
        let r: Vec<Complex32> = out.object.slice(region).iter().copied().collect();
        let w: Vec<Complex32> = truth.slice(region).iter().copied().collect();
        own.push(nrmse(&r, &w));
        let c: Complex32 = r.iter().zip(&w).map(|(a, b)| a.conj() * b).sum();
        eprintln!(
            "tile ({:4}, {:4}): NRMSE {:.3}, its own phase {:+.3} rad",
            t.tile.x0,
            t.tile.y0,
            own[own.len() - 1],
            c.arg()
        );
        all_r.extend(r);
        all_t.extend(w);
    }
    // Diagnostic: the stitched image with a global phase bowl (a + b·x + c·y + q·r²)
    // taken off too.
    {
        let (h, w) = out.object.dim();
        let mut rows = vec![];
        let mut rhs = vec![];
        let mut idx = vec![];
        for t in &out.tiles {
            let m = side / 8;
            for i in 2 * (t.tile.y0 + m)..2 * (t.tile.y0 + side - m) {
                for j in 2 * (t.tile.x0 + m)..2 * (t.tile.x0 + side - m) {
                    if (i + j) % 7 != 0 {
                        continue;
                    }
                    let (x, y) = (j as f64 / w as f64 - 0.5, i as f64 / h as f64 - 0.5);
                    let d = (out.object[[i, j]].conj() * truth[[i, j]]).arg() as f64;
                    rows.push([1.0, x, y, x * x + y * y]);
                    rhs.push(d);
                    idx.push((i, j));
                }
            }
        }
        let a = nalgebra::DMatrix::from_fn(rows.len(), 4, |i, k| rows[i][k]);
        let b = nalgebra::DVector::from_vec(rhs);
        let fit = a.svd(true, true).solve(&b, 1e-12).expect("least squares");
        let corrected: Vec<Complex32> = idx
            .iter()
            .map(|&(i, j)| {
                let (x, y) = (j as f64 / w as f64 - 0.5, i as f64 / h as f64 - 0.5);
                let ph = fit[0] + fit[1] * x + fit[2] * y + fit[3] * (x * x + y * y);
                out.object[[i, j]] * Complex32::from_polar(1.0, ph as f32)
            })
            .collect();
        let t: Vec<Complex32> = idx.iter().map(|&(i, j)| truth[[i, j]]).collect();
        let plain: Vec<Complex32> = idx.iter().map(|&(i, j)| out.object[[i, j]]).collect();
        eprintln!(
            "bowl fit {:.3?} rad; stitched (sampled) {:.3} → {:.3} with the bowl off",
            fit.as_slice(),
            nrmse(&plain, &t),
            nrmse(&corrected, &t)
        );
    }
    let (borders, seams, within) = seam_steps(out, truth);
    eprintln!(
        "phase step across the {borders} tile borders: rms {seams:.3} rad; the same across \
         the middle of a tile: rms {within:.3} rad"
    );
    let own_rms = (own.iter().map(|e| e * e).sum::<f64>() / own.len() as f64).sqrt();
    let stitched = nrmse(&all_r, &all_t);
    eprintln!(
        "tiles' own NRMSE {own:.3?} (rms {own_rms:.3}); stitched over the same parts {stitched:.3} ({:.2}×)",
        stitched / own_rms
    );
    Stitched {
        own_rms,
        stitched,
        seams,
        within,
    }
}

/// The step in phase error (stitched against truth) across each border between
/// neighbouring tiles: the mean phase error over a band on one side of the overlap
/// against a band on the other (each band 8 camera pixels wide, the overlap between
/// them, over the rows or columns both tiles fully cover). For comparison, the same
/// two bands the same distance apart across the middle of a tile, where there is no
/// border: what the sample, noise and any smooth phase error give on their own.
/// Returns the number of borders and the rms of both, rad.
fn seam_steps(out: &tiled::TiledOutcome, truth: &ndarray::Array2<Complex32>) -> (usize, f64, f64) {
    let layout = &out.layout;
    let (side, band) = (layout.size, 8);
    let u = out.object.dim().1 / layout.width;
    // Mean phase of stitched·conj(truth) over HR rows `rows` and columns `cols`.
    let mean_phase = |rows: std::ops::Range<usize>, cols: std::ops::Range<usize>| -> f64 {
        let mut c = Complex32::default();
        for r in rows.start * u..rows.end * u {
            for k in cols.start * u..cols.end * u {
                c += out.object[[r, k]] * truth[[r, k]].conj();
            }
        }
        c.arg() as f64
    };
    let wrap = |d: f64| {
        (d + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI
    };
    let (mut seams, mut within) = (vec![], vec![]);
    let tiles = &layout.tiles;
    for a in tiles {
        let inner = |start: usize| start + side / 8..start + side - side / 8;
        // The neighbour to the right and the one below.
        for b in tiles {
            let across_x = b.y0 == a.y0 && b.x0 > a.x0 && b.x0 < a.x0 + side;
            let across_y = b.x0 == a.x0 && b.y0 > a.y0 && b.y0 < a.y0 + side;
            if !(across_x || across_y) {
                continue;
            }
            // The overlap along the axis crossed, and the width the two bands span.
            let (lo, hi) = if across_x {
                (b.x0, a.x0 + side)
            } else {
                (b.y0, a.y0 + side)
            };
            let span = hi - lo + 2 * band;
            let mid = |start: usize| start + side / 2 - span / 2;
            let step = |first: usize, other: std::ops::Range<usize>| {
                let (near, far) = (first..first + band, first + span - band..first + span);
                if across_x {
                    wrap(mean_phase(other.clone(), far) - mean_phase(other, near))
                } else {
                    wrap(mean_phase(far, other.clone()) - mean_phase(near, other))
                }
            };
            let (start, other) = if across_x {
                (a.x0, inner(a.y0))
            } else {
                (a.y0, inner(a.x0))
            };
            seams.push(step(lo - band, other.clone()));
            within.push(step(mid(start), other));
        }
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    (seams.len(), rms(&seams), rms(&within))
}
