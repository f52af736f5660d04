//! `fpm bench reconstruct`: what a user waits for. The whole `fpm reconstruct` process
//! (start, loading, the automatic checks, EPRY, the outputs and the report page) on a
//! 441-frame set, timed from outside; beside it EPRY alone and each automatic step, as
//! the run's own report.json times them (issue 63: the checks' share, and whether
//! judgement costs more than the reconstruction it judges); and, when a Python with
//! fpm-rs is at hand, fpm-rs's EPRY on the same frames (`tools/peers/compare.py`), all
//! in the same run, as ratios.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_host::simulation::{self, AcquisitionSet, Noise, Scene};
use serde::Serialize;

/// The automatic steps' share of the whole run that issue 63 allows.
const AUTOMATIC_SHARE_GOAL: f64 = 0.25;
/// How much faster than fpm-rs 0.1 the whole process should be (issue 63).
const FPM_RS_GOAL: f64 = 6.0;

/// `fpm bench reconstruct`'s options.
#[derive(Debug, Clone)]
pub struct ReconstructOptions {
    /// A dataset to reconstruct; None: a 441-frame set simulated for the run.
    pub dataset: Option<PathBuf>,
    /// Sensor side of the simulated set, pixels.
    pub size: usize,
    /// EPRY passes.
    pub passes: usize,
    /// HR pixels per camera pixel (None: `fpm reconstruct`'s default).
    pub upsample: Option<usize>,
    /// Runs of `fpm reconstruct`; the median is reported.
    pub rounds: usize,
    /// A Python with fpm-rs (and numpy, tifffile) installed, to run it on the same
    /// frames; None: `$FPM_PEERS_VENV/bin/python` (or compare.sh's default venv) when
    /// it exists, else fpm-rs is left out.
    pub peers_python: Option<PathBuf>,
    /// Print JSON.
    pub json: bool,
}

/// One step of a run, as report.json times it.
#[derive(Debug, Clone, Serialize)]
struct StepTime {
    step: String,
    automatic: bool,
    /// Median over the rounds, s.
    seconds: f64,
    /// Of the whole process.
    share: f64,
}

/// fpm-rs on the same frames.
#[derive(Debug, Clone, Serialize)]
struct FpmRs {
    version: String,
    /// Its EPRY alone (loading and model set-up not counted, which favours it), s.
    epry_s: f64,
    /// Its EPRY over our whole process (goal ≥ 6).
    whole_ratio: f64,
    /// Its EPRY over our EPRY.
    epry_ratio: f64,
}

#[derive(Debug, Serialize)]
struct ReconstructResult {
    dataset: String,
    frames: usize,
    frame_size: [u64; 2],
    passes: usize,
    upsample: u64,
    tiles: usize,
    threads: u64,
    rounds: usize,
    /// The whole process, wall clock, median and spread over the rounds, s.
    whole_s: f64,
    whole_min_s: f64,
    whole_max_s: f64,
    /// EPRY alone, as the run timed it, median, s.
    epry_s: f64,
    /// The automatic steps together, median, s, and their share of the whole.
    automatic_s: f64,
    automatic_share: f64,
    automatic_share_goal: f64,
    steps: Vec<StepTime>,
    /// None: no Python with fpm-rs was found (the reason is in `fpm_rs_skipped`).
    fpm_rs: Option<FpmRs>,
    #[serde(skip_serializing_if = "Option::is_none")]
    fpm_rs_skipped: Option<String>,
    fpm_rs_goal: f64,
    /// Complex NRMSE against the hidden sample, when the set has one (the last round).
    complex_nrmse: Option<f64>,
}

/// One run of `fpm reconstruct`: wall time and its report.
struct Round {
    whole_s: f64,
    report: serde_json::Value,
}

pub fn run(a: ReconstructOptions) -> Result<()> {
    if a.rounds == 0 || a.passes == 0 {
        bail!("--rounds and --passes must be 1 or more");
    }
    let scratch = tempfile::Builder::new()
        .prefix("fpm-bench-reconstruct-")
        .tempdir()
        .context("a scratch directory")?;
    let dataset = match &a.dataset {
        Some(d) => d.clone(),
        None => {
            let dir = scratch.path().join("dataset");
            if !a.json {
                eprintln!("simulating 441 frames of {}²…", a.size);
            }
            let scene = Scene {
                truth: Scene::placed(0.0, 0.0, 0.0, 92.0),
                noise: Noise::Realistic,
                size: a.size,
                seed: 1,
                stray_light: 0.0,
            };
            simulation::write_acquisition(&scene, &AcquisitionSet::default(), &dir)?;
            dir
        }
    };
    let exe = std::env::current_exe().context("the fpm executable")?;
    let bar = progress(a.rounds, a.json);
    let mut rounds = vec![];
    for k in 0..a.rounds {
        rounds.push(reconstruct_once(
            &exe,
            &dataset,
            &scratch.path().join(format!("r{k}")),
            &a,
        )?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let (peers, skipped) = match peers_python(&a) {
        Ok(python) => {
            if !a.json {
                eprintln!("fpm-rs on the same frames ({})…", python.display());
            }
            match fpm_rs_epry(&python, &exe, &dataset, &a, scratch.path()) {
                Ok(p) => (Some(p), None),
                Err(e) => (None, Some(format!("{e:#}"))),
            }
        }
        Err(why) => (None, Some(why)),
    };
    let result = summarise(&dataset, &a, &rounds, peers, skipped)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&result)?);
    } else {
        print_table(&result);
    }
    Ok(())
}

fn progress(n: usize, hidden: bool) -> indicatif::ProgressBar {
    if hidden {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(n as u64);
    bar.set_message("fpm reconstruct");
    bar
}

/// `fpm reconstruct DATASET --json` as a user runs it, timed from outside.
fn reconstruct_once(
    exe: &Path,
    dataset: &Path,
    out: &Path,
    a: &ReconstructOptions,
) -> Result<Round> {
    let mut cmd = Command::new(exe);
    cmd.arg("reconstruct")
        .arg(dataset)
        .arg("--out")
        .arg(out)
        .args(["--passes", &a.passes.to_string(), "--json"]);
    if let Some(u) = a.upsample {
        cmd.args(["--upsample", &u.to_string()]);
    }
    let began = Instant::now();
    let run = cmd.output().context("running fpm reconstruct")?;
    let whole_s = began.elapsed().as_secs_f64();
    if !run.status.success() {
        bail!(
            "fpm reconstruct {} failed: {}",
            dataset.display(),
            String::from_utf8_lossy(&run.stderr)
        );
    }
    let report = serde_json::from_slice(&run.stdout).context("fpm reconstruct --json's report")?;
    Ok(Round { whole_s, report })
}

/// The Python to run fpm-rs with, or why there is none.
fn peers_python(a: &ReconstructOptions) -> std::result::Result<PathBuf, String> {
    if let Some(p) = &a.peers_python {
        return Ok(p.clone());
    }
    let venv = std::env::var_os("FPM_PEERS_VENV")
        .map(PathBuf::from)
        .or_else(|| {
            let cache = std::env::var_os("XDG_CACHE_HOME")
                .map(PathBuf::from)
                .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
            Some(cache.join("fpm-peers/venv"))
        });
    match venv.map(|v| v.join("bin/python")) {
        Some(p) if p.exists() => Ok(p),
        _ => Err("no Python with fpm-rs: run tools/peers/compare.sh once (it makes the venv), or give --peers-python".into()),
    }
}

/// fpm-rs's EPRY on the same frames, through tools/peers/compare.py (which feeds it
/// the same wave vectors, order and upsampling as ours).
fn fpm_rs_epry(
    python: &Path,
    exe: &Path,
    dataset: &Path,
    a: &ReconstructOptions,
    scratch: &Path,
) -> Result<(String, f64)> {
    let script = compare_script()?;
    let out = scratch.join("peers.json");
    let upsample = a
        .upsample
        .unwrap_or(fpm_physics::reconstruct::defaults::UPSAMPLE);
    let run = Command::new(python)
        .arg(&script)
        .arg(dataset)
        .args(["--passes", &a.passes.to_string()])
        .args(["--upsample", &upsample.to_string()])
        .args(["--peers", "fpm-rs", "--without-ours", "--fpm"])
        .arg(exe)
        .arg("--json")
        .arg(&out)
        .output()
        .with_context(|| format!("running {}", script.display()))?;
    if !run.status.success() {
        bail!(
            "{} failed: {}",
            script.display(),
            String::from_utf8_lossy(&run.stderr)
        );
    }
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&out).context("compare.py's JSON")?)?;
    let row = doc["rows"]
        .as_array()
        .into_iter()
        .flatten()
        .find(|r| r["tool"] == "fpm-rs")
        .context("compare.py gave no fpm-rs row")?;
    if let Some(e) = row["error"].as_str() {
        bail!("fpm-rs failed: {e}");
    }
    let per_pass = row["seconds_per_pass"]
        .as_f64()
        .context("fpm-rs row without seconds_per_pass")?;
    let version = row["version"].as_str().unwrap_or("?").to_string();
    Ok((version, per_pass * a.passes as f64))
}

/// tools/peers/compare.py of this checkout (the bench runs from the repository).
fn compare_script() -> Result<PathBuf> {
    let here = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../peers/compare.py");
    match here.exists() {
        true => Ok(here),
        false => bail!(
            "{} is not there: fpm-rs is compared from the repository's checkout",
            here.display()
        ),
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    match v.len() {
        0 => f64::NAN,
        n => v[fpm_physics::stats::rank(n, 0.5)],
    }
}

fn summarise(
    dataset: &Path,
    a: &ReconstructOptions,
    rounds: &[Round],
    peers: Option<(String, f64)>,
    fpm_rs_skipped: Option<String>,
) -> Result<ReconstructResult> {
    let last = &rounds.last().context("no round")?.report;
    let whole: Vec<f64> = rounds.iter().map(|r| r.whole_s).collect();
    let whole_s = median(whole.clone());
    // Steps by name, in the order the run took them.
    let mut steps: Vec<StepTime> = vec![];
    for s in last["steps_ms"].as_array().into_iter().flatten() {
        let name = s["step"].as_str().unwrap_or("?").to_string();
        let seconds = median(
            rounds
                .iter()
                .filter_map(|r| {
                    r.report["steps_ms"]
                        .as_array()?
                        .iter()
                        .find(|t| t["step"] == name.as_str())?["ms"]
                        .as_f64()
                })
                .map(|ms| ms / 1e3)
                .collect(),
        );
        steps.push(StepTime {
            automatic: s["automatic"].as_bool().unwrap_or(false),
            share: seconds / whole_s,
            step: name,
            seconds,
        });
    }
    let epry_s = steps
        .iter()
        .find(|s| s.step == "EPRY")
        .map(|s| s.seconds)
        .context("report.json has no EPRY step")?;
    let automatic_s: f64 = steps
        .iter()
        .filter(|s| s.automatic)
        .map(|s| s.seconds)
        .sum();
    let fpm_rs = peers.map(|(version, epry)| FpmRs {
        version,
        epry_s: epry,
        whole_ratio: epry / whole_s,
        epry_ratio: epry / epry_s,
    });
    let size = |k: usize| last["frame_size"][k].as_u64().unwrap_or(0);
    Ok(ReconstructResult {
        dataset: dataset.display().to_string(),
        frames: last["frames"].as_u64().unwrap_or(0) as usize,
        frame_size: [size(0), size(1)],
        passes: a.passes,
        upsample: last["upsample"].as_u64().unwrap_or(0),
        tiles: last["tiles"].as_array().map_or(0, Vec::len),
        threads: last["threads"].as_u64().unwrap_or(0),
        rounds: rounds.len(),
        whole_s,
        whole_min_s: whole.iter().copied().fold(f64::INFINITY, f64::min),
        whole_max_s: whole.iter().copied().fold(0.0, f64::max),
        epry_s,
        automatic_s,
        automatic_share: automatic_s / whole_s,
        automatic_share_goal: AUTOMATIC_SHARE_GOAL,
        steps,
        fpm_rs,
        fpm_rs_skipped,
        fpm_rs_goal: FPM_RS_GOAL,
        complex_nrmse: last["versus_truth"]["complex_nrmse"].as_f64(),
    })
}

fn print_table(r: &ReconstructResult) {
    println!(
        "{} frames of {}×{}, {} pass(es), U = {}, {} tile(s), {} thread(s); {} round(s)",
        r.frames,
        r.frame_size[0],
        r.frame_size[1],
        r.passes,
        r.upsample,
        r.tiles,
        r.threads,
        r.rounds
    );
    println!(
        "  {:<36} {:>7.2} s  (rounds {:.2}–{:.2} s)",
        "whole process", r.whole_s, r.whole_min_s, r.whole_max_s
    );
    for s in &r.steps {
        println!(
            "  {:<36} {:>7.2} s  {:>5.1} %{}",
            s.step,
            s.seconds,
            s.share * 1e2,
            if s.automatic { "  (automatic)" } else { "" }
        );
    }
    let verdict = if r.automatic_share <= r.automatic_share_goal {
        "within"
    } else {
        "over"
    };
    println!(
        "  {:<36} {:>7.2} s  {:>5.1} % of the whole: {verdict} the {:.0} % goal",
        "automatic steps",
        r.automatic_s,
        r.automatic_share * 1e2,
        r.automatic_share_goal * 1e2
    );
    match (&r.fpm_rs, &r.fpm_rs_skipped) {
        (Some(p), _) => println!(
            "  {:<36} {:>7.2} s: {:.1}× our whole process (goal {:.0}×), {:.1}× our EPRY",
            format!("fpm-rs {} EPRY", p.version),
            p.epry_s,
            p.whole_ratio,
            r.fpm_rs_goal,
            p.epry_ratio
        ),
        (None, Some(why)) => println!("  fpm-rs: not measured ({why})"),
        (None, None) => {}
    }
    if let Some(e) = r.complex_nrmse {
        println!("  complex NRMSE against the hidden sample: {e:.3}");
    }
}
