//! One slide image from many fields: each field's reconstruction is placed where the
//! images say it is, not only where the stage says.
//!
//! 1. Neighbouring fields are registered on their overlap by phase correlation of the
//!    complex object (amplitude and phase at once; each field's arbitrary global phase
//!    drops out of the normalised cross-power spectrum), the window taken where the
//!    stage positions put the overlap, widened by the stage's error.
//! 2. The positions are solved by least squares over every pair's measured offset,
//!    with the stage positions as the prior (σ of the stage's error), so that a pair
//!    with nothing to register on (blank glass) falls back to the stage, and one bad
//!    pair cannot tear the mosaic; pairs that disagree with the solution by more than
//!    a few σ are dropped and the solve repeated.
//! 3. Each field's global phase is taken from its pairs (a's phase over b's where they
//!    coincide), along the tree of the best-matched pairs from the central field.
//! 4. Fields are shifted by their sub-pixel remainder (Fourier shift), rotated by their
//!    phase, and blended with sin² ramps across the overlaps
//!    ([`crate::tiles::Taper`]), a band of rows at a time ([`blend_rows`]).
//!
//! Coordinates: a field's position is the slide point at its centre pixel (W/2, H/2),
//! µm; image columns run along +x and rows along +y, as the stage's axes.

use ndarray::{Array2, ArrayView2};
use rustfft::num_complex::Complex32;
use serde::Serialize;

use crate::fft::Fft2;

/// One field: its reconstruction (HR grid, `pitch_um` pixels) and where the stage put
/// its centre, µm.
#[derive(Debug, Clone, Copy)]
pub struct Field<'a> {
    pub object: ArrayView2<'a, Complex32>,
    pub stage_um: (f64, f64),
}

/// Two overlapping fields' offset as the images measure it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Pair {
    pub a: usize,
    pub b: usize,
    /// Position of b minus position of a, µm, measured.
    pub offset_um: (f64, f64),
    /// The same from the stage.
    pub stage_offset_um: (f64, f64),
    /// The normalised correlation where the fields match (1: perfectly).
    pub peak: f64,
    /// The best other candidate's score over the one taken (near 1: an ambiguous
    /// overlap, repeated texture), for the report.
    pub runner_up: f64,
    /// The matched overlap over the one the stage promised: a registration's error
    /// grows as its overlap shrinks, and it is weighed so.
    pub overlap_fraction: f64,
    /// arg Σ a·b̄ where they coincide: a's global phase over b's (each
    /// reconstruction's own is arbitrary), rad.
    pub phase_rad: f64,
    /// Whether the solve kept it.
    pub used: bool,
}

/// How to stitch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Settings {
    /// The stage's position error, 1σ, µm: how far the overlap is searched (4σ, but
    /// at most half a field) and how much the stage prior weighs.
    pub stage_sigma_um: f64,
    /// A registration's own error, 1σ, µm (a fraction of a pixel where the overlap has
    /// texture).
    pub pair_sigma_um: f64,
    /// A pair is trusted when its match's normalised correlation reaches this (blank
    /// glass does not); a trusted pair that disagrees with the others is dropped in
    /// the solve.
    pub min_score: f64,
    /// Border of each field given no weight, pixels (EPRY's edge artefacts).
    pub unblended_px: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            stage_sigma_um: 10.0,
            pair_sigma_um: 0.3,
            min_score: 0.7,
            unblended_px: 4,
        }
    }
}

/// The solved layout.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Layout {
    /// Each field's centre, µm, as solved.
    pub positions_um: Vec<(f64, f64)>,
    /// Every pair registered.
    pub pairs: Vec<Pair>,
    /// RMS of the used pairs' residuals after the solve, µm.
    pub residual_rms_um: f64,
    /// Each field's global phase rotation onto the field nearest the centre, rad.
    pub phases_rad: Vec<f64>,
}

/// The normalised correlation of `a` and `b` with `b`'s pixel (0, 0) on `a`'s pixel
/// `q` = (col, row), over the pixels both cover (at least `min_area`): |Σ a·b̄| over
/// the norms, each window's mean removed, so 1 is a perfect match whatever the two
/// fields' global phases.
pub fn correlation(
    a: ArrayView2<'_, Complex32>,
    b: ArrayView2<'_, Complex32>,
    q: (isize, isize),
    min_area: usize,
) -> Option<f64> {
    let (ha, wa) = a.dim();
    let (hb, wb) = b.dim();
    let c0 = q.0.max(0);
    let r0 = q.1.max(0);
    let c1 = (q.0 + wb as isize).min(wa as isize);
    let r1 = (q.1 + hb as isize).min(ha as isize);
    if c1 <= c0 || r1 <= r0 || (((c1 - c0) * (r1 - r0)) as usize) < min_area {
        return None;
    }
    let n = ((c1 - c0) * (r1 - r0)) as f64;
    let (mut ma, mut mb) = (
        rustfft::num_complex::Complex64::default(),
        rustfft::num_complex::Complex64::default(),
    );
    let c64 = |v: Complex32| rustfft::num_complex::Complex64::new(v.re as f64, v.im as f64);
    for r in r0..r1 {
        for c in c0..c1 {
            ma += c64(a[[r as usize, c as usize]]);
            mb += c64(b[[(r - q.1) as usize, (c - q.0) as usize]]);
        }
    }
    ma /= n;
    mb /= n;
    let (mut ab, mut aa, mut bb) = (rustfft::num_complex::Complex64::default(), 0.0, 0.0);
    for r in r0..r1 {
        for c in c0..c1 {
            let x = c64(a[[r as usize, c as usize]]) - ma;
            let y = c64(b[[(r - q.1) as usize, (c - q.0) as usize]]) - mb;
            ab += x * y.conj();
            aa += x.norm_sqr();
            bb += y.norm_sqr();
        }
    }
    (aa > 0.0 && bb > 0.0).then(|| ab.norm() / (aa * bb).sqrt())
}

/// Where one image sits on another.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// `b`'s pixel (0, 0) on `a`'s, (col, row), sub-pixel.
    pub at: (f64, f64),
    /// The normalised correlation there (1: a perfect match).
    pub score: f64,
    /// The next candidate's weighted score over this one's (near 1: not distinct).
    pub runner_up: f64,
    /// How much of the expected overlap the match's overlap covers.
    pub overlap_fraction: f64,
}

/// Where `b` sits on `a` (`b`'s pixel (0, 0) on `a`'s pixel (col, row), sub-pixel),
/// searched within `radius` pixels of `guess`, and how well it matches. Every offset
/// whose overlap covers at least `min_area` pixels is scored at once by FFT (the
/// correlation over the overlap's energies, each window's global mean removed); the
/// strongest local maxima are scored again exactly ([`correlation`]), each weighted by
/// how much of `expected_area` its overlap covers — over a small overlap a chance
/// match correlates as well as the true one over a large one.
pub fn locate(
    a: ArrayView2<'_, Complex32>,
    b: ArrayView2<'_, Complex32>,
    guess: (f64, f64),
    radius: f64,
    min_area: usize,
    expected_area: usize,
) -> Option<Match> {
    let (ha, wa) = a.dim();
    let (hb, wb) = b.dim();
    let (h, w) = ((ha + hb).next_power_of_two(), (wa + wb).next_power_of_two());
    let mut fft = Fft2::new(w, h);
    // Zero-padded spectra of an image (its mean removed), of its |·|², and of its
    // support: the correlation and the energies under every overlap, by FFT.
    let mut spectra = |img: ArrayView2<'_, Complex32>| {
        let (ih, iw) = img.dim();
        let mean = img.iter().copied().sum::<Complex32>() / (ih * iw).max(1) as f32;
        let mut v = vec![Complex32::default(); w * h];
        let mut e = vec![Complex32::default(); w * h];
        let mut one = vec![Complex32::default(); w * h];
        for ((r, c), &x) in img.indexed_iter() {
            let d = x - mean;
            v[r * w + c] = d;
            e[r * w + c] = Complex32::new(d.norm_sqr(), 0.0);
            one[r * w + c] = Complex32::new(1.0, 0.0);
        }
        for buf in [&mut v, &mut e, &mut one] {
            fft.forward(buf);
        }
        (v, e, one)
    };
    let (va, ea, oa) = spectra(a);
    let (vb, eb, ob) = spectra(b);
    // corr(x, y)(q) = Σ_u x(u + q)·conj(y(u)).
    let mut corr = |x: &[Complex32], y: &[Complex32]| {
        let mut out: Vec<Complex32> = x.iter().zip(y).map(|(p, q)| p * q.conj()).collect();
        fft.inverse(&mut out);
        out
    };
    let cab = corr(&va, &vb);
    let energy_a = corr(&ea, &ob);
    let energy_b = corr(&oa, &eb);
    let area = corr(&oa, &ob);
    let wrap = |k: usize, n: usize| {
        if k >= n / 2 {
            k as isize - n as isize
        } else {
            k as isize
        }
    };
    let expected = expected_area.max(1) as f64;
    let weight = |area: f64| (area / expected).min(1.0).sqrt();
    let mut map = vec![-1.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let q = (wrap(c, w), wrap(r, h));
            if ((q.0 as f64 - guess.0).powi(2) + (q.1 as f64 - guess.1).powi(2)).sqrt()
                > radius + 1.0
            {
                continue;
            }
            let i = r * w + c;
            if area[i].re < min_area as f32 {
                continue;
            }
            let norm = (energy_a[i].re.max(0.0) * energy_b[i].re.max(0.0)).sqrt();
            if norm > 0.0 {
                map[i] = cab[i].norm() / norm * weight(area[i].re as f64) as f32;
            }
        }
    }
    // Local maxima, strongest first, scored exactly.
    let mut peaks: Vec<(f32, (isize, isize))> = Vec::new();
    for r in 0..h {
        for c in 0..w {
            let v = map[r * w + c];
            if v <= 0.0 {
                continue;
            }
            let is_max = (-1isize..=1).all(|dr| {
                (-1isize..=1).all(|dc| {
                    let rr = (r as isize + dr).rem_euclid(h as isize) as usize;
                    let cc = (c as isize + dc).rem_euclid(w as isize) as usize;
                    map[rr * w + cc] <= v
                })
            });
            if is_max {
                peaks.push((v, (wrap(c, w), wrap(r, h))));
            }
        }
    }
    peaks.sort_by(|x, y| y.0.total_cmp(&x.0));
    let overlap_area = |q: (isize, isize)| {
        let cols = (q.0 + wb as isize).min(wa as isize) - q.0.max(0);
        let rows = (q.1 + hb as isize).min(ha as isize) - q.1.max(0);
        (cols.max(0) * rows.max(0)) as f64
    };
    let exact = |q: (isize, isize)| {
        correlation(a, b, q, min_area).map(|s| (s, s * weight(overlap_area(q))))
    };
    // Each candidate climbed to its exact local maximum (the FFT's map removes each
    // window's global mean, the exact score each overlap's own).
    let climb = |mut q: (isize, isize)| -> Option<((isize, isize), f64, f64)> {
        let (mut s, mut ranked) = exact(q)?;
        for _ in 0..16 {
            let mut moved = false;
            for (dc, dr) in [
                (-1, 0),
                (1, 0),
                (0, -1),
                (0, 1),
                (-1, -1),
                (1, 1),
                (-1, 1),
                (1, -1),
            ] {
                let next = (q.0 + dc, q.1 + dr);
                // Climbed on the correlation itself: the area weight only chooses
                // between candidates, and would pull each toward a larger overlap.
                if let Some((ns, nr)) = exact(next) {
                    if ns > s {
                        (q, s, ranked, moved) = (next, ns, nr, true);
                    }
                }
            }
            if !moved {
                break;
            }
        }
        Some((q, s, ranked))
    };
    let mut scored: Vec<((isize, isize), f64, f64)> = Vec::new();
    for &(_, q) in peaks.iter().take(8) {
        if let Some(c) = climb(q) {
            // Candidates that climbed to (nearly) the same place are one peak.
            if !scored
                .iter()
                .any(|x| (x.0 .0 - c.0 .0).abs() <= 3 && (x.0 .1 - c.0 .1).abs() <= 3)
            {
                scored.push(c);
            }
        }
    }
    scored.sort_by(|x, y| y.2.total_cmp(&x.2));
    let &(q, score, ranked) = scored.first()?;
    let runner_up = scored.get(1).map_or(0.0, |x| x.2 / ranked.max(1e-12));
    // Sub-pixel: a parabola through the correlation either side, per axis.
    let vertex = |m: Option<f64>, p: Option<f64>| match (m, p) {
        (Some(m), Some(p)) => {
            let d = m - 2.0 * score + p;
            if d.abs() > 1e-12 {
                (0.5 * (m - p) / d).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
    };
    let dx = vertex(
        correlation(a, b, (q.0 - 1, q.1), min_area),
        correlation(a, b, (q.0 + 1, q.1), min_area),
    );
    let dy = vertex(
        correlation(a, b, (q.0, q.1 - 1), min_area),
        correlation(a, b, (q.0, q.1 + 1), min_area),
    );
    Some(Match {
        at: (q.0 as f64 + dx, q.1 as f64 + dy),
        score,
        runner_up,
        overlap_fraction: overlap_area(q) / expected,
    })
}

/// Where a field lies, without its pixels: its size and where the stage put its centre.
/// Everything but the registration itself is planned from footprints, so that a
/// slide's fields need not all be in memory at once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    /// (rows, columns) of its reconstruction.
    pub dim: (usize, usize),
    /// Where the stage put its centre, µm.
    pub stage_um: (f64, f64),
}

impl Field<'_> {
    /// Its size and place.
    pub fn footprint(&self) -> Footprint {
        Footprint {
            dim: self.object.dim(),
            stage_um: self.stage_um,
        }
    }
}

/// A field's pixel rectangle in slide µm: (x0, y0, x1, y1) of its pixel centres.
fn extent(f: &Footprint, pitch: f64, at: (f64, f64)) -> (f64, f64, f64, f64) {
    let (h, w) = f.dim;
    let x0 = at.0 - (w / 2) as f64 * pitch;
    let y0 = at.1 - (h / 2) as f64 * pitch;
    (
        x0,
        y0,
        x0 + (w - 1) as f64 * pitch,
        y0 + (h - 1) as f64 * pitch,
    )
}

/// What fields are registered on: the magnitude of the complex object's gradient. It
/// keeps the edges of cells and bars in amplitude and phase alike, and drops what
/// differs between two reconstructions of the same place: each one's global phase and
/// its slow phase (a bowl, a ramp) that the frames hardly determine.
fn features(z: ArrayView2<'_, Complex32>) -> Array2<Complex32> {
    let (h, w) = z.dim();
    Array2::from_shape_fn((h, w), |(r, c)| {
        let dx = z[[r, (c + 1).min(w - 1)]] - z[[r, c.saturating_sub(1)]];
        let dy = z[[(r + 1).min(h - 1), c]] - z[[r.saturating_sub(1), c]];
        Complex32::new((dx.norm_sqr() + dy.norm_sqr()).sqrt(), 0.0)
    })
}

/// A field's pixels: rows `rows.0..rows.1`, columns `cols.0..cols.1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    pub rows: (usize, usize),
    pub cols: (usize, usize),
}

impl Window {
    /// This window of `z`.
    pub fn of<'a>(&self, z: ArrayView2<'a, Complex32>) -> ArrayView2<'a, Complex32> {
        z.slice_move(ndarray::s![
            self.rows.0..self.rows.1,
            self.cols.0..self.cols.1
        ])
    }
}

/// What registering two neighbours takes, planned from their footprints: the part of
/// each facing the other (the overlap as the stage has it, widened by the search
/// margin, each field's border left out) and where the stage puts one on the other.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairPlan {
    pub a: usize,
    pub b: usize,
    /// `a`'s pixels to register on.
    pub window_a: Window,
    /// `b`'s.
    pub window_b: Window,
    /// Where the stage puts `b`'s window on `a`'s, pixels (col, row).
    guess: (f64, f64),
    radius_px: f64,
    min_area: usize,
    expected_area: usize,
    stage_offset_um: (f64, f64),
}

/// Plan the registration of fields `ia` and `ib` (None: too little of them faces the
/// other).
fn plan_pair(
    footprints: &[Footprint],
    (ia, ib): (usize, usize),
    pitch: f64,
    s: &Settings,
) -> Option<PairPlan> {
    let (a, b) = (&footprints[ia], &footprints[ib]);
    let ea = extent(a, pitch, a.stage_um);
    let eb = extent(b, pitch, b.stage_um);
    let margin = (4.0 * s.stage_sigma_um).max(4.0 * pitch);
    let overlap = (
        ea.0.max(eb.0),
        ea.1.max(eb.1),
        ea.2.min(eb.2),
        ea.3.min(eb.3),
    );
    let widened = (
        overlap.0 - margin,
        overlap.1 - margin,
        overlap.2 + margin,
        overlap.3 + margin,
    );
    // Each field's pixels inside the widened overlap, its border left out: a
    // reconstruction's edges carry its periodic boundary's artefacts, which look alike
    // in every field.
    let window = |e: (f64, f64, f64, f64), f: &Footprint| {
        let (h, w) = f.dim;
        let t = s.unblended_px;
        let c0 = ((widened.0 - e.0) / pitch).ceil().max(0.0) as usize;
        let r0 = ((widened.1 - e.1) / pitch).ceil().max(0.0) as usize;
        let c1 = (((widened.2 - e.0) / pitch).floor() as usize + 1).min(w);
        let r1 = (((widened.3 - e.1) / pitch).floor() as usize + 1).min(h);
        let (c0, r0) = (c0.max(t), r0.max(t));
        let (c1, r1) = (
            c1.max(c0).min(w.saturating_sub(t)),
            r1.max(r0).min(h.saturating_sub(t)),
        );
        Window {
            rows: (r0, r1.max(r0)),
            cols: (c0, c1.max(c0)),
        }
    };
    let (wa, wb) = (window(ea, a), window(eb, b));
    let small = |w: &Window| w.cols.1 < w.cols.0 + 16 || w.rows.1 < w.rows.0 + 16;
    if small(&wa) || small(&wb) {
        return None;
    }
    let overlap_px = (
        ((overlap.2 - overlap.0) / pitch).max(0.0),
        ((overlap.3 - overlap.1) / pitch).max(0.0),
    );
    Some(PairPlan {
        a: ia,
        b: ib,
        window_a: wa,
        window_b: wb,
        guess: (
            (eb.0 + wb.cols.0 as f64 * pitch - ea.0 - wa.cols.0 as f64 * pitch) / pitch,
            (eb.1 + wb.rows.0 as f64 * pitch - ea.1 - wa.rows.0 as f64 * pitch) / pitch,
        ),
        radius_px: margin / pitch,
        // At least a quarter of the overlap the stage promises must coincide.
        min_area: ((overlap_px.0 * overlap_px.1) / 4.0).max(64.0) as usize,
        expected_area: (overlap_px.0 * overlap_px.1) as usize,
        stage_offset_um: (b.stage_um.0 - a.stage_um.0, b.stage_um.1 - a.stage_um.1),
    })
}

/// Every pair of edge neighbours worth registering (a corner's overlap is too small),
/// planned from the footprints alone.
pub fn plan_pairs(footprints: &[Footprint], pitch_um: f64, s: &Settings) -> Vec<PairPlan> {
    let n = footprints.len();
    let mut plans = Vec::new();
    for ia in 0..n {
        for ib in ia + 1..n {
            let (ea, eb) = (
                extent(&footprints[ia], pitch_um, footprints[ia].stage_um),
                extent(&footprints[ib], pitch_um, footprints[ib].stage_um),
            );
            let (ow, oh) = (
                ea.2.min(eb.2) - ea.0.max(eb.0),
                ea.3.min(eb.3) - ea.1.max(eb.1),
            );
            let (fw, fh) = (ea.2 - ea.0, ea.3 - ea.1);
            if ow > 0.0 && oh > 0.0 && (ow >= 0.5 * fw || oh >= 0.5 * fh) {
                plans.extend(plan_pair(footprints, (ia, ib), pitch_um, s));
            }
        }
    }
    plans
}

/// Register a planned pair on its windows (`a` and `b`: `plan.window_a` of field
/// `plan.a`, `plan.window_b` of `plan.b`): the offset, how well it matches, and the
/// two fields' relative global phase there.
pub fn register(
    plan: &PairPlan,
    a: ArrayView2<'_, Complex32>,
    b: ArrayView2<'_, Complex32>,
    pitch: f64,
    s: &Settings,
) -> Option<Pair> {
    let (fa, fb) = (features(a), features(b));
    let m = locate(
        fa.view(),
        fb.view(),
        plan.guess,
        plan.radius_px,
        plan.min_area,
        plan.expected_area,
    )?;
    let (qx, qy) = m.at;
    // a's global phase over b's where they coincide (at the nearest whole pixel): what
    // turns b onto a, for the blend.
    let (q0, q1) = (qx.round() as isize, qy.round() as isize);
    let (ha, wa) = a.dim();
    let (hb, wb) = b.dim();
    let mut c = rustfft::num_complex::Complex64::default();
    for r in q1.max(0)..(q1 + hb as isize).min(ha as isize) {
        for k in q0.max(0)..(q0 + wb as isize).min(wa as isize) {
            let p = a[[r as usize, k as usize]] * b[[(r - q1) as usize, (k - q0) as usize]].conj();
            c += rustfft::num_complex::Complex64::new(p.re as f64, p.im as f64);
        }
    }
    let stage_offset = plan.stage_offset_um;
    Some(Pair {
        a: plan.a,
        b: plan.b,
        offset_um: (
            stage_offset.0 + (qx - plan.guess.0) * pitch,
            stage_offset.1 + (qy - plan.guess.1) * pitch,
        ),
        stage_offset_um: stage_offset,
        peak: m.score,
        runner_up: m.runner_up,
        overlap_fraction: m.overlap_fraction,
        phase_rad: c.arg(),
        // Trusted when strong, or nearly so and clearly the only match (its runner-up
        // under half of it): a textured overlap seen through two reconstructions' noise.
        used: m.score >= s.min_score || (m.score >= 0.6 && m.runner_up <= 0.5),
    })
}

/// Solve `(w0·I + L)·x = rhs` by conjugate gradients, L the pairs' weighted graph
/// Laplacian (pairs as (a, b, weight)): the normal equations of the layout.
fn solve_normal(rhs: &[f64], pairs: &[(usize, usize, f64)], w0: f64, start: &[f64]) -> Vec<f64> {
    let n = rhs.len();
    let apply = |p: &[f64]| -> Vec<f64> {
        let mut out: Vec<f64> = p.iter().map(|v| w0 * v).collect();
        for &(a, b, wp) in pairs {
            let d = wp * (p[b] - p[a]);
            out[b] += d;
            out[a] -= d;
        }
        out
    };
    let mut x = start.to_vec();
    let ax = apply(&x);
    let mut r: Vec<f64> = rhs.iter().zip(&ax).map(|(b, a)| b - a).collect();
    let mut p = r.clone();
    let mut rr: f64 = r.iter().map(|v| v * v).sum();
    let scale: f64 = rhs.iter().map(|v| v * v).sum::<f64>().max(1e-300);
    for _ in 0..(4 * n + 20) {
        if rr <= 1e-24 * scale {
            break;
        }
        let ap = apply(&p);
        let alpha = rr / p.iter().zip(&ap).map(|(a, b)| a * b).sum::<f64>();
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        let rr_new: f64 = r.iter().map(|v| v * v).sum();
        let beta = rr_new / rr;
        rr = rr_new;
        for i in 0..n {
            p[i] = r[i] + beta * p[i];
        }
    }
    x
}

/// The least-squares positions along one axis: the stage's (weight `w0`) and each
/// pair's measured offset (a, b, offset, weight).
fn solve_axis(stage: &[f64], pairs: &[(usize, usize, f64, f64)], w0: f64) -> Vec<f64> {
    let mut rhs: Vec<f64> = stage.iter().map(|v| w0 * v).collect();
    for &(a, b, m, wp) in pairs {
        rhs[b] += wp * m;
        rhs[a] -= wp * m;
    }
    let graph: Vec<(usize, usize, f64)> = pairs.iter().map(|&(a, b, _, w)| (a, b, w)).collect();
    solve_normal(&rhs, &graph, w0, stage)
}

/// The variance of p_b − p_a under the normal equations (per axis; both axes alike).
fn difference_variance(
    n: usize,
    pairs: &[(usize, usize, f64)],
    w0: f64,
    a: usize,
    b: usize,
) -> f64 {
    let mut e = vec![0.0; n];
    e[b] = 1.0;
    e[a] = -1.0;
    let x = solve_normal(&e, pairs, w0, &vec![0.0; n]);
    (x[b] - x[a]).max(0.0)
}

/// Register every overlapping pair and solve the fields' positions (all fields in
/// memory; [`plan_pairs`], [`register`] and [`solve`] do the same a pair at a time).
pub fn layout(fields: &[Field<'_>], pitch_um: f64, s: &Settings) -> Layout {
    let footprints: Vec<Footprint> = fields.iter().map(Field::footprint).collect();
    let pairs = plan_pairs(&footprints, pitch_um, s)
        .iter()
        .filter_map(|p| {
            register(
                p,
                p.window_a.of(fields[p.a].object),
                p.window_b.of(fields[p.b].object),
                pitch_um,
                s,
            )
        })
        .collect();
    solve(&footprints, pairs, pitch_um, s)
}

/// The fields' positions from their registered `pairs` and the stage (the prior), and
/// their global phases.
pub fn solve(
    footprints: &[Footprint],
    mut pairs: Vec<Pair>,
    pitch_um: f64,
    s: &Settings,
) -> Layout {
    let w0 = 1.0 / s.stage_sigma_um.powi(2);
    // A pair's σ: the registration's own, grown as its overlap falls short of the
    // promised one (fewer pixels, and nearer the fields' edges), never below a tenth
    // of a pixel.
    let sigma =
        |p: &Pair| s.pair_sigma_um.max(0.1 * pitch_um) / p.overlap_fraction.clamp(0.05, 1.0);
    let stage_x: Vec<f64> = footprints.iter().map(|f| f.stage_um.0).collect();
    let stage_y: Vec<f64> = footprints.iter().map(|f| f.stage_um.1).collect();
    let n = footprints.len();
    let solve = |pairs: &[&Pair]| -> Vec<(f64, f64)> {
        let axis = |k: usize| -> Vec<(usize, usize, f64, f64)> {
            pairs
                .iter()
                .map(|p| {
                    let m = if k == 0 { p.offset_um.0 } else { p.offset_um.1 };
                    (p.a, p.b, m, sigma(p).powi(-2))
                })
                .collect()
        };
        solve_axis(&stage_x, &axis(0), w0)
            .into_iter()
            .zip(solve_axis(&stage_y, &axis(1), w0))
            .collect()
    };
    // Each pair checked against the layout the others give (and its uncertainty
    // there): a wrong match that the rest contradict by more than 4σ is dropped, the
    // worst first, until none is left. Checked against the layout without it, so that a
    // confident wrong pair cannot bend the others out of line first.
    loop {
        let used: Vec<usize> = (0..pairs.len()).filter(|&i| pairs[i].used).collect();
        let mut worst: Option<(usize, f64)> = None;
        for &i in &used {
            let others: Vec<&Pair> = used
                .iter()
                .filter(|&&j| j != i)
                .map(|&j| &pairs[j])
                .collect();
            let without = solve(&others);
            let p = &pairs[i];
            let r = residual(p, &without);
            let graph: Vec<(usize, usize, f64)> = others
                .iter()
                .map(|q| (q.a, q.b, sigma(q).powi(-2)))
                .collect();
            let var = difference_variance(n, &graph, w0, p.a, p.b);
            let excess = r / (4.0 * (sigma(p).powi(2) + var).sqrt()).max(pitch_um);
            if excess > 1.0 && worst.is_none_or(|(_, e)| excess > e) {
                worst = Some((i, excess));
            }
        }
        match worst {
            Some((i, _)) => pairs[i].used = false,
            None => break,
        }
    }
    let kept: Vec<&Pair> = pairs.iter().filter(|p| p.used).collect();
    let positions = solve(&kept);
    let used: Vec<f64> = pairs
        .iter()
        .filter(|p| p.used)
        .map(|p| residual(p, &positions).powi(2))
        .collect();
    let residual_rms_um = if used.is_empty() {
        0.0
    } else {
        (used.iter().sum::<f64>() / used.len() as f64).sqrt()
    };
    let phases_rad = phases(&positions, &pairs);
    Layout {
        positions_um: positions,
        pairs,
        residual_rms_um,
        phases_rad,
    }
}

/// Each field's phase rotation onto the field nearest the centre: along the tree of
/// the best-matched pairs from it (used pairs first; a field that only an unused pair
/// reaches takes that one's phase, one that none reaches keeps its own).
fn phases(positions: &[(f64, f64)], pairs: &[Pair]) -> Vec<f64> {
    let n = positions.len();
    let mut phase = vec![0.0; n];
    if n == 0 {
        return phase;
    }
    let centre = positions.iter().fold((0.0, 0.0), |a, p| {
        (a.0 + p.0 / n as f64, a.1 + p.1 / n as f64)
    });
    let d = |k: usize| (positions[k].0 - centre.0).powi(2) + (positions[k].1 - centre.1).powi(2);
    let root = (0..n).min_by(|&i, &j| d(i).total_cmp(&d(j))).unwrap_or(0);
    let mut reached = vec![false; n];
    reached[root] = true;
    for trusted in [true, false] {
        loop {
            // The strongest pair from a reached field to one not reached.
            let next = pairs
                .iter()
                .filter(|p| p.used || !trusted)
                .filter(|p| reached[p.a] != reached[p.b])
                .max_by(|p, q| {
                    (p.peak * p.overlap_fraction).total_cmp(&(q.peak * q.overlap_fraction))
                });
            let Some(p) = next else { break };
            // ρ_b = ρ_a + arg Σ a·b̄.
            if reached[p.a] {
                phase[p.b] = phase[p.a] + p.phase_rad;
                reached[p.b] = true;
            } else {
                phase[p.a] = phase[p.b] - p.phase_rad;
                reached[p.a] = true;
            }
        }
    }
    phase
}

fn residual(p: &Pair, positions: &[(f64, f64)]) -> f64 {
    let (a, b) = (positions[p.a], positions[p.b]);
    ((b.0 - a.0 - p.offset_um.0).powi(2) + (b.1 - a.1 - p.offset_um.1).powi(2)).sqrt()
}

/// The mosaic's pixel grid: size and the slide position of its first pixel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    /// Slide position of pixel (0, 0), µm.
    pub origin_um: (f64, f64),
    pub pitch_um: f64,
}

impl Canvas {
    /// The grid that holds every field at `positions`.
    pub fn covering(footprints: &[Footprint], positions: &[(f64, f64)], pitch_um: f64) -> Self {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for (f, &p) in footprints.iter().zip(positions) {
            let e = extent(f, pitch_um, p);
            x0 = x0.min(e.0);
            y0 = y0.min(e.1);
            x1 = x1.max(e.2);
            y1 = y1.max(e.3);
        }
        Self {
            width: ((x1 - x0) / pitch_um).ceil() as usize + 1,
            height: ((y1 - y0) / pitch_um).ceil() as usize + 1,
            origin_um: (x0, y0),
            pitch_um,
        }
    }

    /// Where a field at `position` lands: the canvas pixel of its pixel (0, 0) once
    /// shifted by the fraction (x, y) of a pixel (see [`shifted_onto_canvas`]).
    pub fn placement(&self, f: &Footprint, position: (f64, f64)) -> ((usize, usize), (f64, f64)) {
        let e = extent(f, self.pitch_um, position);
        let fx = (e.0 - self.origin_um.0) / self.pitch_um;
        let fy = (e.1 - self.origin_um.1) / self.pitch_um;
        let (ix, iy) = (fx.floor(), fy.floor());
        (
            (ix.max(0.0) as usize, iy.max(0.0) as usize),
            (fx - ix, fy - iy),
        )
    }
}

/// A field's pixels on the canvas's grid: Fourier-shifted by the `fraction` of a pixel
/// its place leaves ([`Canvas::placement`]), so that pixel j of a canvas row reads the
/// field at j − fraction.
pub fn shifted_onto_canvas(
    object: ArrayView2<'_, Complex32>,
    fraction: (f64, f64),
) -> Array2<Complex32> {
    crate::color::shifted_back(&object.to_owned(), -fraction.0, -fraction.1)
}

/// A field as blended: its pixels on the canvas's grid, the canvas pixel of its first
/// pixel, and its global phase rotation.
#[derive(Debug, Clone, Copy)]
pub struct Placed<'a> {
    pub object: ArrayView2<'a, Complex32>,
    pub at: (usize, usize),
    pub phase_rad: f64,
}

/// Rows `rows` of a canvas `width` wide, blended from `placed` with sin² ramps across
/// the overlaps (`overlap_px` the nominal overlap, the ramp's length): the object, and
/// each pixel's total weight (0: no field reached it; the object is 0 there). A band
/// at a time, so that a slide is written as it is blended.
pub fn blend_rows(
    placed: &[Placed<'_>],
    width: usize,
    rows: std::ops::Range<usize>,
    overlap_px: usize,
    s: &Settings,
) -> (Array2<Complex32>, Array2<f32>) {
    let band = rows.end.saturating_sub(rows.start);
    let mut sum = Array2::<Complex32>::zeros((band, width));
    let mut weight = Array2::<f32>::zeros((band, width));
    let taper = crate::tiles::Taper {
        free: s.unblended_px,
        ramp: overlap_px
            .max(2 * s.unblended_px + 2)
            .saturating_sub(2 * s.unblended_px)
            .max(1),
    };
    for p in placed {
        let (h, w) = p.object.dim();
        let (x0, y0) = p.at;
        let rotation = Complex32::from_polar(1.0, p.phase_rad as f32);
        let (r0, r1) = (rows.start.max(y0), rows.end.min(y0 + h));
        for r in r0..r1 {
            let fr = r - y0;
            let wr = taper.weight(fr, h, true, true);
            if wr == 0.0 {
                continue;
            }
            for fc in 0..w.min(width.saturating_sub(x0)) {
                let wt = wr * taper.weight(fc, w, true, true);
                sum[[r - rows.start, x0 + fc]] += p.object[[fr, fc]] * rotation * wt;
                weight[[r - rows.start, x0 + fc]] += wt;
            }
        }
    }
    for (v, &w) in sum.iter_mut().zip(weight.iter()) {
        *v = if w > 0.0 {
            *v / w
        } else {
            Complex32::default()
        };
    }
    (sum, weight)
}

/// Blend the fields laid out by `layout` onto `canvas` (all in memory): the object and
/// where some field covers it (the edges of a mosaic of misplaced fields are ragged).
/// `overlap_px` is the nominal overlap (the ramp's length).
pub fn blend(
    fields: &[Field<'_>],
    layout: &Layout,
    canvas: &Canvas,
    overlap_px: usize,
    s: &Settings,
) -> (Array2<Complex32>, Array2<bool>) {
    let placements: Vec<((usize, usize), Array2<Complex32>)> = fields
        .iter()
        .zip(&layout.positions_um)
        .map(|(f, &p)| {
            let (at, fraction) = canvas.placement(&f.footprint(), p);
            (at, shifted_onto_canvas(f.object, fraction))
        })
        .collect();
    let placed: Vec<Placed<'_>> = placements
        .iter()
        .zip(&layout.phases_rad)
        .map(|((at, object), &phase_rad)| Placed {
            object: object.view(),
            at: *at,
            phase_rad,
        })
        .collect();
    let (object, weight) = blend_rows(&placed, canvas.width, 0..canvas.height, overlap_px, s);
    (object, weight.mapv(|w| w > 0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured complex image, smooth enough to shift by Fourier interpolation.
    fn texture(h: usize, w: usize, seed: u64) -> Array2<Complex32> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let blobs: Vec<(f64, f64, f64, f64)> = (0..80)
            .map(|_| {
                (
                    rng.gen_range(0.0..w as f64),
                    rng.gen_range(0.0..h as f64),
                    rng.gen_range(2.0..6.0),
                    rng.gen_range(-1.0..1.0),
                )
            })
            .collect();
        Array2::from_shape_fn((h, w), |(r, c)| {
            let mut a = 0.0;
            let mut p = 0.0;
            for &(x, y, s, v) in &blobs {
                let g = (-((c as f64 - x).powi(2) + (r as f64 - y).powi(2)) / (2.0 * s * s)).exp();
                a += 0.3 * g * v.abs();
                p += g * v;
            }
            Complex32::from_polar((-a).exp() as f32, p as f32)
        })
    }

    #[test]
    fn locate_finds_a_known_offset_whatever_the_global_phase() {
        let big = texture(96, 96, 3);
        let a = big.slice(ndarray::s![10..74, 10..74]).to_owned();
        // b's first pixel is a's (3, 5).
        let b = big
            .slice(ndarray::s![15..60, 13..50])
            .mapv(|v| v * Complex32::from_polar(1.0, 1.3));
        let m = locate(a.view(), b.view(), (0.0, 0.0), 10.0, 400, 45 * 37).unwrap();
        let (qx, qy) = m.at;
        assert!(
            (qx - 3.0).abs() < 0.1 && (qy - 5.0).abs() < 0.1,
            "{qx} {qy}"
        );
        assert!(m.score > 0.99 && m.runner_up < 0.5, "{m:?}");
    }

    #[test]
    fn a_three_by_three_layout_recovers_the_stage_errors() {
        let pitch = 1.0;
        let slide = texture(340, 340, 7);
        let side = 112usize;
        let step = 85.0;
        let errors = [
            (4.0, -3.0),
            (-7.0, 2.0),
            (1.0, 6.0),
            (-2.0, -8.0),
            (0.0, 0.0),
            (9.0, 1.0),
            (-5.0, 5.0),
            (3.0, -6.0),
            (6.0, 4.0),
        ];
        let mut crops = Vec::new();
        let mut stage = Vec::new();
        let mut truth = Vec::new();
        for (k, error) in errors.iter().enumerate() {
            let (row, col) = (k / 3, k % 3);
            let commanded = (70.0 + col as f64 * step, 70.0 + row as f64 * step);
            let real = (commanded.0 + error.0, commanded.1 + error.1);
            let (x0, y0) = (real.0 as usize - side / 2, real.1 as usize - side / 2);
            crops.push(
                slide
                    .slice(ndarray::s![y0..y0 + side, x0..x0 + side])
                    .mapv(|v| v * Complex32::from_polar(1.0, k as f32)),
            );
            stage.push(commanded);
            truth.push(real);
        }
        let fields: Vec<Field<'_>> = crops
            .iter()
            .zip(&stage)
            .map(|(c, &s)| Field {
                object: c.view(),
                stage_um: s,
            })
            .collect();
        let lay = layout(&fields, pitch, &Settings::default());
        // Up to a common translation (the images cannot know where the slide is).
        let n = 9.0;
        let shift = (0..9).fold((0.0, 0.0), |a, k| {
            (
                a.0 + truth[k].0 - lay.positions_um[k].0,
                a.1 + truth[k].1 - lay.positions_um[k].1,
            )
        });
        let shift = (shift.0 / n, shift.1 / n);
        for (k, (placed, real)) in lay.positions_um.iter().zip(&truth).enumerate() {
            let e = ((placed.0 + shift.0 - real.0).powi(2) + (placed.1 + shift.1 - real.1).powi(2))
                .sqrt();
            // Field 6's only other link (to field 3) has 6 px of overlap left after
            // the fields' borders are trimmed: weighed little, it still pulls.
            assert!(e < 0.75, "field {k}: {e} µm off");
        }
        // Field 6 sits 13 µm further down than commanded: its overlap with field 3 is
        // a few pixels, too little to register on; the other pairs hold it in place.
        assert!(
            lay.pairs.iter().filter(|p| p.used).count() >= 11,
            "{:?}",
            lay.pairs
        );
        let footprints: Vec<Footprint> = fields.iter().map(Field::footprint).collect();
        let canvas = Canvas::covering(&footprints, &lay.positions_um, pitch);
        let (mosaic, covered) = blend(&fields, &lay, &canvas, 27, &Settings::default());
        // Compare with the slide where the canvas lies on it, after one global phase.
        let ox = (canvas.origin_um.0 + shift.0).round() as usize;
        let oy = (canvas.origin_um.1 + shift.1).round() as usize;
        let mut rot = rustfft::num_complex::Complex64::default();
        let (h, w) = mosaic.dim();
        for r in 8..h - 8 {
            for c in (8..w - 8).filter(|&c| covered[[r, c]]) {
                let p = mosaic[[r, c]].conj() * slide[[oy + r, ox + c]];
                rot += rustfft::num_complex::Complex64::new(p.re as f64, p.im as f64);
            }
        }
        let rot = Complex32::new((rot.re / rot.norm()) as f32, (rot.im / rot.norm()) as f32);
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for r in 8..h - 8 {
            for c in (8..w - 8).filter(|&c| covered[[r, c]]) {
                err += (mosaic[[r, c]] * rot - slide[[oy + r, ox + c]]).norm_sqr() as f64;
                norm += slide[[oy + r, ox + c]].norm_sqr() as f64;
            }
        }
        let nrmse = (err / norm).sqrt();

        assert!(nrmse < 0.02, "mosaic NRMSE {nrmse}");
    }
}
