//! Many datasets (the fields of view of a slide), each reconstructed by the same
//! [`Job`] into ROOT/<its directory's name>, resumably: fields already done are
//! skipped, and a field is moved into place only when its outputs are complete (it is
//! written to a hidden partial directory first), so an interrupted batch resumes where
//! it stopped. `fpm reconstruct --out-root` runs it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use serde::Serialize;

use super::{Finished, Job, JobEvent};

/// The datasets `args` name: paths as given, patterns (with `*`, `?` or `[`)
/// expanded to the matching directories that hold a dataset.toml, in order.
pub fn expand(args: &[PathBuf]) -> Result<Vec<PathBuf>> {
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
#[derive(Debug, Clone, Serialize)]
pub struct Field {
    /// The dataset.
    pub dataset: PathBuf,
    /// Where its reconstruction is.
    pub out: PathBuf,
    /// "done", "skipped" (already done) or "failed".
    pub status: &'static str,
    /// Why it failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// What a user must know before trusting its images.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
    /// Time it took, s.
    pub seconds: f64,
}

/// What a batch did.
#[derive(Debug, Clone, Serialize)]
pub struct BatchSummary {
    /// The output root.
    pub out_root: PathBuf,
    /// Fields reconstructed now.
    pub done: usize,
    /// Fields already done.
    pub skipped: usize,
    /// Fields that failed.
    pub failed: usize,
    /// Fields reconstructed per minute of the batch.
    pub fields_per_minute: f64,
    /// Every field, in order.
    pub fields: Vec<Field>,
}

/// How a batch writes one finished field into a directory, returning the warnings on
/// its images (the CLI writes the images, previews and page: `fpm_report`).
pub type WriteField<'w> = dyn Fn(&Finished, &Path) -> Result<Vec<String>> + Sync + 'w;

/// A batch; see the module's doc.
pub struct Batch<'w> {
    /// How each dataset is reconstructed.
    pub job: Job,
    /// The datasets ([`expand`] turns patterns into them).
    pub datasets: Vec<PathBuf>,
    /// The output root.
    pub root: PathBuf,
    /// Reconstruct fields already done again.
    pub redo: bool,
    /// How each field's outputs are written.
    pub write: &'w WriteField<'w>,
}

/// Whether `dir` holds a finished reconstruction.
fn finished(dir: &Path) -> bool {
    dir.join("report.json").is_file()
}

impl Batch<'_> {
    /// Run it: `on_field(k, n, field)` after each field, `on_event` inside each job.
    /// A failed field does not stop the batch; the summary counts it.
    pub fn run(
        &self,
        mut on_field: impl FnMut(usize, usize, &Field),
        on_event: &(dyn Fn(JobEvent) + Sync),
    ) -> Result<BatchSummary> {
        self.job.validate()?;
        let names = names(&self.datasets)?;
        std::fs::create_dir_all(&self.root)
            .with_context(|| format!("creating {}", self.root.display()))?;
        let start = Instant::now();
        let mut fields = Vec::with_capacity(self.datasets.len());
        for (k, (dataset, name)) in self.datasets.iter().zip(&names).enumerate() {
            let out = self.root.join(name);
            let began = Instant::now();
            let (status, error, warnings) = if finished(&out) && !self.redo {
                ("skipped", None, vec![])
            } else {
                match self.one(dataset, &out, name, on_event) {
                    Ok(warnings) => ("done", None, warnings),
                    Err(e) => ("failed", Some(format!("{e:#}")), vec![]),
                }
            };
            let field = Field {
                dataset: dataset.clone(),
                out,
                status,
                error,
                warnings,
                seconds: began.elapsed().as_secs_f64(),
            };
            on_field(k, self.datasets.len(), &field);
            fields.push(field);
        }
        let count = |s: &str| fields.iter().filter(|f| f.status == s).count();
        let done = count("done");
        Ok(BatchSummary {
            out_root: self.root.clone(),
            done,
            skipped: count("skipped"),
            failed: count("failed"),
            fields_per_minute: done as f64 / (start.elapsed().as_secs_f64() / 60.0).max(1e-9),
            fields,
        })
    }

    /// Reconstruct `dataset` into `out` through a partial directory beside it; the
    /// warnings on its images.
    fn one(
        &self,
        dataset: &Path,
        out: &Path,
        name: &str,
        on_event: &(dyn Fn(JobEvent) + Sync),
    ) -> Result<Vec<String>> {
        let partial = self.root.join(format!(".{name}.partial"));
        if partial.exists() {
            std::fs::remove_dir_all(&partial)
                .with_context(|| format!("clearing {}", partial.display()))?;
        }
        let written = self
            .job
            .run(dataset, on_event)
            .and_then(|f| (self.write)(&f, &partial));
        let written = match written {
            Ok(w) => w,
            Err(e) => {
                std::fs::remove_dir_all(&partial).ok();
                return Err(e);
            }
        };
        if out.exists() {
            std::fs::remove_dir_all(out).with_context(|| format!("replacing {}", out.display()))?;
        }
        std::fs::rename(&partial, out)
            .with_context(|| format!("moving {} to {}", partial.display(), out.display()))?;
        Ok(written)
    }
}
