//! `caltech-mat`: the MATLAB files of Caltech's FPM_software (Haowen Zhou, Caltech
//! Biophotonics Lab; github.com/hwzhou2020/FPM_software, MIT), as its loader and
//! Gerchberg–Saxton reconstruction read them:
//!
//! * `imlow`: H × W × N (rows, columns, one frame per illumination), counts.
//! * `NA_list`: N × 2, row n the illumination of frame n; column 1 along the image's
//!   columns (x), column 2 along its rows (y). The reference cuts frame n's window
//!   from the object's centred spectrum at −(2π/λ)·NA_list(n, :) (`u = -NA_list[:, 0]`),
//!   so NA_list is the light's direction sines, s = f_i·λ (docs/dataset.md §1.3), and
//!   the LED sits at −NA_list as seen from the sample: fpm's `[[led.na]]` is −NA_list.
//! * `NA` (objective), `lambda` (µm), `dpix_c` (the camera's pixel, µm), `mag`.
//!   The reference falls back to defaults for absent ones; an import refuses instead
//!   and names the option that states it.
//! * No LED distance: the reference models plane waves.

use std::path::Path;

use fpm_host::dataset::{LedNa, LedNas, LedSection};

use crate::mat::MatFile;
use crate::stack::{self, Layout};
use crate::{
    camera_for, frame_id, in_focus, system_section, Format, ImportError, Imported, Stated,
};

/// Where the LEDs are placed when the file gives no distance: far enough that the
/// light is a plane wave across any field the reference reconstructs in one piece.
pub const PLANE_WAVE_HEIGHT_MM: f64 = 1000.0;

/// Read a FPM_software `.mat` file.
pub fn read(src: &Path, stated: &Stated) -> Result<Imported, ImportError> {
    let mat = MatFile::open(src)?;
    let imlow = mat.get("imlow")?;
    let (h, w, n) = match imlow.dims.as_slice() {
        [h, w, n] => (*h, *w, *n),
        [h, w] => (*h, *w, 1),
        dims => {
            return Err(ImportError::field(
                src,
                "imlow",
                format!("dims {dims:?}: H x W x N expected"),
            ))
        }
    };
    if imlow.len() != h * w * n || n > 256 * 256 {
        return Err(ImportError::field(
            src,
            "imlow",
            format!("{} values for dims {:?}", imlow.len(), imlow.dims),
        ));
    }
    let na_list = mat.get("NA_list")?;
    if na_list.dims != [n, 2] {
        return Err(ImportError::field(
            src,
            "NA_list",
            format!(
                "dims {:?}: N x 2 expected, one row per frame of imlow ({n} frames)",
                na_list.dims
            ),
        ));
    }
    let mut assumed = vec![
        "NA_list(n, :) is the light's direction (the reference reads frame n at -2π/λ·NA_list(n, :)): each LED placed at -NA_list".to_string(),
        "NA_list column 1 along the image columns (x), column 2 along its rows (y)".to_string(),
        "frames are imlow(:, :, n) in order; LED ids (n / 256, n mod 256), n from 0".to_string(),
    ];
    let lambda = mat.scalar_opt("lambda")?;
    let dpix_c = mat.scalar_opt("dpix_c")?;
    for (name, v, rule) in [
        ("lambda", lambda, (0.1, 20.0)),
        ("dpix_c", dpix_c, (0.05, 100.0)),
    ] {
        if let Some(v) = v.filter(|v| !(rule.0..=rule.1).contains(v)) {
            return Err(ImportError::field(
                src,
                name,
                format!(
                    "{v} is not in µm as FPM_software keeps it ({}-{} µm): a file in metres or nm; state the value with the option instead",
                    rule.0, rule.1
                ),
            ));
        }
    }
    let system = system_section(
        Format::CaltechMat,
        [
            lambda,
            mat.scalar_opt("NA")?,
            mat.scalar_opt("mag")?,
            dpix_c,
        ],
        stated,
        &mut assumed,
    )?;
    let values = na_list.to_f64();
    let nas = (0..n)
        .map(|k| LedNa {
            led: frame_id(k),
            na: [-values[k], -values[n + k]],
        })
        .collect();
    let nas = LedNas::new(nas).map_err(|e| ImportError::field(src, "NA_list", e))?;
    let height_mm = stated.height_mm.unwrap_or_else(|| {
        assumed.push(format!(
            "the file gives no LED distance and the reference models plane waves: LEDs placed {PLANE_WAVE_HEIGHT_MM} mm away (state the real one with --height-mm for fields reconstructed in tiles)"
        ));
        PLANE_WAVE_HEIGHT_MM
    });
    let frames: Vec<_> = (0..n)
        .map(|k| {
            let pixels = stack::frame(&imlow.values, Layout::MatlabHwn, (h, w), k);
            (in_focus(frame_id(k)), pixels)
        })
        .collect();
    assumed.push("every frame exposed alike (imlow carries no exposure)".into());
    let camera = camera_for(frames.first().map(|f| &f.1), "imlow", stated, &mut assumed);
    Ok(Imported {
        system,
        led: LedSection {
            na: Some(nas),
            ..LedSection::listed(height_mm)
        },
        camera,
        frames,
        assumed,
    })
}
