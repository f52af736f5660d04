//! `fpm bench warnings`: how often each of a reconstruction's warnings fires on good
//! data (false alarms) and on data with the condition it names (detections).
//!
//! Good data: simulated linear, telecentric sets of three samples (cells, weak-phase,
//! stained), two cameras (12-bit, 8-bit) and two dark-field exposures (auto-exposed,
//! dim), their datasets stating the true geometry. Each condition is one thing wrong
//! with such a set, reconstructed as a user would (no flags): frames saved with a
//! display gamma the dataset does not state, a dataset's LED height 8 mm off, a
//! non-telecentric objective. A detection counts where the condition changes the
//! image by ≥ 10 % (complex NRMSE against the same set without it); the cases where it
//! does not are shown apart.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{bail, Context, Result};
use fpm_host::dataset::DatasetOnDisk;
use fpm_host::reconstruction::height::HeightChoice;
use fpm_host::reconstruction::{checks, BoundaryCheck, Check, GeometryChoice, Job};
use fpm_host::simulation::{self, AcquisitionSet, Noise, Scene};
use fpm_physics::reconstruct::ContrastFit;
use fpm_physics::simulate::SampleKind;
use serde::Serialize;

/// What a set has wrong with it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Condition {
    /// Nothing: a linear, telecentric set whose dataset states its true geometry.
    None,
    /// Frames saved with a display gamma of 2.2 that the dataset does not state.
    UndeclaredGamma,
    /// The dataset states the LEDs 8 mm farther than they are.
    WrongHeight,
    /// An objective whose entrance pupil is 60 mm above the sample, reconstructed as
    /// telecentric.
    NonTelecentric,
}

impl Condition {
    /// Every condition that is a fault.
    pub const FAULTS: [Condition; 3] = [
        Self::UndeclaredGamma,
        Self::WrongHeight,
        Self::NonTelecentric,
    ];
}

/// One simulated set.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Case {
    /// The sample.
    pub sample: SampleKind,
    /// 8-bit camera (else 12-bit).
    pub eight_bit: bool,
    /// Dark-field frames dim (else auto-exposed).
    pub dim_dark_field: bool,
    /// Noise seed and sample layout.
    pub seed: u64,
    /// What is wrong with it.
    pub condition: Condition,
}

impl Case {
    /// The check meant to catch its condition: 8-bit frames are scanned for a gamma
    /// by default (and decoded where it is clear, which the check reports); deeper
    /// ones only have the bright-field fit.
    pub fn expected_check(&self) -> Option<Check> {
        match self.condition {
            Condition::None => None,
            Condition::UndeclaredGamma if self.eight_bit => Some(Check::GammaRead),
            Condition::UndeclaredGamma => Some(Check::BrightFieldOffset),
            Condition::WrongHeight => Some(Check::HeightFromEdge),
            Condition::NonTelecentric => Some(Check::EntrancePupil),
        }
    }
}

/// One case's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct Outcome {
    /// The case.
    pub case: Case,
    /// The condition's effect: this NRMSE over the same set's without it, minus 1.
    pub effect: Option<f64>,
    /// The same on the detail (the low-order phase fitted out of both): what is left
    /// of the effect once a phase bowl is not counted.
    pub detail_effect: Option<f64>,
    /// What its reconstruction showed.
    #[serde(flatten)]
    pub scored: Scored,
}

impl Outcome {
    /// What the checks read: the bright-field fit, the edge's h and entrance pupil.
    pub fn evidence(&self) -> String {
        let fit = self.scored.bright_field_fit.map(|f| {
            format!(
                "offset {:+.2} gain {:.2} r {:.2}",
                f.offset_share, f.gain, f.correlation
            )
        });
        let edge = self.scored.boundary.map(|b| {
            let pupil = match b.entrance_pupil {
                Some(p) => format!(
                    " pupil {} ({} blocks off, {} as given)",
                    p.entrance_pupil_mm
                        .map_or("telecentric".to_string(), |mm| format!("{mm:.0} mm")),
                    p.mismatched_blocks,
                    p.mismatched_blocks_as_given
                ),
                None => String::new(),
            };
            format!(
                "h {:.1} ± {:.1} mm{pupil}",
                b.estimate.height_mm, b.sigma_with_na_mm
            )
        });
        let weighed = self.scored.height_choice.map(|c| format!("h {c}"));
        [fit, edge, weighed]
            .into_iter()
            .flatten()
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The checks that fired, by name.
    pub fn fired_names(&self) -> String {
        let names: Vec<&str> = self.scored.fired.iter().map(|c| c.name()).collect();
        names.join(", ")
    }
}

/// A kebab-case enum's name as serde writes it.
fn kebab(value: impl Serialize) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default()
}

/// One check's rates.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Rates {
    /// Good sets it fired on, of how many.
    pub false_alarms: (usize, usize),
    /// Sets with its condition changing the image ≥ 10 % that it fired on, of how many.
    pub detections: (usize, usize),
    /// Sets with its condition changing the image < 10 % that it fired on, of how many.
    pub small_effect_detections: (usize, usize),
}

/// Sensor side, pixels: large enough for the bright/dark-field edges to show in
/// blocks, small enough for ~100 sets in a few minutes.
pub const SIZE: usize = 128;

/// The effect above which a check must catch its condition.
pub const EFFECT: f64 = 0.10;

/// The cases: every good set for `seeds` seeds, and every fault on the auto-exposed
/// good sets of the first `fault_seeds` seeds.
pub fn cases(seeds: u64, fault_seeds: u64) -> Vec<Case> {
    let mut out = vec![];
    for seed in 1..=seeds {
        for sample in SampleKind::ALL {
            for eight_bit in [false, true] {
                for dim_dark_field in [false, true] {
                    let good = Case {
                        sample,
                        eight_bit,
                        dim_dark_field,
                        seed,
                        condition: Condition::None,
                    };
                    out.push(good);
                    if seed <= fault_seeds && !dim_dark_field {
                        out.extend(Condition::FAULTS.map(|condition| Case { condition, ..good }));
                    }
                }
            }
        }
    }
    out
}

/// What one reconstruction showed.
#[derive(Debug, Clone, Serialize)]
pub struct Scored {
    /// Complex NRMSE against the hidden truth.
    pub complex_nrmse: f64,
    /// The same with the low-order phase (piston, tilts, quadratic) fitted out: the
    /// detail, without a phase bowl.
    pub detail_nrmse: f64,
    /// The checks that fired (the run's warnings).
    pub fired: Vec<Check>,
    /// The bright-field frames' fit of measured on modelled intensity.
    pub bright_field_fit: Option<ContrastFit>,
    /// The bright/dark-field edge's height and entrance pupil.
    pub boundary: Option<BoundaryCheck>,
    /// The edge's height weighed against the dataset's, where they were apart.
    pub height_choice: Option<HeightChoice>,
    /// The frames' error after the last pass.
    pub final_error: Option<f64>,
}

/// Simulate `case` into `dir` and reconstruct it as a user would.
pub fn run_case(case: &Case, dir: &Path) -> Result<Scored> {
    let scene = Scene {
        noise: if case.eight_bit {
            Noise::EightBit
        } else {
            Noise::Realistic
        },
        size: SIZE,
        seed: case.seed,
        ..Scene::default()
    };
    let set = AcquisitionSet {
        dark_field_peak_dn: case.dim_dark_field.then_some(if case.eight_bit {
            25.0
        } else {
            300.0
        }),
        entrance_pupil_mm: (case.condition == Condition::NonTelecentric).then_some(60.0),
        display_gamma: (case.condition == Condition::UndeclaredGamma).then_some(2.2),
        sample: case.sample,
        ..AcquisitionSet::default()
    };
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("clearing {}", dir.display()))?;
    }
    simulation::write_acquisition(&scene, &set, dir)?;
    let manifest = dir.join("dataset.toml");
    let stated = DatasetOnDisk::open(dir)?.manifest.geometry();
    if stated != scene.truth {
        bail!(
            "{}: states {stated:?}, not the simulated {:?}",
            manifest.display(),
            scene.truth
        );
    }
    let text = std::fs::read_to_string(&manifest)?;
    let edited: String = text
        .lines()
        .filter(|l| {
            case.condition != Condition::UndeclaredGamma || !l.trim_start().starts_with("gamma")
        })
        .map(|l| match l.trim_start().strip_prefix("height_mm = ") {
            Some(_) if case.condition == Condition::WrongHeight => {
                format!("height_mm = {}\n", stated.height_mm + 8.0)
            }
            _ => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&manifest, edited)?;
    let job = Job {
        geometry: GeometryChoice::Nominal,
        ..Job::default()
    };
    let finished = job.run(dir, &|_| {})?;
    let report = &finished.reconstruction.report;
    let truth = report
        .versus_truth
        .as_ref()
        .context("the simulated set has no truth to score against")?;
    let (nrmse, detail) = (truth.complex_nrmse, truth.detail_nrmse);
    // Every set's dataset states its true placement, uncalibrated: the reminder to
    // calibrate is right on each and is not counted.
    let mut fired: Vec<Check> = checks(report)
        .into_iter()
        .map(|w| w.check)
        .filter(|c| *c != Check::NominalGeometry)
        .collect();
    fired.dedup();
    Ok(Scored {
        complex_nrmse: nrmse,
        detail_nrmse: detail,
        fired,
        bright_field_fit: report.bright_field_fit,
        boundary: report.height_from_boundary,
        height_choice: report.height_choice,
        final_error: report.error_per_pass.last().copied(),
    })
}

/// Run every case; rates per check.
pub fn measure(
    seeds: u64,
    fault_seeds: u64,
    work: &Path,
    mut progress: impl FnMut(usize, usize),
) -> Result<(Vec<Outcome>, BTreeMap<Check, Rates>)> {
    let cases = cases(seeds, fault_seeds);
    let mut outcomes: Vec<Outcome> = vec![];
    for (k, case) in cases.iter().enumerate() {
        let scored = run_case(case, &work.join("set")).with_context(|| format!("case {case:?}"))?;
        let clean = (case.condition != Condition::None)
            .then(|| {
                outcomes.iter().find(|o| {
                    o.case.condition == Condition::None
                        && o.case.sample == case.sample
                        && o.case.eight_bit == case.eight_bit
                        && o.case.dim_dark_field == case.dim_dark_field
                        && o.case.seed == case.seed
                })
            })
            .flatten();
        let effect = clean.map(|c| scored.complex_nrmse / c.scored.complex_nrmse - 1.0);
        let detail_effect = clean.map(|c| scored.detail_nrmse / c.scored.detail_nrmse - 1.0);
        outcomes.push(Outcome {
            case: *case,
            effect,
            detail_effect,
            scored,
        });
        progress(k + 1, cases.len());
    }
    let rates = rates(&outcomes);
    Ok((outcomes, rates))
}

/// Each check's false alarms (on good sets) and detections (on its condition's sets).
pub fn rates(outcomes: &[Outcome]) -> BTreeMap<Check, Rates> {
    let mut out: BTreeMap<Check, Rates> = BTreeMap::new();
    let good = outcomes
        .iter()
        .filter(|o| o.case.condition == Condition::None);
    // Every check that fired anywhere, plus those a condition is meant for.
    let mut every: Vec<Check> = outcomes
        .iter()
        .flat_map(|o| o.scored.fired.clone())
        .collect();
    every.extend(outcomes.iter().filter_map(|o| o.case.expected_check()));
    every.sort();
    every.dedup();
    for check in every {
        let r = out.entry(check).or_default();
        for o in good.clone() {
            r.false_alarms.1 += 1;
            r.false_alarms.0 += o.scored.fired.contains(&check) as usize;
        }
        for o in outcomes
            .iter()
            .filter(|o| o.case.expected_check() == Some(check))
        {
            let slot = if o.effect.unwrap_or(0.0) >= EFFECT {
                &mut r.detections
            } else {
                &mut r.small_effect_detections
            };
            slot.1 += 1;
            slot.0 += o.scored.fired.contains(&check) as usize;
        }
    }
    out
}

/// `fpm bench warnings`.
pub fn run(seeds: u64, fault_seeds: u64, json: bool) -> Result<()> {
    let work = tempfile::tempdir()?;
    let bar = if json {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(cases(seeds, fault_seeds).len() as u64)
    };
    let (outcomes, rates) = measure(seeds, fault_seeds, work.path(), |done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();
    if json {
        let rates: BTreeMap<&str, &Rates> = rates.iter().map(|(c, r)| (c.name(), r)).collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "size": SIZE,
                "effect_threshold": EFFECT,
                "rates": rates,
                "outcomes": outcomes,
            }))?
        );
        return Ok(());
    }
    let good = outcomes
        .iter()
        .filter(|o| o.case.condition == Condition::None)
        .count();
    println!(
        "warnings on {good} good simulated sets ({SIZE}², 441 LEDs; 3 samples × 12/8-bit × auto/dim dark field × {seeds} seeds) and {} with a fault:",
        outcomes.len() - good
    );
    println!(
        "  {:<24} {:>13} {:>24} {:>22}",
        "check", "false alarms", "detections (effect ≥10 %)", "fired (effect <10 %)"
    );
    let pct = |(k, n): (usize, usize)| {
        if n == 0 {
            "—".to_string()
        } else {
            format!("{k}/{n} ({:.0} %)", 100.0 * k as f64 / n as f64)
        }
    };
    for (check, r) in &rates {
        println!(
            "  {:<24} {:>13} {:>24} {:>22}",
            check.name(),
            pct(r.false_alarms),
            pct(r.detections),
            pct(r.small_effect_detections)
        );
    }
    println!("faults (complex NRMSE over the clean set's − 1; in brackets the same with the low-order phase fitted out; and what fired):");
    for o in outcomes
        .iter()
        .filter(|o| o.case.condition != Condition::None)
    {
        println!(
            "  {:<16} {:<10} {:>6} seed {}  effect {:>+6.1} % ({:>+6.1} %)  {}  {}",
            kebab(o.case.condition),
            kebab(o.case.sample),
            if o.case.eight_bit { "8-bit" } else { "12-bit" },
            o.case.seed,
            100.0 * o.effect.unwrap_or(f64::NAN),
            100.0 * o.detail_effect.unwrap_or(f64::NAN),
            o.evidence(),
            o.fired_names()
        );
    }
    for o in outcomes
        .iter()
        .filter(|o| o.case.condition == Condition::None && !o.scored.fired.is_empty())
    {
        println!(
            "  false alarm: {:<10} {:>6} {} dark field, seed {}: {}  {}",
            kebab(o.case.sample),
            if o.case.eight_bit { "8-bit" } else { "12-bit" },
            if o.case.dim_dark_field { "dim" } else { "auto" },
            o.case.seed,
            o.evidence(),
            o.fired_names()
        );
    }
    Ok(())
}
