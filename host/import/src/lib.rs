//! Other labs' FPM data read into fpm datasets (docs/import.md): each source format's
//! conventions (axis order, LED index origin, the sign of the angles, units, HDR floats)
//! mapped onto docs/dataset.md's, what could not be read from the source taken from
//! the user ([`Stated`]) or refused by name, and every assumption written into the
//! dataset's `[source]` section.

pub mod caltech;
pub mod h5;
pub mod mat;
pub mod ptylab;
mod stack;
pub mod tiff_csv;
pub mod zheng;

use std::path::{Path, PathBuf};

use fpm_host::dataset::{
    CameraSection, Dataset, DatasetError, FrameEntry, LedSection, Manifest, Pixels, SourceSection,
    SystemSection,
};

/// A source format `fpm import` reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// The Zheng lab's MATLAB files (`imlow_HDR`, `xint`/`yint`, …).
    ZhengMat,
    /// Caltech's FPM_software MATLAB files (`imlow`, `NA_list`, …).
    CaltechMat,
    /// PtyLab's FPM HDF5 files (`ptychogram`, `encoder`, …).
    PtylabH5,
    /// A folder of TIFFs (or one multi-page TIFF) with a CSV of LED positions or NAs.
    TiffCsv,
}

impl Format {
    /// Every format, in the order `fpm import --list` prints them.
    pub const ALL: [Format; 4] = [
        Format::ZhengMat,
        Format::CaltechMat,
        Format::PtylabH5,
        Format::TiffCsv,
    ];

    /// The name users type.
    pub fn name(self) -> &'static str {
        match self {
            Format::ZhengMat => "zheng-mat",
            Format::CaltechMat => "caltech-mat",
            Format::PtylabH5 => "ptylab-h5",
            Format::TiffCsv => "tiff-csv",
        }
    }

    /// One line on what it reads.
    pub fn describe(self) -> &'static str {
        match self {
            Format::ZhengMat => "Zheng lab MATLAB file (v5 or v7.3): imlow_HDR, xint/yint, wlength, z",
            Format::CaltechMat => "Caltech FPM_software MATLAB file (v5 or v7.3): imlow, NA_list, NA, dpix_c, lambda, mag",
            Format::PtylabH5 => "PtyLab FPM HDF5 file: ptychogram, encoder, wavelength, dxd, zled",
            Format::TiffCsv => "a folder of TIFFs (or one multi-page TIFF) and a CSV of LED positions (x_mm, y_mm[, z_mm]) or NAs (na_x, na_y)",
        }
    }

    /// The format called `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// What the user states about the data: where the source says nothing, or says it
/// wrongly (a stated value always wins, and the dataset's `[source]` says so).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stated {
    /// µm.
    pub wavelength_um: Option<f64>,
    /// Objective NA.
    pub na: Option<f64>,
    /// Objective magnification.
    pub magnification: Option<f64>,
    /// Camera pixel, µm.
    pub pixel_size_um: Option<f64>,
    /// LED plane to sample, mm.
    pub height_mm: Option<f64>,
    /// zheng-mat: the LED pitch, mm (a constant of the reference code, not in its
    /// files).
    pub pitch_mm: Option<f64>,
    /// Sensor bits (raw counts saturate at 2^bits − 1).
    pub bit_depth: Option<u32>,
    /// Counts to subtract from every pixel.
    pub dark_level: Option<f64>,
    /// tiff-csv: the CSV (default: the one CSV in the folder, or beside the TIFF).
    pub csv: Option<PathBuf>,
}

/// Why an import failed: always naming the file, and the variable, column or option.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// A file cannot be read, or is not what the format says.
    #[error("{}: {reason}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A variable, dataset or column is missing or wrong.
    #[error("{}: `{field}`: {reason}", path.display())]
    Field {
        /// The file.
        path: PathBuf,
        /// The variable, dataset or column.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A value the source does not give and the user did not state.
    #[error("{format}: {reason}")]
    Needs {
        /// The format.
        format: &'static str,
        /// What is missing and the option that gives it.
        reason: String,
    },
    /// The dataset written does not load (a mapping this importer got wrong).
    #[error(transparent)]
    Dataset(#[from] DatasetError),
}

impl ImportError {
    pub(crate) fn io(path: &Path, e: std::io::Error) -> Self {
        Self::file(path, e.to_string())
    }

    pub(crate) fn file(path: &Path, reason: impl Into<String>) -> Self {
        Self::File {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }

    pub(crate) fn field(path: &Path, field: &str, reason: impl Into<String>) -> Self {
        Self::Field {
            path: path.to_path_buf(),
            field: field.to_string(),
            reason: reason.into(),
        }
    }
}

/// A source read into memory, mapped onto fpm's conventions.
pub struct Imported {
    /// `[system]`.
    pub system: SystemSection,
    /// `[led]`.
    pub led: LedSection,
    /// `[camera]`.
    pub camera: CameraSection,
    /// Each frame (its `file` set when written) and its pixels in sample-plane
    /// orientation (x along columns, y along rows).
    pub frames: Vec<(FrameEntry, Pixels)>,
    /// What was assumed, one sentence each.
    pub assumed: Vec<String>,
}

/// What an import wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// The dataset's directory.
    pub out: PathBuf,
    /// Frames written.
    pub frames: usize,
    /// Their size, (height, width).
    pub dim: (usize, usize),
    /// What was assumed (also in the dataset's `[source]`).
    pub assumed: Vec<String>,
}

/// Read `src` as `format` and write it as an fpm dataset in `out`.
pub fn import(
    format: Format,
    src: &Path,
    out: &Path,
    stated: &Stated,
) -> Result<Summary, ImportError> {
    let imported = read(format, src, stated)?;
    write(format, src, out, imported)
}

/// Read `src` as `format` into memory.
pub fn read(format: Format, src: &Path, stated: &Stated) -> Result<Imported, ImportError> {
    match format {
        Format::TiffCsv => tiff_csv::read(src, stated),
        Format::CaltechMat => caltech::read(src, stated),
        Format::ZhengMat => zheng::read(src, stated),
        Format::PtylabH5 => ptylab::read(src, stated),
    }
}

/// Write what was read as a dataset in `out`, and load it back (the loader's checks
/// catch a mapping that does not make a valid dataset).
pub fn write(
    format: Format,
    src: &Path,
    out: &Path,
    imported: Imported,
) -> Result<Summary, ImportError> {
    let Imported {
        system,
        led,
        camera,
        frames,
        assumed,
    } = imported;
    let dim = frames.first().map_or((0, 0), |(_, p)| p.dim());
    let (entries, pixels): (Vec<FrameEntry>, Vec<Pixels>) = frames.into_iter().unzip();
    let manifest = Manifest {
        system,
        led,
        camera,
        source: Some(SourceSection {
            format: format.name().into(),
            path: src.display().to_string(),
            assumed: assumed.clone(),
        }),
        frames: entries.clone(),
        entrance_pupil_mm: None,
    };
    let mut dataset = Dataset {
        dir: out.to_path_buf(),
        manifest,
        frames: entries
            .into_iter()
            .zip(pixels)
            .map(|(entry, raw)| fpm_host::dataset::Frame { entry, raw })
            .collect(),
    };
    dataset.save()?;
    let written = fpm_host::dataset::DatasetOnDisk::open(out)?;
    Ok(Summary {
        out: out.to_path_buf(),
        frames: written.manifest.frames.len(),
        dim,
        assumed,
    })
}

/// The four `[system]` numbers: each from the source (`from_source`, named) unless
/// the user stated it; any still missing refused with the option that gives it.
pub(crate) fn system_section(
    format: Format,
    from_source: [Option<f64>; 4],
    stated: &Stated,
    assumed: &mut Vec<String>,
) -> Result<SystemSection, ImportError> {
    const OPTIONS: [(&str, &str); 4] = [
        ("wavelength", "--wavelength-um"),
        ("objective NA", "--na"),
        ("magnification", "--magnification"),
        ("camera pixel", "--pixel-size-um"),
    ];
    let given = [
        stated.wavelength_um,
        stated.na,
        stated.magnification,
        stated.pixel_size_um,
    ];
    let mut values = [0.0; 4];
    let mut missing = Vec::new();
    for k in 0..4 {
        match (given[k], from_source[k]) {
            (Some(v), source) => {
                if let Some(s) = source.filter(|s| (s - v).abs() > 1e-9 * v.abs()) {
                    assumed.push(format!(
                        "{} {v} as stated ({}), not the source's {s}",
                        OPTIONS[k].0, OPTIONS[k].1
                    ));
                }
                values[k] = v;
            }
            (None, Some(v)) => values[k] = v,
            (None, None) => missing.push(format!("{} ({})", OPTIONS[k].0, OPTIONS[k].1)),
        }
    }
    if !missing.is_empty() {
        return Err(ImportError::Needs {
            format: format.name(),
            reason: format!(
                "the source does not give the {}: state it",
                missing.join(", ")
            ),
        });
    }
    Ok(SystemSection {
        wavelength_um: values[0],
        na: values[1],
        magnification: values[2],
        pixel_size_um: values[3],
    })
}

/// Frame k's LED id where a source numbers its frames only: (k / 256, k mod 256).
pub(crate) fn frame_id(k: usize) -> fpm_physics::LedIndex {
    fpm_physics::LedIndex::new((k / 256) as u8, (k % 256) as u8)
}

/// An in-focus frame under `led`, exposed as every other (sources that carry no
/// exposure).
pub(crate) fn in_focus(led: fpm_physics::LedIndex) -> FrameEntry {
    FrameEntry {
        also: vec![],
        file: String::new(),
        led,
        defocus_um: 0.0,
        exposure_ms: 1.0,
    }
}

/// `[camera]` for frames like `first` (what `what` names): the stated dark level and
/// bit depth, 8 bits for 8-bit frames, none for float (HDR) ones; an unstated dark
/// level on raw counts is an assumption said.
pub(crate) fn camera_for(
    first: Option<&Pixels>,
    what: &str,
    stated: &Stated,
    assumed: &mut Vec<String>,
) -> CameraSection {
    let float = matches!(first, Some(Pixels::F32(_)));
    let eight_bit = matches!(first, Some(Pixels::U8(_)));
    if stated.dark_level.is_none() && !float {
        assumed.push(format!(
            "no dark level stated (--dark-level): {what} taken as dark-subtracted"
        ));
    }
    CameraSection {
        dark_level: stated.dark_level.unwrap_or(0.0),
        bit_depth: stated
            .bit_depth
            .or(eight_bit.then_some(8))
            .filter(|_| !float),
        ..CameraSection::default()
    }
}
