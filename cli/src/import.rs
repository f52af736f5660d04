//! `fpm import`: other labs' FPM data into an fpm dataset.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use fpm_import::{Format, Stated};

use crate::units::{positive_mm, positive_um};

/// `fpm import FORMAT SRC --out DIR`.
#[derive(Args, Debug)]
pub struct ImportArgs {
    /// The source's format (`fpm import --list` names them).
    #[arg(required_unless_present = "list")]
    format: Option<String>,
    /// The source: a .mat or .h5 file, a TIFF folder or a multi-page TIFF.
    #[arg(required_unless_present = "list")]
    src: Option<PathBuf>,
    /// The dataset to write (a directory; created).
    #[arg(long, required_unless_present = "list")]
    out: Option<PathBuf>,
    /// List the formats and what each reads.
    #[arg(long)]
    list: bool,
    /// Wavelength, µm (where the source does not give it, or gives it wrongly).
    #[arg(long, value_parser = positive_um)]
    wavelength_um: Option<f64>,
    /// Objective NA.
    #[arg(long)]
    na: Option<f64>,
    /// Objective magnification.
    #[arg(long)]
    magnification: Option<f64>,
    /// Camera pixel pitch, µm (on the sensor, not at the sample).
    #[arg(long, value_parser = positive_um)]
    pixel_size_um: Option<f64>,
    /// Distance from the LEDs (a listed array's origin) to the sample, mm.
    #[arg(long, value_parser = positive_mm)]
    height_mm: Option<f64>,
    /// zheng-mat: the LED pitch, mm (the reference code's constant, not in its files).
    #[arg(long, value_parser = positive_mm)]
    pitch_mm: Option<f64>,
    /// Sensor bit depth (raw counts saturate at 2^bits − 1).
    #[arg(long)]
    bit_depth: Option<u32>,
    /// Counts to subtract from every pixel (the camera's dark level).
    #[arg(long)]
    dark_level: Option<f64>,
    /// tiff-csv: the CSV of LED positions or NAs [default: the one CSV in the folder,
    /// or SRC with .csv].
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Print what was written as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(a: ImportArgs) -> Result<()> {
    if a.list {
        if a.json {
            let formats: Vec<_> = Format::ALL
                .iter()
                .map(|f| serde_json::json!({ "name": f.name(), "reads": f.describe() }))
                .collect();
            println!("{}", serde_json::to_string_pretty(&formats)?);
        } else {
            for f in Format::ALL {
                println!("{:12} {}", f.name(), f.describe());
            }
        }
        return Ok(());
    }
    let (Some(name), Some(src), Some(out)) = (a.format, a.src, a.out) else {
        bail!("give FORMAT, SRC and --out DIR (or --list)");
    };
    let Some(format) = Format::from_name(&name) else {
        let names: Vec<_> = Format::ALL.iter().map(|f| f.name()).collect();
        bail!("unknown format {name:?}: one of {}", names.join(", "));
    };
    let stated = Stated {
        wavelength_um: a.wavelength_um,
        na: a.na,
        magnification: a.magnification,
        pixel_size_um: a.pixel_size_um,
        height_mm: a.height_mm,
        pitch_mm: a.pitch_mm,
        bit_depth: a.bit_depth,
        dark_level: a.dark_level,
        csv: a.csv,
    };
    let summary = fpm_import::import(format, &src, &out, &stated)?;
    if a.json {
        let json = serde_json::json!({
            "format": format.name(),
            "source": src,
            "out": summary.out,
            "frames": summary.frames,
            "height": summary.dim.0,
            "width": summary.dim.1,
            "assumed": summary.assumed,
        });
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else {
        println!(
            "wrote {} frames ({}x{}) from {} ({}) to {}",
            summary.frames,
            summary.dim.1,
            summary.dim.0,
            src.display(),
            format.name(),
            summary.out.display()
        );
        for a in &summary.assumed {
            println!("  assumed: {a}");
        }
    }
    Ok(())
}
