//! Progress bars on stderr (hidden when it is not a terminal).

use indicatif::{ProgressBar, ProgressStyle};

/// A bar counting frames, `what` in front: "acquiring [====    ] 120/441 frames (…)".
pub fn frames(what: &str) -> ProgressBar {
    let template =
        format!("{what} [{{bar:40}}] {{pos}}/{{len}} frames ({{per_sec}}, {{eta}} left) {{msg}}");
    ProgressBar::new(0).with_style(
        ProgressStyle::with_template(&template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    )
}

/// A bar counting `unit`, `what` in front ("reconstructing DIR [===  ] 40/100 frame updates").
pub fn counter(what: &str, unit: &str) -> ProgressBar {
    let template = format!("{what} [{{bar:40}}] {{pos}}/{{len}} {unit} ({{eta}} left)");
    ProgressBar::new(0).with_style(
        ProgressStyle::with_template(&template).unwrap_or_else(|_| ProgressStyle::default_bar()),
    )
}

/// Set a bar to `done` of `total`.
pub fn advance(bar: &ProgressBar, done: usize, total: usize) {
    bar.set_length(total as u64);
    bar.set_position(done as u64);
}
