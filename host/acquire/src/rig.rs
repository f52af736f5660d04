//! What every driver reads from the rig before it starts: that a camera publishes,
//! what its driver says it applied, and where the board says its LEDs are.

use anyhow::{bail, Result};
use fpm_frames::ServiceNames;
use fpm_physics::{LedGeometry, System};
use fpm_protocol::{BoardCalibration, StoredCalibration};

use crate::board_geometry;
use crate::controller::Controller;

/// How long an acquisition waits for its camera to publish before saying none does.
pub const CAMERA_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

/// Whether a camera publishes on `names`, waiting up to [`CAMERA_WAIT`] for one to come
/// up: a sequence over every LED with no camera would take minutes to fail.
pub fn wait_for_camera(names: &ServiceNames) -> Result<()> {
    let subscriber = fpm_frames::FrameSubscriber::create(names)?;
    if !subscriber.wait_for_publisher(CAMERA_WAIT) {
        bail!(
            "no camera publishes frames on {} (waited {} s): start the camera's driver (`fpm camera run`, or the virtual rig's camera) or give its name with --frames",
            names.frames,
            CAMERA_WAIT.as_secs()
        );
    }
    Ok(())
}

/// What the camera's driver says it applied, if it says (an optional extra: never an
/// error). A reported pixel pitch that disagrees with the system's is warned about.
pub fn camera_settings(camera: &ServiceNames, system: &System) -> Option<serde_json::Value> {
    let text = fpm_frames::read_settings(camera, std::time::Duration::from_millis(300))?;
    let value: serde_json::Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            tracing::warn!("the camera's settings are not JSON ({e}); left out");
            return None;
        }
    };
    tracing::info!("camera settings as applied: {value}");
    if let Some(pitch) = value.get("pixel_size_um").and_then(|v| v.as_f64()) {
        let binning = value
            .get("binning")
            .and_then(|b| b.get(0))
            .and_then(|b| b.as_f64())
            .unwrap_or(1.0);
        // A colour mosaic's channel is published one pixel per 2 × 2 cell.
        let factor = value
            .get("published_pixel_factor")
            .and_then(|f| f.as_f64())
            .unwrap_or(1.0);
        let effective = pitch * binning * factor;
        if (effective - system.pixel_size_um).abs() > 0.01 * system.pixel_size_um {
            tracing::warn!(
                "the camera reports {effective:.3} µm pixels ({pitch} µm × binning {binning} × {factor} for a colour channel), the system says {:.3} µm (--pixel-um)",
                system.pixel_size_um
            );
        }
    }
    Some(value)
}

/// The nominal array as the controller describes it.
pub fn nominal_geometry(dev: &Controller) -> LedGeometry {
    board_geometry::nominal(&dev.info().geometry)
}

/// Where the board's LEDs are: its stored calibration placing its grid, or the
/// nominal grid when it stores none.
pub fn board_geometry(dev: &Controller) -> LedGeometry {
    let nominal = nominal_geometry(dev);
    match stored_board_calibration(dev) {
        Some(c) => board_geometry::geometry(&nominal, &c),
        None => nominal,
    }
}

/// The calibration stored on the board, if any. A board that cannot say (older
/// firmware, a damaged record, a link error) has none, with a note in the log.
pub fn stored_board_calibration(dev: &Controller) -> Option<BoardCalibration> {
    match dev.stored_calibration() {
        Ok(StoredCalibration::Calibrated(c)) => Some(c),
        Ok(other) => {
            tracing::info!("the board: {}", board_geometry::describe_stored(&other));
            None
        }
        Err(e) => {
            tracing::info!("no stored geometry: {e}");
            None
        }
    }
}
