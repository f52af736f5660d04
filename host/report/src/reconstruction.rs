//! A finished reconstruction written for people: the images (`fpm_host`), their
//! previews and the HTML report.

use std::path::{Path, PathBuf};

use anyhow::Result;
use fpm_host::reconstruction::{write_outputs_with, Finished, OutputOptions};

/// What [`write`] wrote.
pub struct Written {
    /// `report.html`, or why it could not be written (an extra: never fails the job).
    pub page: Result<PathBuf>,
    /// What a user must know before trusting the images.
    pub warnings: Vec<String>,
}

/// Write the images, the pupil, the previews, charts and report.json into `out`, and
/// the HTML report (`reproduce`: the command that makes it again).
pub fn write(
    finished: &Finished,
    out: &Path,
    output: OutputOptions,
    reproduce: &str,
) -> Result<Written> {
    let r = &finished.reconstruction;
    write_outputs_with(r, out, output)?;
    crate::preview::reconstruction(r, out)?;
    let context = crate::pages::reconstruction::Context {
        system: &finished.system,
        nominal: &finished.nominal,
        reproduce,
    };
    let page =
        crate::pages::reconstruction::write(r, out, &context).map(|()| out.join("report.html"));
    if let Err(e) = &page {
        tracing::warn!("no HTML report: {e:#}");
    }
    Ok(Written {
        page,
        warnings: fpm_host::reconstruction::warnings(&r.report),
    })
}
