//! The calibration a board stores (protocol 1.1, `fpm/board/geometry`): made from a
//! `calibration.json`, turned back into the geometry an acquisition uses, and described
//! in words with its uncertainty and age.

use std::path::Path;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context, Result};
use fpm_host::calibration::PlacementFile;
use fpm_physics::LedGeometry;
use fpm_protocol::{BoardCalibration, PlacementSigma, StoredCalibration};

/// The array a board describes, at its nominal place (no offset, turn or tilt).
pub fn nominal(g: &fpm_protocol::BoardGeometry) -> LedGeometry {
    LedGeometry::grid(
        g.rows as usize,
        g.cols as usize,
        g.pitch_um as f64 / 1e3,
        g.height_um as f64 / 1e3,
        g.center,
    )
}

/// The calibration in `path` (a full `fpm calibrate` file or the minimal four-key
/// form), checked against the board's own grid. The date stored is the file's
/// modification time (when the calibration was written).
pub fn from_calibration_file(path: &Path, board: &LedGeometry) -> Result<BoardCalibration> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let file = PlacementFile::parse(&text).with_context(|| format!("{}", path.display()))?;
    if let Some(grid) = file.nominal {
        if !grid.same_grid(board) {
            bail!(
                "{}: computed for a {}x{} grid at {} mm pitch centred on {}, but this board is {}x{} at {} mm centred on {}: not its calibration",
                path.display(),
                grid.rows,
                grid.cols,
                grid.pitch_mm,
                grid.center,
                board.rows,
                board.cols,
                board.pitch_mm,
                board.center
            );
        }
    }
    // PlacementFile::parse has checked that the text is a JSON object.
    let json: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}", path.display()))?;
    let number = |v: Option<&serde_json::Value>, key: &str| -> Result<f32> {
        match v {
            None => Ok(0.0),
            Some(v) => v
                .as_f64()
                .filter(|x| x.is_finite() && *x >= 0.0)
                .map(|x| x as f32)
                .with_context(|| format!("{}: `{key}` = {v} is not a number ≥ 0", path.display())),
        }
    };
    let sigma = json.get("uncertainty");
    let sigma_of = |key: &str| number(sigma.and_then(|s| s.get(key)), key);
    let calibrated = std::fs::metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_secs());
    let calibration = BoardCalibration {
        dx_mm: file.placement.dx_mm as f32,
        dy_mm: file.placement.dy_mm as f32,
        theta_deg: file.placement.theta_deg as f32,
        height_mm: file.placement.height_mm as f32,
        sigma: PlacementSigma {
            dx_mm: sigma_of("dx_mm")?,
            dy_mm: sigma_of("dy_mm")?,
            theta_deg: sigma_of("theta_deg")?,
            height_mm: sigma_of("height_mm")?,
        },
        rms_residual_um: number(json.get("rms_residual_um"), "rms_residual_um")?,
        calibrated_unix_s: calibrated,
    };
    if !calibration.is_valid() {
        bail!(
            "{}: the geometry does not fit the board's record (a number too large for it?)",
            path.display()
        );
    }
    Ok(calibration)
}

/// The board's grid placed as `calibration` says.
pub fn geometry(board: &LedGeometry, calibration: &BoardCalibration) -> LedGeometry {
    board.placed(
        calibration.dx_mm as f64,
        calibration.dy_mm as f64,
        calibration.theta_deg as f64,
        calibration.height_mm as f64,
    )
}

/// One line a person reads: the numbers with their 1σ, the fit residual and the date.
pub fn describe(calibration: &BoardCalibration) -> String {
    let c = calibration;
    let s = &c.sigma;
    let when = match c.calibrated_unix_s {
        0 => "date unknown".to_string(),
        t => format!(
            "calibrated {}",
            humantime::format_rfc3339_seconds(UNIX_EPOCH + Duration::from_secs(t))
        ),
    };
    let age = SystemTime::now()
        .duration_since(UNIX_EPOCH + Duration::from_secs(c.calibrated_unix_s))
        .ok()
        .filter(|_| c.calibrated_unix_s > 0)
        .map(|d| format!(", {} days ago", d.as_secs() / 86_400))
        .unwrap_or_default();
    format!(
        "Δx {:.4} ± {:.4} mm, Δy {:.4} ± {:.4} mm, θ {:.3} ± {:.3}°, h {:.2} ± {:.2} mm; fit residual {:.2} µm; {when}{age}",
        c.dx_mm, s.dx_mm, c.dy_mm, s.dy_mm, c.theta_deg, s.theta_deg, c.height_mm, s.height_mm,
        c.rms_residual_um
    )
}

/// Words for what a board has stored.
pub fn describe_stored(stored: &StoredCalibration) -> String {
    match stored {
        StoredCalibration::NotCalibrated => "not calibrated".into(),
        StoredCalibration::Damaged => {
            "not calibrated (the stored record is damaged; store the geometry again)".into()
        }
        StoredCalibration::Calibrated(c) => describe(c),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn a_calibration_file_becomes_the_record_and_back() {
        let dir = std::env::temp_dir().join(format!("fpm-board-geometry-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let board = LedGeometry::paper();
        let full = write(
            &dir,
            "full.json",
            &format!(
                r#"{{"dx_mm": 1.25, "dy_mm": -0.5, "theta_deg": 2.0, "height_mm": 91.5,
                   "uncertainty": {{"dx_mm": 0.002, "dy_mm": 0.003, "theta_deg": 0.01, "height_mm": 0.2}},
                   "rms_residual_um": 0.6, "nominal": {}}}"#,
                serde_json::to_string(&board).unwrap()
            ),
        );
        let c = from_calibration_file(&full, &board).unwrap();
        assert_eq!(
            (c.dx_mm, c.dy_mm, c.theta_deg, c.height_mm),
            (1.25, -0.5, 2.0, 91.5)
        );
        assert_eq!(c.sigma.height_mm, 0.2);
        assert_eq!(c.rms_residual_um, 0.6);
        assert!(c.calibrated_unix_s > 1_700_000_000, "the file's date");
        let g = geometry(&board, &c);
        assert_eq!((g.dx_mm, g.height_mm), (1.25, 91.5));
        assert!(
            describe(&c).contains("h 91.50 ± 0.20 mm"),
            "{}",
            describe(&c)
        );

        // The minimal form: σ unknown (0).
        let minimal = write(
            &dir,
            "minimal.json",
            r#"{"dx_mm": 0.1, "dy_mm": 0.2, "theta_deg": 0.3, "height_mm": 90}"#,
        );
        let c = from_calibration_file(&minimal, &board).unwrap();
        assert_eq!(c.sigma, PlacementSigma::default());

        // Another board's calibration is refused, naming both grids.
        let other = LedGeometry {
            rows: 15,
            cols: 15,
            center: fpm_protocol::LedIndex::new(7, 7),
            ..board
        };
        let err = from_calibration_file(&full, &other)
            .unwrap_err()
            .to_string();
        assert!(err.contains("21x21") && err.contains("15x15"), "{err}");

        // A negative σ names its key.
        let bad = write(
            &dir,
            "bad.json",
            r#"{"dx_mm": 0.1, "dy_mm": 0.2, "theta_deg": 0.3, "height_mm": 90, "uncertainty": {"dy_mm": -1}}"#,
        );
        let err = format!("{:#}", from_calibration_file(&bad, &board).unwrap_err());
        assert!(err.contains("dy_mm"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
