//! `fpm reconstruct DIR... --out-root ROOT`: many datasets (the fields of view of a
//! slide), each into ROOT/<its name>, resumable: done fields are skipped, and a field
//! is moved into place only when its outputs are complete.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use serde::Serialize;

use super::{one, ReconstructArgs};

/// The datasets `args` name: paths as given, patterns (with `*`, `?` or `[`)
/// expanded to the matching directories that hold a dataset.toml, in order.
fn datasets(args: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = vec![];
    for arg in args {
        let text = arg.to_string_lossy();
        if !text.contains(['*', '?', '[']) {
            out.push(arg.clone());
            continue;
        }
        let mut matched: Vec<PathBuf> = glob::glob(&text)
            .with_context(|| format!("pattern '{text}'"))?
            .filter_map(|entry| entry.ok())
            .filter(|p| p.join("dataset.toml").is_file())
            .collect();
        if matched.is_empty() {
            bail!("pattern '{text}' matches no dataset directory (none with a dataset.toml)");
        }
        matched.sort();
        out.append(&mut matched);
    }
    Ok(out)
}

/// Each dataset's output name (its directory's own name), refused when two share one.
fn names(datasets: &[PathBuf]) -> Result<Vec<String>> {
    let names: Vec<String> = datasets
        .iter()
        .map(|d| {
            std::fs::canonicalize(d)
                .unwrap_or_else(|_| d.clone())
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .with_context(|| format!("{}: a dataset directory has a name", d.display()))
        })
        .collect::<Result<_>>()?;
    for (k, name) in names.iter().enumerate() {
        if let Some(j) = names[..k].iter().position(|n| n == name) {
            bail!(
                "{} and {} would both be written to '{name}' under the output root: rename one",
                datasets[j].display(),
                datasets[k].display()
            );
        }
    }
    Ok(names)
}

/// What became of one dataset.
#[derive(Debug, Serialize)]
struct Field {
    dataset: PathBuf,
    out: PathBuf,
    /// "done", "skipped" (already done) or "failed".
    status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<String>,
    seconds: f64,
}

/// Whether `dir` holds a finished reconstruction.
fn finished(dir: &Path) -> bool {
    dir.join("report.json").is_file()
}

/// Reconstruct `dataset` into `out` through a partial directory beside it.
fn reconstruct_into(a: &ReconstructArgs, dataset: &Path, out: &Path, name: &str) -> Result<()> {
    let root = out.parent().unwrap_or(Path::new("."));
    let partial = root.join(format!(".{name}.partial"));
    if partial.exists() {
        std::fs::remove_dir_all(&partial)
            .with_context(|| format!("clearing {}", partial.display()))?;
    }
    let result = one(a, dataset, &partial, false);
    if result.is_err() {
        std::fs::remove_dir_all(&partial).ok();
        return result;
    }
    if out.exists() {
        std::fs::remove_dir_all(out).with_context(|| format!("replacing {}", out.display()))?;
    }
    std::fs::rename(&partial, out)
        .with_context(|| format!("moving {} to {}", partial.display(), out.display()))
}

/// Run the batch.
pub fn run(a: &ReconstructArgs, root: &Path) -> Result<()> {
    let datasets = datasets(&a.dirs)?;
    let names = names(&datasets)?;
    std::fs::create_dir_all(root).with_context(|| format!("creating {}", root.display()))?;
    let start = Instant::now();
    let mut fields = Vec::with_capacity(datasets.len());
    for (k, (dataset, name)) in datasets.iter().zip(&names).enumerate() {
        let out = root.join(name);
        let began = Instant::now();
        let (status, error) = if finished(&out) && !a.redo {
            ("skipped", None)
        } else {
            match reconstruct_into(a, dataset, &out, name) {
                Ok(()) => ("done", None),
                Err(e) => ("failed", Some(format!("{e:#}"))),
            }
        };
        let field = Field {
            dataset: dataset.clone(),
            out,
            status,
            error,
            seconds: began.elapsed().as_secs_f64(),
        };
        if !a.json {
            let what = match (field.status, &field.error) {
                ("skipped", _) => "already done, skipped".to_string(),
                (_, Some(e)) => format!("FAILED: {e}"),
                _ => format!("done in {:.1} s", field.seconds),
            };
            println!(
                "[{}/{}] {} → {}: {what}",
                k + 1,
                datasets.len(),
                field.dataset.display(),
                field.out.display()
            );
        }
        fields.push(field);
    }
    let count = |s: &str| fields.iter().filter(|f| f.status == s).count();
    let (done, skipped, failed) = (count("done"), count("skipped"), count("failed"));
    let minutes = start.elapsed().as_secs_f64() / 60.0;
    if a.json {
        let summary = serde_json::json!({
            "out_root": root,
            "done": done,
            "skipped": skipped,
            "failed": failed,
            "fields_per_minute": (done as f64) / minutes.max(1e-9),
            "fields": fields,
        });
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{done} reconstructed, {skipped} already done, {failed} failed ({:.1} fields per minute) under {}",
            done as f64 / minutes.max(1e-9),
            root.display()
        );
    }
    if failed > 0 {
        bail!("{failed} of {} datasets failed (see above)", fields.len());
    }
    Ok(())
}
