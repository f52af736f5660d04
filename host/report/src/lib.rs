//! # fpm-report
//!
//! What fpm shows people: HTML pages ([`pages`], on [`html`]), charts ([`charts`],
//! plotters with the embedded DejaVu Sans), PNG previews with scale and colour bars
//! ([`preview`]), the truth beside reconstructions ([`comparison`]) and a finished
//! reconstruction written with its report ([`reconstruction`]). Computing crates
//! never import it: a report is an extra, and a failure to write one never fails the
//! job that made the numbers.

pub mod charts;
pub mod color;
pub mod colour_bar;
pub mod comparison;
pub mod html;
pub mod pages;
pub mod preview;
pub mod reconstruction;
pub mod scale_bar;
pub mod slide;
pub mod text;
