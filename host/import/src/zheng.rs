//! `zheng-mat`: the MATLAB files the Zheng lab (UConn Smart Imaging Lab) publishes
//! with its FPM code (github.com/SmartImagingLabUConn/Fourier-Ptychography, 2020), as
//! `FP_recover_code.m`, `LED_location.m`, `k_vector.m` and `himrecover.m` read them:
//!
//! * `imlow_HDR`: H × W × N single, image k (1-based) under the k-th LED of a spiral
//!   out from the centre LED (`LED_location.m`: x+, y+, x−, x−, y−, y−, x+ ×3, …).
//!   `himrecover.m` puts it in place of the field's modulus: an amplitude, so a frame
//!   is its square.
//! * `xint`, `yint` (mm): the centre LED's offset from the patch's centre; `theta`
//!   (degrees): the array's turn, x1 = x0·cos θ − y0·sin θ (fpm's θ); x along the
//!   image's columns, y along its rows, and an LED at +x gives kx < 0 (fpm's sign):
//!   a grid in fpm's terms, offset R(θ)·(xint, yint).
//! * `wlength` and `z` in metres: the wavelength and the sample's known defocus.
//! * `aberration`: a pre-calibrated pupil (0 when none).
//! * Not in the file: the code's constants (15 × 15 LEDs 4 mm apart, 90.88 mm below
//!   the sample, objective NA 0.1, 1.845 µm sample pixels: a 2× objective on 3.69 µm
//!   pixels), taken as defaults a stated option replaces.

use std::path::Path;

use fpm_host::dataset::Pixels;
use fpm_host::dataset::{CameraSection, LedSection};
use fpm_physics::LedIndex;

use crate::mat::MatFile;
use crate::stack::{self, Layout};
use crate::{in_focus, system_section, Format, ImportError, Imported, Stated};

/// The reference code's array: 15 × 15 LEDs.
const ARRAY: usize = 15;
/// Its LED pitch, mm.
const PITCH_MM: f64 = 4.0;
/// Its LED height, mm.
const HEIGHT_MM: f64 = 90.88;
/// Its objective NA.
const NA: f64 = 0.1;
/// Its sample-plane pixel, µm (`spsize`), as a 2× objective on 3.69 µm pixels.
const MAGNIFICATION: f64 = 2.0;
const CAMERA_PIXEL_UM: f64 = 3.69;

/// The offsets (xi, yi) from the centre LED of the first `n` LEDs of the reference's
/// spiral: legs of 1, 1, 2, 2, 3, 3, … LEDs along +x, +y, −x, −y in turn.
pub fn spiral(n: usize) -> Vec<(i32, i32)> {
    let steps = [(1, 0), (0, 1), (-1, 0), (0, -1)];
    let mut at = (0, 0);
    let mut out = vec![at];
    let mut leg = 0;
    while out.len() < n {
        let (dx, dy) = steps[leg % 4];
        for _ in 0..leg / 2 + 1 {
            if out.len() == n {
                break;
            }
            at = (at.0 + dx, at.1 + dy);
            out.push(at);
        }
        leg += 1;
    }
    out.truncate(n);
    out
}

/// Read a Zheng lab `.mat` file.
pub fn read(src: &Path, stated: &Stated) -> Result<Imported, ImportError> {
    let mat = MatFile::open(src)?;
    let stack = mat.get("imlow_HDR")?;
    let (h, w, n) = match stack.dims.as_slice() {
        [h, w, n] => (*h, *w, *n),
        dims => {
            return Err(ImportError::field(
                src,
                "imlow_HDR",
                format!("dims {dims:?}: H x W x N expected"),
            ))
        }
    };
    if stack.len() != h * w * n {
        return Err(ImportError::field(
            src,
            "imlow_HDR",
            format!("{} values for dims {:?}", stack.len(), stack.dims),
        ));
    }
    if n > ARRAY * ARRAY {
        return Err(ImportError::field(
            src,
            "imlow_HDR",
            format!(
                "{n} images: the reference's spiral covers {} LEDs",
                ARRAY * ARRAY
            ),
        ));
    }
    let wavelength_m = mat.scalar("wlength")?;
    if !(1e-7..=2e-5).contains(&wavelength_m) {
        return Err(ImportError::field(
            src,
            "wlength",
            format!("{wavelength_m} is not a wavelength in metres, as the reference keeps it"),
        ));
    }
    let offset = [mat.scalar_opt("xint")?, mat.scalar_opt("yint")?];
    let theta_deg = mat.scalar_opt("theta")?.unwrap_or(0.0);
    let z_m = mat.scalar_opt("z")?.unwrap_or(0.0);
    let mut assumed = vec![
        "imlow_HDR is an amplitude (himrecover.m puts it in place of the field's modulus): frames are its square".to_string(),
        format!("image k under the k-th LED of LED_location.m's spiral out from the centre LED of a {ARRAY}x{ARRAY} array (LED ids [7 + yi, 7 + xi])"),
        "x along the image columns, y along its rows, an LED at +x lighting at kx < 0 (k_vector.m): as fpm's".to_string(),
        "the reference bends each angle through a 1 mm slide of n 1.52 (at most 0.0023 in NA): fpm does not".to_string(),
    ];
    let mut constant = |what: &str, v: f64, option: &str, given: Option<f64>| -> f64 {
        given.unwrap_or_else(|| {
            assumed.push(format!(
                "{what} {v} from the reference code (not in the file; {option} states another)"
            ));
            v
        })
    };
    let height_mm = constant(
        "LED height (mm)",
        HEIGHT_MM,
        "--height-mm",
        stated.height_mm,
    );
    let pitch_mm = constant("LED pitch (mm)", PITCH_MM, "--pitch-mm", stated.pitch_mm);
    let system = system_section(
        Format::ZhengMat,
        [
            Some(wavelength_m * 1e6),
            Some(constant("objective NA", NA, "--na", stated.na)),
            Some(constant(
                "magnification",
                MAGNIFICATION,
                "--magnification",
                stated.magnification,
            )),
            Some(constant(
                "camera pixel (µm)",
                CAMERA_PIXEL_UM,
                "--pixel-size-um",
                stated.pixel_size_um,
            )),
        ],
        stated,
        &mut assumed,
    )?;
    if z_m != 0.0 {
        assumed.push(format!(
            "the file's z: the sample sat {:.1} µm from focus; reconstruct with --refocus-um {:.1}",
            z_m * 1e6,
            z_m * 1e6
        ));
    }
    if mat
        .find("aberration")
        .is_some_and(|a| a.to_f64().iter().any(|&v| v != 0.0))
    {
        assumed.push("the file's pre-calibrated pupil (aberration) is left out: fpm recovers the pupil itself".into());
    }
    let (x0, y0) = (offset[0].unwrap_or(0.0), offset[1].unwrap_or(0.0));
    let (s, c) = theta_deg.to_radians().sin_cos();
    let centre = (ARRAY / 2) as i32;
    let led = LedSection {
        rows: Some(ARRAY),
        cols: Some(ARRAY),
        pitch_mm: Some(pitch_mm),
        center: Some(LedIndex::new(centre as u8, centre as u8)),
        offset_mm: [x0 * c - y0 * s, x0 * s + y0 * c],
        rotation_deg: theta_deg,
        ..LedSection::listed(height_mm)
    };
    let frames = spiral(n)
        .into_iter()
        .enumerate()
        .map(|(k, (xi, yi))| {
            let entry = in_focus(LedIndex::new((centre + yi) as u8, (centre + xi) as u8));
            let amplitude = stack::frame(&stack.values, Layout::MatlabHwn, (h, w), k);
            (entry, Pixels::F32(amplitude.to_f32().mapv(|a| a * a)))
        })
        .collect();
    assumed.push(
        "HDR frames, each exposure already folded in: every frame exposed alike, no dark level"
            .into(),
    );
    Ok(Imported {
        system,
        led,
        camera: CameraSection::default(),
        frames,
        assumed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spiral_is_the_reference_codes() {
        // LED_location.m's first twelve, as its comment spells them, and its last.
        let s = spiral(225);
        assert_eq!(
            s[..12],
            [
                (0, 0),
                (1, 0),
                (1, 1),
                (0, 1),
                (-1, 1),
                (-1, 0),
                (-1, -1),
                (0, -1),
                (1, -1),
                (2, -1),
                (2, 0),
                (2, 1)
            ]
        );
        assert_eq!(s[224], (7, -7));
        let mut all = s.clone();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), 225, "every LED of the 15 x 15 array once");
        assert!(s.iter().all(|&(x, y)| x.abs() <= 7 && y.abs() <= 7));
    }
}
