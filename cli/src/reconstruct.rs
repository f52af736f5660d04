//! `fpm reconstruct DIR --out OUT`: EPRY phase retrieval of a dataset.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::Args;
use fpm_physics::background::Correction;
use fpm_physics::reconstruct::{defaults, GammaScan, Refine, Settings};

use fpm_host::dataset::image_io::TiffOptions;
use fpm_host::reconstruction::{
    CameraGamma, GeometryChoice, ImageFormat, Job, JobEvent, OutputOptions, Refocus, Report,
    ZARR_NAME,
};

use crate::flatten::FlattenArgs;
use crate::units::positive_mm;

mod batch;

/// Reconstruct the high-resolution amplitude and phase (and the pupil) with EPRY.
///
/// One dataset into `--out DIR`, or many (the fields of view of a slide) each into
/// its own directory under `--out-root ROOT`, skipping those already done.
#[derive(Args, Debug)]
pub struct ReconstructArgs {
    /// Dataset directories (with dataset.toml); their in-focus frames are used. One
    /// with --out; any number, or quoted patterns such as 'slide/field_*', with
    /// --out-root.
    #[arg(required = true)]
    dirs: Vec<PathBuf>,
    /// Output directory (one dataset).
    #[arg(
        long,
        required_unless_present = "out_root",
        conflicts_with = "out_root"
    )]
    out: Option<PathBuf>,
    /// Reconstruct each dataset into OUT_ROOT/<its directory's name>. Datasets whose
    /// output is already there are skipped; a run is written to a hidden partial
    /// directory and moved into place only when complete, so an interrupted batch
    /// resumes where it stopped.
    #[arg(long)]
    out_root: Option<PathBuf>,
    /// With --out-root: reconstruct the datasets already done again.
    #[arg(long, requires = "out_root")]
    redo: bool,
    /// LED array placement to reconstruct with: the calibration.json of `fpm
    /// calibrate`, or a JSON file with just dx_mm, dy_mm, theta_deg and height_mm (an
    /// array measured by other means; the grid then comes from the dataset). Without
    /// it, a dataset is reconstructed with the placement it was acquired with where its
    /// acquisition.json records one (the calibration made then, or the one stored on
    /// the board), else with its nominal placement (dataset.toml).
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// The dataset's nominal placement (dataset.toml), even where acquisition.json
    /// records a calibrated one: to compare the two.
    #[arg(long, conflicts_with_all = ["calibration", "led_height_mm"])]
    nominal_geometry: bool,
    /// The LEDs' height below the sample, mm, instead of the dataset's (the rest of the
    /// nominal placement kept): for a height misreported or measured to another plane.
    /// When the bright/dark-field edge of the frames disagrees with the dataset's
    /// height, this command warns and names the height it finds there.
    #[arg(long, conflicts_with = "calibration", value_parser = positive_mm)]
    led_height_mm: Option<f64>,
    /// The objective's entrance pupil distance above the sample, mm, for objectives
    /// that are not telecentric (camera lenses, simple low-power objectives): the
    /// chief ray of a point x off the axis aims at the pupil, so every LED's angle to
    /// it changes across the field. Stated wrong or left out, outer tiles get stripes
    /// and ripples at the frequency of that error, and frames that are partly bright
    /// where the nominal geometry says dark. Default: telecentric. The report's edge
    /// check says when the frames' bright/dark-field edges ask for one
    #[arg(long, value_parser = positive_mm)]
    entrance_pupil_mm: Option<f64>,
    /// The frames were saved for viewing with this display gamma (e.g. 2.2), not as
    /// raw counts: decode them so (overrides the dataset's `[camera] gamma`; needs its
    /// `bit_depth`). `auto` reads it from the frames: the central square (≤ 256 px) is
    /// reconstructed with each candidate gamma (1–3) and the one whose result explains
    /// the frames best is taken (1: linear; about ten short runs first). Without the
    /// flag, 8-bit frames whose dataset states no gamma are scanned so too, and decoded
    /// only with a clear gamma (`1` keeps them linear). The report's bright-field fit
    /// warns when frames read as linear hold light no object explains
    #[arg(long, value_name = "GAMMA|auto", value_parser = camera_gamma)]
    camera_gamma: Option<CameraGamma>,
    /// The sample sat this far from focus when the frames were taken, µm (toward the
    /// LEDs positive, as dataset.toml's defocus_um): the pupil starts with that
    /// defocus and the image comes out refocused onto the sample. Frames of a sample
    /// left out of focus give spoke-like artefacts around small features and smeared
    /// fine detail when reconstructed as in focus. `auto`: as far as the bright-field
    /// frames' shifts against each other say. Left out: that too, where the shifts
    /// clearly show a defocus (beyond 3σ), else as in focus; the report says which
    #[arg(long, value_name = "UM|auto", allow_hyphen_values = true, value_parser = refocus)]
    refocus_um: Option<Refocus>,
    /// HR pixels per camera pixel.
    #[arg(long, default_value_t = defaults::UPSAMPLE)]
    upsample: usize,
    /// Passes over all frames.
    #[arg(long, default_value_t = defaults::PASSES)]
    passes: usize,
    /// Object step size α (1 = the full ePIE step).
    #[arg(long, default_value_t = Settings::default().alpha)]
    alpha: f32,
    /// Pupil step size β.
    #[arg(long, default_value_t = Settings::default().beta)]
    beta: f32,
    /// Keep the ideal pupil instead of recovering it.
    #[arg(long)]
    fixed_pupil: bool,
    #[command(flatten)]
    flatten: FlattenArgs,
    /// Tile side, camera pixels: larger or non-square frames are cut into overlapping
    /// tiles (a quarter tile of overlap, at least 8 PSF widths), each with its own wave
    /// vectors, reconstructed in parallel and blended. Default: from the physics, the
    /// largest side over which every LED's wave stays within 0.25 rad of the axial
    /// LED's curvature at the tile's edge (64–512 px); a square frame no larger is one
    /// tile.
    #[arg(long)]
    tile: Option<usize>,
    /// What is taken off the frames: the dataset's dark level only, or also each
    /// dark-field frame's own background, measured in its darkest blocks (the stray
    /// light and offset drift that long dark-field exposures pick up).
    #[arg(long, value_enum, default_value_t = BackgroundArg::PerFrame)]
    background: BackgroundArg,
    /// With `--background per-frame`: the floor, in standard deviations of the
    /// dark-field frame's background noise (0: only the level is taken off).
    #[arg(long, default_value_t = defaults::FLOOR_SIGMA)]
    floor_sigma: f32,
    /// With `--background per-frame`: how the floor treats the light near it. soft
    /// (default): light v counts as v·(v²/(v² + floor²))², so noise barely counts and
    /// dim light in part; hard: everything up to the floor is cut
    #[arg(long, value_enum, default_value_t = FloorArg::Soft)]
    floor: FloorArg,
    /// With `--background per-frame`: the noise band of the dark-field frames that are
    /// mostly noise (their brightest block under 20× their noise), in standard
    /// deviations of that noise. Where the model's light lies within it of a measured
    /// pixel the model keeps it, so such frames' noise is not pressed into the object
    /// (docs/results.md, "Noise band"). 0: every pixel imposed exactly
    #[arg(long, default_value_t = defaults::NOISE_BAND_SIGMA)]
    noise_band_sigma: f32,
    /// Refine each LED's position inside the passes, from the second pass on: for
    /// boards with LEDs off their grid or mounted at a tilt. Each frame's place is
    /// measured against the data with its own uncertainty; a board model (its tilts) is
    /// fitted to them, and each LED takes its own move only as far as the data say the
    /// LEDs sit off the model (τ, printed), so a well-built board's LEDs and dim
    /// dark-field frames stay on the model. The refined positions go into report.json,
    /// and a rigid, tilted board fitted to them into refined-board.json (usable as
    /// --calibration; with dim dark field the image gains but the positions are not a
    /// calibration). Each pass takes 3–5× longer.
    #[arg(long)]
    refine_leds: bool,
    /// How amplitude and phase are stored: OME-TIFFs (amplitude.tif, phase.tif), or
    /// one OME-Zarr multiscale image (image.ome.zarr: both as channels, chunked, a
    /// pyramid for large mosaics; napari opens it).
    #[arg(long, value_enum, default_value_t = FormatArg::Tiff)]
    format: FormatArg,
    /// Deflate-compress amplitude.tif and phase.tif (lossless; OME-TIFF either way).
    #[arg(long)]
    compress: bool,
    /// Frames (in-focus, as stored) up to this size are held in memory; a larger set
    /// is read from disk band by band (each frame whole once, then one band of tile
    /// rows of every frame at a time), with the same result. GB.
    #[arg(long, default_value_t = 8.0)]
    frame_memory_gb: f64,
    /// Print the report (report.json) as JSON instead of text.
    #[arg(long)]
    json: bool,
}

fn refocus(text: &str) -> Result<Refocus, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(Refocus::Auto);
    }
    text.parse()
        .map(Refocus::Distance)
        .map_err(|_| format!("{text}: give a distance in µm (0: as in focus) or auto"))
}

fn camera_gamma(text: &str) -> Result<CameraGamma, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(CameraGamma::Auto);
    }
    text.parse()
        .map(CameraGamma::Exponent)
        .map_err(|_| format!("{text}: give an exponent (2.2 for sRGB-like images) or auto"))
}

/// `--format`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum FormatArg {
    /// amplitude.tif and phase.tif, float32 OME-TIFF.
    Tiff,
    /// image.ome.zarr (OME-Zarr 0.4).
    OmeZarr,
}

/// `--background`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum BackgroundArg {
    /// The dataset's dark level only.
    DarkLevel,
    /// Also each dark-field frame's own background, its noise floored.
    PerFrame,
}

/// `--floor`.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq)]
pub enum FloorArg {
    /// Light near the floor shrunk.
    Soft,
    /// Light up to the floor cut.
    Hard,
}

impl ReconstructArgs {
    fn background(&self) -> Correction {
        match self.background {
            BackgroundArg::DarkLevel => Correction::DarkLevel,
            BackgroundArg::PerFrame => Correction::PerFrame {
                floor_sigma: self.floor_sigma,
                soft: self.floor == FloorArg::Soft,
                band_sigma: self.noise_band_sigma,
            },
        }
    }
}

/// Run `fpm reconstruct`.
pub fn run(a: ReconstructArgs) -> Result<()> {
    match (&a.out, &a.out_root) {
        (Some(out), None) => match a.dirs.as_slice() {
            [dir] => one(&a, dir, out),
            dirs => bail!(
                "--out takes one dataset, not {}: use --out-root ROOT to give each its own directory",
                dirs.len()
            ),
        },
        (None, Some(root)) => batch::run(&a, root),
        _ => bail!("give --out DIR (one dataset) or --out-root ROOT (many)"),
    }
}

/// One line on what the gamma scan found, and the gamma the frames were decoded with.
fn gamma_summary(scan: &GammaScan, decoded: Option<f64>) -> String {
    let read = match decoded {
        Some(gamma) => format!("decoded with gamma {gamma:.2}"),
        None if scan.linear => "linear (no display encoding)".to_string(),
        None => format!(
            "best gamma {:.2}, not clearly apart from linear: read as linear",
            scan.best
        ),
    };
    let table: Vec<String> = scan
        .candidates
        .iter()
        .map(|c| format!("{:.1}: {:.4}", c.gamma, c.error))
        .collect();
    format!(
        "camera gamma read from the frames ({} px square, {} passes each): {read}; error within {:.0} % of its least for gamma {:.1}-{:.1} [{}]",
        scan.side_px,
        scan.passes,
        100.0 * fpm_physics::reconstruct::gamma::FLAT_WITHIN,
        scan.range.0,
        scan.range.1,
        table.join(", ")
    )
}

impl ReconstructArgs {
    /// The job these arguments describe.
    fn job(&self) -> Job {
        Job {
            geometry: match (&self.calibration, self.led_height_mm) {
                (Some(path), _) => GeometryChoice::File(path.clone()),
                (None, Some(h)) => GeometryChoice::LedHeightMm(h),
                (None, None) if self.nominal_geometry => GeometryChoice::Nominal,
                (None, None) => GeometryChoice::AsAcquired,
            },
            entrance_pupil_mm: self.entrance_pupil_mm,
            camera_gamma: self.camera_gamma,
            settings: Settings {
                upsample: self.upsample,
                update_pupil: !self.fixed_pupil,
                alpha: self.alpha,
                beta: self.beta,
                background: self.background(),
                refine_leds: self.refine_leds.then(Refine::default),
                flatten: self.flatten.flatten(),
                defocus_um: 0.0,
            },
            refocus: self.refocus_um.unwrap_or_default(),
            passes: self.passes,
            tile: self.tile,
            frame_memory_gb: self.frame_memory_gb,
        }
    }

    fn output(&self) -> OutputOptions {
        OutputOptions {
            format: match self.format {
                FormatArg::Tiff => ImageFormat::Tiff,
                FormatArg::OmeZarr => ImageFormat::OmeZarr,
            },
            tiff: TiffOptions {
                compress: self.compress,
                ..TiffOptions::default()
            },
        }
    }
}

/// Reconstruct the dataset in `dir` into `out` and print what it did.
fn one(a: &ReconstructArgs, dir: &Path, out: &Path) -> Result<()> {
    if fpm_host::color::is_color(dir) {
        return color(a, dir, out);
    }
    let gamma_bar = crate::progress::counter(
        &format!("reading the camera gamma of {}", dir.display()),
        "candidates",
    );
    let bar = crate::progress::counter(
        &format!("reconstructing {}", dir.display()),
        "frame updates",
    );
    let finished = a.job().run(dir, &|event| match event {
        JobEvent::GammaCandidates { done, total } => crate::progress::advance(&gamma_bar, done, total),
        JobEvent::FromDisk { bytes } => eprintln!(
            "{}: the frames take {:.1} GB, over --frame-memory-gb {}: reading them from disk band by band",
            dir.display(),
            bytes as f64 / 1e9,
            a.frame_memory_gb
        ),
        JobEvent::WeighingEdgeHeight { stated_mm, edge_mm } => {
            bar.reset();
            eprintln!(
                "{}: the bright/dark-field edge puts the LEDs at {edge_mm:.1} mm, not the dataset's {stated_mm:.1} mm: reconstructing at it too, to keep the height the frames fit clearly better",
                dir.display()
            );
        }
        JobEvent::Updates { done, total } => crate::progress::advance(&bar, done, total),
    })?;
    gamma_bar.finish_and_clear();
    bar.finish_and_clear();
    let written = fpm_report::reconstruction::write(
        &finished,
        out,
        a.output(),
        &fpm_report::html::command_line(),
    )?;
    for w in &written.warnings {
        eprintln!("warning: {w}");
    }
    let rep = &finished.reconstruction.report;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&fpm_host::reconstruction::report_json(rep)?)?
        );
        return Ok(());
    }
    if let Some(scan) = &finished.gamma_scan {
        println!("{}", gamma_summary(scan, rep.camera_gamma));
    }
    print_report(rep, out, a.output().format);
    if let Ok(page) = &written.page {
        println!(
            "wrote {} (the report: open it in a browser)",
            page.display()
        );
    }
    Ok(())
}

/// The report of one reconstruction, as text.
fn print_report(rep: &Report, out: &Path, format: ImageFormat) {
    println!(
        "{} frames ({}x{}, {} tile(s) of {} px), {} passes, {}x upsampling in {:.2} s ({:.0} ms per pass); amplitude error per pass: first {:.4}, last {:.4}",
        rep.frames,
        rep.frame_size[0],
        rep.frame_size[1],
        rep.tiles.len(),
        rep.tile_size,
        rep.passes,
        rep.upsample,
        rep.total_ms / 1e3,
        rep.ms_per_pass,
        rep.error_per_pass.first().copied().unwrap_or(f64::NAN),
        rep.error_per_pass.last().copied().unwrap_or(f64::NAN)
    );
    if let Some(b) = &rep.height_from_boundary {
        println!(
            "h from the bright/dark-field edge: {:.2} ± {:.2} mm (± {:.2} mm with the NA's {:.0} %; the geometry's {:.2} mm, {:+.1}σ)",
            b.estimate.height_mm,
            b.estimate.sigma_mm,
            b.sigma_with_na_mm,
            b.na_relative_sigma * 100.0,
            b.geometry_height_mm,
            b.difference_sigma
        );
    }
    if let Some(c) = &rep.height_choice {
        println!("LED height {c}");
    }
    if let Some(r) = &rep.refined_leds {
        print_refined(r, out);
    }
    if rep.background_phase.block_um.is_some() {
        println!(
            "background phase: {}",
            fpm_report::pages::reconstruction::background_phase(&rep.background_phase)
        );
    }
    if let Some(s) = &rep.versus_truth {
        println!(
            "versus the simulation's truth: complex NRMSE {:.3} ({:.3} with the slow phase fitted out), amplitude NRMSE {:.3}, phase RMSE {:.3} rad",
            s.complex_nrmse, s.detail_nrmse, s.amplitude_nrmse, s.phase_rmse_rad
        );
    }
    println!(
        "wrote {}, pupil TIFFs, PNG previews, charts (plots/) and report.json to {}",
        match format {
            ImageFormat::Tiff => "amplitude/phase OME-TIFFs (pixel size in µm)".to_string(),
            ImageFormat::OmeZarr => format!("{ZARR_NAME} (amplitude and phase, OME-Zarr pyramid)"),
        },
        out.display()
    );
}

fn print_refined(r: &fpm_host::refinement::RefinedLedsReport, out: &Path) {
    println!(
        "LEDs refined: moved {:.3} mm RMS from the geometry's places{}",
        r.moved_rms_mm,
        r.led_scatter_mm.map_or(String::new(), |t| format!(
            "; the data put them {t:.3} mm (1σ) off the board model"
        ))
    );
    if let Some(t) = &r.versus_truth {
        println!(
            "  versus the simulation's truth: LEDs off by {:.3} mm RMS as given, {:.3} mm refined",
            t.given_rms_mm, t.refined_rms_mm
        );
    }
    if let Some(b) = &r.board {
        println!(
            "  board fitted to them: {} ({})",
            b.summary(),
            out.join(fpm_host::refinement::BOARD_FILE).display()
        );
    }
}

/// Reconstruct a colour dataset: every channel into `out/<name>/` as `fpm reconstruct`
/// of its dataset would, then the registered colour images, preview and report into
/// `out`.
fn color(a: &ReconstructArgs, dir: &Path, out: &Path) -> Result<()> {
    use fpm_host::color::{self, ColorDataset, ColorGeometry};
    let ds = ColorDataset::open(dir)?;
    let geometry = match &a.calibration {
        Some(path) => ColorGeometry::File(path.clone()),
        None => ColorGeometry::Nominal,
    };
    let bar = crate::progress::counter(
        &format!("reconstructing {}", dir.display()),
        "frame updates",
    );
    let current = std::sync::Mutex::new(String::new());
    let run = color::reconstruct(&ds, &a.job(), &geometry, &|name, event| {
        if let Ok(mut c) = current.lock() {
            if *c != name {
                *c = name.to_string();
                bar.reset();
                bar.set_message(format!("reconstructing {} ({name})", dir.display()));
            }
        }
        match event {
            JobEvent::Updates { done, total } => crate::progress::advance(&bar, done, total),
            JobEvent::FromDisk { bytes } => eprintln!(
                "{name}: the frames take {:.1} GB, over --frame-memory-gb {}: reading them from disk band by band",
                bytes as f64 / 1e9,
                a.frame_memory_gb
            ),
            JobEvent::WeighingEdgeHeight { stated_mm, edge_mm } => eprintln!(
                "{name}: the bright/dark-field edge puts the LEDs at {edge_mm:.1} mm, not the dataset's {stated_mm:.1} mm: reconstructing at it too"
            ),
            JobEvent::GammaCandidates { .. } => {}
        }
    })?;
    bar.finish_and_clear();
    write_and_print_color(&run, out, a.output(), a.json)
}

/// Write a colour run's outputs into `out` (each channel's own in `out/<name>/`) and
/// print what it did (`json`: its report).
fn write_and_print_color(
    run: &fpm_host::color::ColorRun,
    out: &Path,
    output: OutputOptions,
    json: bool,
) -> Result<()> {
    use fpm_host::color;
    let page = fpm_report::color::write(run, out, output, &fpm_report::html::command_line())?;
    let report = &run.report;
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        println!(
            "{} channels, registered to {}, LEDs placed by {}:",
            report.channels.len(),
            report.reference,
            report.geometry
        );
        for c in &report.channels {
            let truth = c.versus_truth.map_or(String::new(), |s| {
                format!(", complex NRMSE {:.3} against its truth", s.complex_nrmse)
            });
            let shift = c
                .shift_um
                .map_or("not registered (no texture)".to_string(), |[x, y]| {
                    format!("shifted ({x:+.2}, {y:+.2}) µm")
                });
            println!(
                "  {} ({:.1} nm): final error {:.4}, {shift}{truth} ({}/)",
                c.name,
                c.wavelength_um * 1e3,
                c.final_error.unwrap_or(f64::NAN),
                out.join(&c.output).display()
            );
        }
        println!(
            "wrote amplitude/phase OME-TIFFs with one channel per wavelength (or {}), {} (sRGB, white-balanced on the clear background) and report.json to {}",
            fpm_host::reconstruction::ZARR_NAME,
            color::PREVIEW_NAME,
            out.display()
        );
        if let Ok(page) = &page {
            println!(
                "wrote {} (the report: open it in a browser)",
                page.display()
            );
        }
    }
    for w in &report.warnings {
        eprintln!("warning: {}", w.message);
    }
    // Each channel's warnings, named by its channel; one said by several, once.
    let mut said: Vec<(&str, Vec<&str>)> = vec![];
    for c in &report.channels {
        for w in &c.warnings {
            match said.iter_mut().find(|(m, _)| *m == w.message) {
                Some((_, names)) => names.push(&c.name),
                None => said.push((&w.message, vec![&c.name])),
            }
        }
    }
    for (message, names) in said {
        eprintln!("warning: {}: {message}", names.join(", "));
    }
    Ok(())
}
