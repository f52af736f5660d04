//! The HTML report of each command (`calibration.html`, `report.html`), assembled from
//! its JSON result and its charts. A report is an optional extra: the callers log a
//! failure to write one as a warning, never fail the run for it.

pub mod calibration;
pub mod dpc;
pub mod reconstruction;

use std::path::Path;

use crate::charts::{Chart, Figure};
use crate::html::Page;

/// Render `chart`, write it as `dir/stem.png` and `dir/stem.svg`, and embed it in
/// `page` with links to both files (`rel` is `dir` relative to the page). A chart that
/// cannot be drawn or written is said on the page and in the log.
pub fn embed_chart(
    page: &mut Page,
    chart: &impl Chart,
    (dir, rel): (&Path, &str),
    stem: &str,
    caption: &str,
) {
    match Figure::render(chart) {
        Ok(figure) => {
            let files = match figure.write(dir, stem) {
                Ok(()) => vec![format!("{rel}/{stem}.png"), format!("{rel}/{stem}.svg")],
                Err(e) => {
                    tracing::warn!("chart {stem} not written: {e:#}");
                    vec![]
                }
            };
            let links: Vec<&str> = files.iter().map(String::as_str).collect();
            page.figure(&figure.png, caption, caption, &links);
        }
        Err(e) => {
            tracing::warn!("chart {stem} not drawn: {e:#}");
            page.paragraph(&format!("({caption}: the chart could not be drawn: {e:#})"));
        }
    }
}

/// `value ± sigma` with `digits` decimals and a unit.
pub fn pm(value: f64, sigma: f64, digits: usize, unit: &str) -> String {
    format!("{value:+.digits$} ± {sigma:.digits$} {unit}")
}
