//! A colour acquisition: the whole acquisition of a [`Plan`] once per LED colour (each
//! LED lit in that colour alone, each colour its own sequence, into `out/<colour>/`),
//! joined as a colour dataset (docs/dataset.md §5.9); each colour calibrated when the
//! plan calibrates (its dies sit apart from the others'), the colour calibration
//! written; and, when the plan reconstructs, the colour image. What `fpm acquire
//! --colors` and the service's acquire job with `colors` run.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use fpm_host::calibration::{CalibrationFile, GeometrySource};
use fpm_host::color::{ColorCalibration, ColorDataset, ColorGeometry, ColorManifest, ColorReport};
use fpm_protocol::Rgb;
use serde::Serialize;

use crate::pipeline::{self, AcquireSummary, Control, Plan, Watcher};
use crate::{Controller, FocusStage};

/// One colour to acquire.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorChannel {
    /// `red`, `green` or `blue`.
    pub name: String,
    /// What the LEDs are set to.
    pub rgb: Rgb,
    /// Its wavelength, µm.
    pub wavelength_um: f64,
}

/// The colours to acquire and the one the sample was focused in.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorPlan {
    /// In the order acquired.
    pub channels: Vec<ColorChannel>,
    /// The colour the sample was focused in (the stage's zero): the others' focal
    /// shifts are measured from it and their images registered to it.
    pub focus: String,
}

impl ColorPlan {
    /// `items` (`red`, `green`, `blue`, each optionally `NAME:UM`) focused in `focus`:
    /// the WS2812B's wavelengths (`fpm_physics::color::ws2812b`) unless given. Errors
    /// name the item (as `what`'s) that is wrong.
    pub fn parse(items: &[String], focus: &str, what: &str) -> Result<Self> {
        let channels: Vec<ColorChannel> = fpm_physics::color::parse_channels(items, what)?
            .into_iter()
            .map(|c| ColorChannel {
                rgb: match c.name.as_str() {
                    "red" => Rgb::new(255, 0, 0),
                    "green" => Rgb::new(0, 255, 0),
                    _ => Rgb::new(0, 0, 255),
                },
                wavelength_um: c.wavelength_um,
                name: c.name,
            })
            .collect();
        let focus = fpm_physics::color::ws2812b_channel(focus)
            .map(|c| c.name)
            .filter(|f| channels.iter().any(|c| &c.name == f))
            .with_context(|| {
                format!(
                    "focus colour {focus}: not one of the colours ({}); name the colour the sample was focused in",
                    channels.iter().map(|c| c.name.as_str()).collect::<Vec<_>>().join(", ")
                )
            })?;
        Ok(Self { channels, focus })
    }
}

/// What a colour acquisition did.
#[derive(Debug, Clone, Serialize)]
pub struct ColorAcquisition {
    /// Each colour's acquisition, in the order acquired.
    pub channels: Vec<ColorChannelSummary>,
    /// The colour the sample was focused in.
    pub focus: String,
    /// Acquiring every colour took this long, s.
    pub seconds: f64,
    /// The colour calibration, when each colour was calibrated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<PathBuf>,
    /// The colour image's report, when it was reconstructed (`out/reconstruction/`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reconstruction: Option<ColorReport>,
}

/// One colour of a [`ColorAcquisition`].
#[derive(Debug, Clone, Serialize)]
pub struct ColorChannelSummary {
    /// Its name.
    pub name: String,
    /// Its wavelength, µm.
    pub wavelength_um: f64,
    /// Its acquisition.
    pub summary: AcquireSummary,
}

/// Acquire `plan` once per colour of `colors` (see the module's doc). `watcher_for`
/// gives each colour's watcher; `control` cancels the whole (a cancelled colour ends
/// the run). `reproduce` goes on the colour image's page.
pub fn acquire<W: Watcher>(
    dev: &Controller,
    stage: &mut dyn FocusStage,
    plan: &Plan,
    colors: &ColorPlan,
    mut watcher_for: impl FnMut(&str) -> W,
    control: &Control,
    reproduce: &str,
) -> Result<ColorAcquisition> {
    if !plan.multiplex.is_one() {
        bail!("multiplex with colors: a colour acquisition lights one LED per frame");
    }
    if plan.leds.is_some() {
        bail!("leds with colors: a colour acquisition lights every LED in every colour");
    }
    let start = Instant::now();
    let mut channels = vec![];
    for c in &colors.channels {
        tracing::info!("acquiring {} ({:.1} nm)", c.name, c.wavelength_um * 1e3);
        let mut one = plan.clone();
        one.color = c.rgb;
        one.system.wavelength_um = c.wavelength_um;
        one.out = plan.out.join(&c.name);
        one.reconstruct = false;
        // The board keeps one geometry: the focus colour's (the reference's), not
        // whichever colour was calibrated last.
        one.store_geometry = plan.store_geometry && c.name == colors.focus;
        let summary = pipeline::acquire(dev, stage, &one, watcher_for(&c.name), control)
            .with_context(|| format!("acquiring {}", c.name))?;
        channels.push(ColorChannelSummary {
            name: c.name.clone(),
            wavelength_um: c.wavelength_um,
            summary,
        });
    }
    let manifest = ColorManifest::of_names(
        colors.channels.iter().map(|c| c.name.clone()),
        Some(colors.focus.clone()),
    );
    ColorDataset::write_manifest(&plan.out, &manifest)?;
    let ds = ColorDataset::open(&plan.out)?;
    let seconds = start.elapsed().as_secs_f64();
    let calibration = if plan.calibrate {
        let mut files = vec![];
        for c in &ds.channels {
            let path = c.dir.join("calibration.json");
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            let file: CalibrationFile = serde_json::from_str(&text)
                .with_context(|| format!("parsing {}", path.display()))?;
            files.push((c.name.clone(), file));
        }
        let cal = ColorCalibration::from_files(files, ds.reference);
        let path = plan.out.join("calibration.json");
        std::fs::write(&path, serde_json::to_string_pretty(&cal.to_json()?)?)
            .with_context(|| format!("writing {}", path.display()))?;
        Some(path)
    } else {
        None
    };
    let reconstruction = if plan.reconstruct {
        let geometry = match (&calibration, channels.first()) {
            (Some(path), _) => ColorGeometry::File(path.clone()),
            (None, Some(c)) if c.summary.geometry_source == GeometrySource::Board => {
                ColorGeometry::Given(c.summary.geometry, "the board's stored calibration".into())
            }
            _ => ColorGeometry::Nominal,
        };
        let job = fpm_host::reconstruction::Job {
            passes: plan.passes,
            tile: plan.tile,
            entrance_pupil_mm: plan.system.entrance_pupil_mm,
            settings: fpm_physics::reconstruct::Settings {
                flatten: plan.flatten,
                ..Default::default()
            },
            ..Default::default()
        };
        let run = fpm_host::color::reconstruct(&ds, &job, &geometry, &|_, _| {})?;
        // The page's own failure was logged: it is an extra.
        let _page = fpm_report::color::write(
            &run,
            &plan.out.join("reconstruction"),
            Default::default(),
            reproduce,
        )?;
        Some(run.report)
    } else {
        None
    };
    let summary = ColorAcquisition {
        channels,
        focus: colors.focus.clone(),
        seconds,
        calibration,
        reconstruction,
    };
    let path = plan.out.join("acquisition.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(summary)
}
