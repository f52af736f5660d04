//! `ptylab-h5`: PtyLab's FPM files (PtyLab.py, Loetgering et al.), as its loader and
//! FPM reconstruction read them (written from that description, not from its code,
//! whose licence forbids reuse):
//!
//! * Datasets at the file's root: `ptychogram` (frames × rows × columns, counts),
//!   `encoder` (frames × 2, metres: the LED's position relative to the optical axis,
//!   column 0 along the image rows, column 1 along its columns; stored 2 × frames, it
//!   is transposed and its mean taken off, as PtyLab does), `wavelength`, `dxd` (the
//!   camera's pixel) and `zled` (LEDs to sample), all in metres, `magnification`, and
//!   optionally `NA` and `orientation` (flips of the frames: 0 none, 1 columns, 2 rows,
//!   3 both, 4 transposed).
//! * PtyLab reads frame n's band of the object's spectrum at +encoder(n)/(λ·R),
//!   R = √(encoder² + zled²): an LED at +encoder in fpm's terms (docs/dataset.md
//!   §1.3), so the positions are taken as they are, with y the rows.
//! * No background is taken off by PtyLab's loader.

use std::path::Path;

use fpm_host::dataset::{LedSection, Pixels};
use fpm_physics::{LedList, ListedLed};

use crate::h5::H5File;
use crate::mat::Values;
use crate::stack::{self, Layout};
use crate::{
    camera_for, frame_id, in_focus, system_section, Format, ImportError, Imported, Stated,
};

/// Read a PtyLab FPM HDF5 file.
pub fn read(src: &Path, stated: &Stated) -> Result<Imported, ImportError> {
    let file = H5File::open(src)?;
    let (shape, values) = file.read_numeric("ptychogram")?;
    let (n, h, w) = match shape.as_slice() {
        [n, h, w] => (*n, *h, *w),
        [h, w] => (1, *h, *w),
        _ => {
            return Err(ImportError::field(
                src,
                "ptychogram",
                format!("shape {shape:?}: frames x rows x columns expected"),
            ))
        }
    };
    if n > 256 * 256 {
        return Err(ImportError::field(
            src,
            "ptychogram",
            format!("{n} frames: at most 65536"),
        ));
    }
    let values = Values::from_h5(values);
    let (enc_shape, enc) = file.read_numeric("encoder")?;
    let enc = enc.to_f64();
    let mut assumed = vec![
        "encoder holds each LED's position (m) relative to the optical axis, column 0 along the image rows (y), column 1 along its columns (x), an LED at +encoder lighting the band PtyLab reads at +encoder/(λR)".to_string(),
        "LED ids (n / 256, n mod 256) for frame n, from 0".to_string(),
    ];
    // (y, x) per frame, metres.
    let positions: Vec<(f64, f64)> = match enc_shape.as_slice() {
        [rows, 2] if *rows == n => (0..n).map(|k| (enc[2 * k], enc[2 * k + 1])).collect(),
        [2, cols] if *cols == n => {
            let mean = |axis: usize| enc[axis * n..(axis + 1) * n].iter().sum::<f64>() / n as f64;
            let (my, mx) = (mean(0), mean(1));
            assumed.push(
                "encoder stored 2 x frames: transposed and its mean taken off, as PtyLab does"
                    .into(),
            );
            (0..n).map(|k| (enc[k] - my, enc[n + k] - mx)).collect()
        }
        _ => {
            return Err(ImportError::field(
                src,
                "encoder",
                format!(
                "shape {enc_shape:?}: frames x 2 expected, one row per frame of ptychogram ({n})"
            ),
            ))
        }
    };
    let metres = |name: &str, lo: f64, hi: f64| -> Result<f64, ImportError> {
        let v = file.scalar(name)?;
        if (lo..=hi).contains(&v) {
            Ok(v)
        } else {
            Err(ImportError::field(
                src,
                name,
                format!("{v} is not in metres as PtyLab keeps it ({lo:e}-{hi:e} m)"),
            ))
        }
    };
    let wavelength = metres("wavelength", 1e-7, 2e-5)?;
    let dxd = metres("dxd", 5e-8, 1e-4)?;
    let zled = metres("zled", 1e-3, 10.0)?;
    let na = file.scalar_opt("NA")?;
    if na.is_none() && stated.na.is_none() {
        return Err(ImportError::Needs {
            format: Format::PtylabH5.name(),
            reason: format!(
                "the file gives no `NA`: state the objective's with --na (PtyLab would guess λ/(4·pixel) = {:.3})",
                wavelength / (4.0 * dxd / file.scalar("magnification")?)
            ),
        });
    }
    let system = system_section(
        Format::PtylabH5,
        [
            Some(wavelength * 1e6),
            na,
            Some(file.scalar("magnification")?),
            Some(dxd * 1e6),
        ],
        stated,
        &mut assumed,
    )?;
    let height_mm = stated.height_mm.unwrap_or(zled * 1e3);
    let leds: Vec<ListedLed> = positions
        .iter()
        .enumerate()
        .map(|(k, &(y, x))| ListedLed {
            led: frame_id(k),
            x_mm: x * 1e3,
            y_mm: y * 1e3,
            z_mm: 0.0,
        })
        .collect();
    let list = LedList::new(leds).map_err(|e| ImportError::field(src, "encoder", e.message))?;
    let orientation = match file.scalar_opt("orientation")? {
        None => 0,
        Some(v) if v.fract() == 0.0 && (0.0..=4.0).contains(&v) => v as u8,
        Some(v) => {
            return Err(ImportError::field(
                src,
                "orientation",
                format!(
                    "{v}: fpm reads 0-4 (flips and the transpose); orient the frames and set 0"
                ),
            ))
        }
    };
    if orientation != 0 {
        assumed.push(format!(
            "orientation {orientation} applied to the frames (not to the encoder), as PtyLab does"
        ));
    }
    let frames: Vec<_> = (0..n)
        .map(|k| {
            let pixels = stack::frame(&values, Layout::NumpyNhw, (h, w), k);
            (in_focus(frame_id(k)), oriented(pixels, orientation))
        })
        .collect();
    assumed.push("every frame exposed alike (the file carries no exposure)".into());
    let camera = camera_for(
        frames.first().map(|f| &f.1),
        "ptychogram (PtyLab's loader takes nothing off)",
        stated,
        &mut assumed,
    );
    Ok(Imported {
        system,
        led: LedSection {
            position: Some(list),
            ..LedSection::listed(height_mm)
        },
        camera,
        frames,
        assumed,
    })
}

/// A frame as PtyLab's `orientation` 0–4 leaves it: 1 flips the columns, 2 the rows,
/// 3 both, 4 swaps rows and columns.
fn oriented(p: Pixels, orientation: u8) -> Pixels {
    fn turn<T: Clone>(mut a: ndarray::Array2<T>, o: u8) -> ndarray::Array2<T> {
        match o {
            1 => a.invert_axis(ndarray::Axis(1)),
            2 => a.invert_axis(ndarray::Axis(0)),
            3 => {
                a.invert_axis(ndarray::Axis(0));
                a.invert_axis(ndarray::Axis(1));
            }
            4 => a = a.reversed_axes(),
            _ => {}
        }
        a.as_standard_layout().to_owned()
    }
    match p {
        Pixels::U8(a) => Pixels::U8(turn(a, orientation)),
        Pixels::U16(a) => Pixels::U16(turn(a, orientation)),
        Pixels::F32(a) => Pixels::F32(turn(a, orientation)),
    }
}
