//! `tiff-csv`: the simplest way labs share FPM data: a folder of TIFFs (or one
//! multi-page TIFF) and a CSV with one row per frame giving its LED's position or
//! illumination NA. Every unit is in the column's name (`x_mm`, `na_x`), so a column
//! whose unit is not said is refused, not guessed.
//!
//! Columns (a header row first; `,`, `;` or tab between fields; `#` starts a comment):
//! `file` (the frame's TIFF, relative to the CSV; absent: the folder's TIFFs sorted by
//! name, or the pages in order), `row`, `col` (the LED's id; absent: the row's index
//! k as (k / 256, k mod 256)), `x_mm`, `y_mm`, optional `z_mm` (docs/dataset.md §1.2:
//! the array's frame, + z away from the sample) or `na_x`, `na_y` (the LED's sines
//! seen from the field's centre, signed as its position), optional `exposure_ms`
//! (intensities are divided by it) and `defocus_um`.

use std::path::{Path, PathBuf};

use fpm_host::dataset::{FrameEntry, LedNa, LedNas, LedSection, Pixels};
use fpm_physics::{LedIndex, LedList, ListedLed};

use crate::{camera_for, system_section, Format, ImportError, Imported, Stated};

/// The columns this format knows.
const COLUMNS: [&str; 10] = [
    "file",
    "row",
    "col",
    "x_mm",
    "y_mm",
    "z_mm",
    "na_x",
    "na_y",
    "exposure_ms",
    "defocus_um",
];

/// Read a TIFF folder or multi-page TIFF `src` and its CSV.
pub fn read(src: &Path, stated: &Stated) -> Result<Imported, ImportError> {
    let csv_path = find_csv(src, stated)?;
    let table = Table::read(&csv_path)?;
    let base = csv_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let images = images(src, &table, &csv_path, &base)?;

    let mut assumed = Vec::new();
    let ids = table.ids(&csv_path)?;
    if table.column("row").is_none() {
        assumed.push(
            "no row/col columns: LED ids are the CSV rows' order, k as (k / 256, k mod 256)".into(),
        );
    }
    let number = |name: &str, k: usize| table.number(&csv_path, name, k);
    let has = |name: &str| table.column(name).is_some();
    let height_mm = stated.height_mm.ok_or_else(|| ImportError::Needs {
        format: Format::TiffCsv.name(),
        reason: "the LEDs' distance below the sample is not in a CSV: state it with --height-mm"
            .into(),
    })?;
    let led = led_section(&table, &csv_path, &ids, height_mm)?;

    let frames = images
        .into_iter()
        .enumerate()
        .map(|(k, (_, pixels))| {
            let entry = FrameEntry {
                also: vec![],
                file: String::new(),
                led: ids[k],
                defocus_um: if has("defocus_um") {
                    number("defocus_um", k)?
                } else {
                    0.0
                },
                exposure_ms: if has("exposure_ms") {
                    number("exposure_ms", k)?
                } else {
                    1.0
                },
            };
            Ok((entry, pixels))
        })
        .collect::<Result<Vec<_>, ImportError>>()?;
    if !has("exposure_ms") {
        assumed.push("no exposure_ms column: every frame exposed alike".into());
    }
    let camera = camera_for(
        frames.first().map(|f| &f.1),
        "the frames",
        stated,
        &mut assumed,
    );
    let system = system_section(Format::TiffCsv, [None; 4], stated, &mut assumed)?;
    Ok(Imported {
        system,
        led,
        camera,
        frames,
        assumed,
    })
}

/// The frames, each with its name: the `file` column's TIFFs (relative to the CSV at
/// `base`), else the folder's TIFFs by name, else the multi-page TIFF's pages; one for
/// each of the CSV's rows, all of one size.
fn images(
    src: &Path,
    table: &Table,
    csv_path: &Path,
    base: &Path,
) -> Result<Vec<(String, Pixels)>, ImportError> {
    let images: Vec<(String, Pixels)> = match table.column("file") {
        Some(files) => files
            .iter()
            .map(|f| {
                let path = base.join(f);
                Ok((f.clone(), one_page(&path)?))
            })
            .collect::<Result<_, ImportError>>()?,
        None if src.is_dir() => {
            let tiffs = tiffs_in(src)?;
            if tiffs.len() != table.rows.len() {
                return Err(ImportError::file(
                    csv_path,
                    format!(
                        "{} rows but {} TIFFs in {}: give a `file` column to pair them",
                        table.rows.len(),
                        tiffs.len(),
                        src.display()
                    ),
                ));
            }
            tiffs
                .into_iter()
                .map(|p| {
                    let name = p.file_name().map(|n| n.to_string_lossy().into_owned());
                    Ok((name.unwrap_or_default(), one_page(&p)?))
                })
                .collect::<Result<_, ImportError>>()?
        }
        None => {
            let pages = pages(src)?;
            if pages.len() != table.rows.len() {
                return Err(ImportError::file(
                    csv_path,
                    format!(
                        "{} rows but {} pages in {}",
                        table.rows.len(),
                        pages.len(),
                        src.display()
                    ),
                ));
            }
            pages
                .into_iter()
                .enumerate()
                .map(|(k, p)| (format!("page {k}"), p))
                .collect()
        }
    };
    if let Some((name, p)) = images.iter().find(|(_, p)| p.dim() != images[0].1.dim()) {
        return Err(ImportError::file(
            &base.join(name),
            format!(
                "{}x{} differs from the first frame's {}x{}",
                p.dim().1,
                p.dim().0,
                images[0].1.dim().1,
                images[0].1.dim().0
            ),
        ));
    }
    Ok(images)
}

/// The LED section: each row's LED placed by its position or its NA (not both), an
/// LED given twice only alike.
fn led_section(
    table: &Table,
    csv_path: &Path,
    ids: &[LedIndex],
    height_mm: f64,
) -> Result<LedSection, ImportError> {
    let number = |name: &str, k: usize| table.number(csv_path, name, k);
    let has = |name: &str| table.column(name).is_some();
    let mut positions: Vec<ListedLed> = Vec::new();
    let mut nas: Vec<LedNa> = Vec::new();
    let by_position = has("x_mm") || has("y_mm");
    let by_na = has("na_x") || has("na_y");
    match (by_position, by_na) {
        (true, true) => {
            return Err(ImportError::file(
                csv_path,
                "give the LEDs' positions (x_mm, y_mm) or their NAs (na_x, na_y), not both",
            ))
        }
        (false, false) => {
            return Err(ImportError::file(
                csv_path,
                "no LED columns: give x_mm and y_mm (and z_mm) or na_x and na_y",
            ))
        }
        _ => {}
    }
    for (k, &led) in ids.iter().enumerate() {
        if by_position {
            let place = ListedLed {
                led,
                x_mm: number("x_mm", k)?,
                y_mm: number("y_mm", k)?,
                z_mm: if has("z_mm") { number("z_mm", k)? } else { 0.0 },
            };
            match positions.iter().find(|p| p.led == led) {
                Some(p) if *p != place => {
                    return Err(ImportError::field(
                        csv_path,
                        "x_mm",
                        format!("row {}: LED {led} is placed twice, differently", k + 1),
                    ))
                }
                Some(_) => {}
                None => positions.push(place),
            }
        } else {
            let na = LedNa {
                led,
                na: [number("na_x", k)?, number("na_y", k)?],
            };
            match nas.iter().find(|n| n.led == led) {
                Some(n) if *n != na => {
                    return Err(ImportError::field(
                        csv_path,
                        "na_x",
                        format!("row {}: LED {led} is given two NAs", k + 1),
                    ))
                }
                Some(_) => {}
                None => nas.push(na),
            }
        }
    }
    let mut led = LedSection::listed(height_mm);
    if by_position {
        led.position = Some(
            LedList::new(positions).map_err(|e| ImportError::field(csv_path, "x_mm", e.message))?,
        );
    } else {
        led.na = Some(LedNas::new(nas).map_err(|e| ImportError::field(csv_path, "na_x", e))?);
    }

    Ok(led)
}

/// The CSV: as stated, the one CSV in the folder, or `<stem>.csv` beside a TIFF.
fn find_csv(src: &Path, stated: &Stated) -> Result<PathBuf, ImportError> {
    if let Some(csv) = &stated.csv {
        return Ok(csv.clone());
    }
    if src.is_dir() {
        let csvs: Vec<PathBuf> = std::fs::read_dir(src)
            .map_err(|e| ImportError::io(src, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| has_extension(p, &["csv"]))
            .collect();
        return match csvs.as_slice() {
            [one] => Ok(one.clone()),
            [] => Err(ImportError::file(
                src,
                "no .csv in the folder: name it with --csv",
            )),
            _ => Err(ImportError::file(
                src,
                format!(
                    "{} .csv files in the folder: name one with --csv",
                    csvs.len()
                ),
            )),
        };
    }
    let beside = src.with_extension("csv");
    if beside.is_file() {
        Ok(beside)
    } else {
        Err(ImportError::file(
            src,
            format!("no {} beside it: name the CSV with --csv", beside.display()),
        ))
    }
}

fn has_extension(path: &Path, exts: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| exts.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// The TIFFs in `dir`, by name.
fn tiffs_in(dir: &Path) -> Result<Vec<PathBuf>, ImportError> {
    let mut tiffs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| ImportError::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| has_extension(p, &["tif", "tiff"]))
        .collect();
    tiffs.sort();
    Ok(tiffs)
}

/// The first image of a TIFF.
fn one_page(path: &Path) -> Result<Pixels, ImportError> {
    fpm_host::dataset::image_io::read(path).map_err(|e| ImportError::file(path, e.reason()))
}

/// Every page of a multi-page TIFF, grey-scale 8- or 16-bit or 32-bit float.
fn pages(path: &Path) -> Result<Vec<Pixels>, ImportError> {
    use tiff::decoder::{Decoder, DecodingResult};
    let bad = |e: tiff::TiffError| ImportError::file(path, format!("TIFF: {e}"));
    let file = std::fs::File::open(path).map_err(|e| ImportError::io(path, e))?;
    let mut decoder = Decoder::new(std::io::BufReader::new(file)).map_err(bad)?;
    let mut pages = Vec::new();
    loop {
        let k = pages.len();
        let page = |reason: String| ImportError::file(path, format!("page {k}: {reason}"));
        let colour = decoder.colortype().map_err(bad)?;
        if !matches!(colour, tiff::ColorType::Gray(_)) {
            return Err(page(format!("{colour:?}: grey-scale pages only")));
        }
        let (w, h) = decoder.dimensions().map_err(bad)?;
        let shape = (h as usize, w as usize);
        let wrong = |e: ndarray::ShapeError| page(e.to_string());
        pages.push(match decoder.read_image().map_err(bad)? {
            DecodingResult::U8(v) => {
                Pixels::U8(ndarray::Array2::from_shape_vec(shape, v).map_err(wrong)?)
            }
            DecodingResult::U16(v) => {
                Pixels::U16(ndarray::Array2::from_shape_vec(shape, v).map_err(wrong)?)
            }
            DecodingResult::F32(v) => {
                Pixels::F32(ndarray::Array2::from_shape_vec(shape, v).map_err(wrong)?)
            }
            DecodingResult::F64(v) => Pixels::F32(
                ndarray::Array2::from_shape_vec(shape, v.into_iter().map(|x| x as f32).collect())
                    .map_err(wrong)?,
            ),
            _ => {
                return Err(page(
                    "sample type: 8- or 16-bit unsigned or float only".into(),
                ))
            }
        });
        if !decoder.more_images() {
            break;
        }
        decoder.next_image().map_err(bad)?;
    }
    Ok(pages)
}

/// A CSV: its header's names (lower case) and its rows' fields.
struct Table {
    names: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    fn read(path: &Path) -> Result<Self, ImportError> {
        let text = std::fs::read_to_string(path).map_err(|e| ImportError::io(path, e))?;
        let mut lines = text
            .lines()
            .map(|l| l.split('#').next().unwrap_or("").trim())
            .filter(|l| !l.is_empty());
        let header = lines
            .next()
            .ok_or_else(|| ImportError::file(path, "empty: a header row and one row per frame"))?;
        let split = |l: &str| -> Vec<String> {
            l.split([',', ';', '\t'])
                .map(|f| f.trim().trim_matches('"').to_string())
                .collect()
        };
        let names: Vec<String> = split(header)
            .iter()
            .map(|n| n.to_ascii_lowercase())
            .collect();
        for n in &names {
            if !COLUMNS.contains(&n.as_str()) {
                return Err(ImportError::field(
                    path,
                    n,
                    format!(
                        "not a column fpm knows ({}; the unit is part of the name)",
                        COLUMNS.join(", ")
                    ),
                ));
            }
        }
        if let Some(twice) = names
            .iter()
            .enumerate()
            .find(|(k, n)| names[..*k].contains(n))
        {
            return Err(ImportError::field(path, twice.1, "given twice"));
        }
        let rows: Vec<Vec<String>> = lines.map(split).collect();
        if let Some((k, r)) = rows
            .iter()
            .enumerate()
            .find(|(_, r)| r.len() != names.len())
        {
            return Err(ImportError::file(
                path,
                format!(
                    "row {}: {} fields, the header has {}",
                    k + 1,
                    r.len(),
                    names.len()
                ),
            ));
        }
        if rows.is_empty() {
            return Err(ImportError::file(path, "no rows after the header"));
        }
        Ok(Self { names, rows })
    }

    fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    fn column(&self, name: &str) -> Option<Vec<String>> {
        let i = self.index(name)?;
        Some(self.rows.iter().map(|r| r[i].clone()).collect())
    }

    /// Row `k`'s `name` as a finite number.
    fn number(&self, path: &Path, name: &str, k: usize) -> Result<f64, ImportError> {
        let i = self
            .index(name)
            .ok_or_else(|| ImportError::field(path, name, "missing"))?;
        let text = &self.rows[k][i];
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                ImportError::field(
                    path,
                    name,
                    format!("row {}: {text:?} is not a finite number", k + 1),
                )
            })
    }

    /// Each row's LED id: its `row`, `col` (0–255), or its index.
    fn ids(&self, path: &Path) -> Result<Vec<LedIndex>, ImportError> {
        match (self.index("row"), self.index("col")) {
            (Some(_), Some(_)) => (0..self.rows.len())
                .map(|k| {
                    let id = |name: &str| {
                        let v = self.number(path, name, k)?;
                        if v.fract() == 0.0 && (0.0..=255.0).contains(&v) {
                            Ok(v as u8)
                        } else {
                            Err(ImportError::field(
                                path,
                                name,
                                format!("row {}: {v} is not an id 0-255", k + 1),
                            ))
                        }
                    };
                    Ok(LedIndex::new(id("row")?, id("col")?))
                })
                .collect(),
            (None, None) => {
                if self.rows.len() > 256 * 256 {
                    return Err(ImportError::file(path, "more than 65536 rows"));
                }
                Ok((0..self.rows.len()).map(crate::frame_id).collect())
            }
            _ => Err(ImportError::field(
                path,
                if self.index("row").is_some() {
                    "col"
                } else {
                    "row"
                },
                "row and col come together (or neither)",
            )),
        }
    }
}
