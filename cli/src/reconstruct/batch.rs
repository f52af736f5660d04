//! `fpm reconstruct DIR... --out-root ROOT`: many datasets (the fields of view of a
//! slide), each into ROOT/<its name>, resumable ([`fpm_host::reconstruction::batch`]).

use std::path::Path;

use anyhow::{bail, Result};
use fpm_host::reconstruction::batch::{expand, Batch, Field};
use fpm_host::reconstruction::Finished;

use super::ReconstructArgs;

/// Run the batch, one line per field (or the summary as JSON).
pub fn run(a: &ReconstructArgs, root: &Path) -> Result<()> {
    let (output, reproduce) = (a.output(), fpm_report::html::command_line());
    let write = |finished: &Finished, dir: &Path| {
        fpm_report::reconstruction::write(finished, dir, output, &reproduce).map(|w| w.warnings)
    };
    let batch = Batch {
        job: a.job(),
        datasets: expand(&a.dirs)?,
        root: root.to_path_buf(),
        redo: a.redo,
        write: &write,
    };
    let summary = batch.run(
        |k, n, field| {
            for w in &field.warnings {
                eprintln!("warning: {}: {w}", field.dataset.display());
            }
            if !a.json {
                print_field(k, n, field);
            }
        },
        &|_| {},
    )?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} reconstructed, {} already done, {} failed ({:.1} fields per minute) under {}",
            summary.done,
            summary.skipped,
            summary.failed,
            summary.fields_per_minute,
            root.display()
        );
    }
    if summary.failed > 0 {
        bail!(
            "{} of {} datasets failed (see above)",
            summary.failed,
            summary.fields.len()
        );
    }
    Ok(())
}

fn print_field(k: usize, n: usize, field: &Field) {
    let what = match (field.status, &field.error) {
        ("skipped", _) => "already done, skipped".to_string(),
        (_, Some(e)) => format!("FAILED: {e}"),
        _ => format!("done in {:.1} s", field.seconds),
    };
    println!(
        "[{}/{}] {} → {}: {what}",
        k + 1,
        n,
        field.dataset.display(),
        field.out.display()
    );
}
