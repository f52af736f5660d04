//! What an acquisition did (`acquisition.json`): written by the pipeline, shown by
//! its page.

use fpm_host::calibration::GeometrySource;
use fpm_physics::LedGeometry;
use fpm_protocol::{BoardCalibration, LedIndex};
use serde::Serialize;

use crate::capture::CaptureReport;

/// What an acquisition did, also written as `acquisition.json`.
#[derive(Debug, Clone, Serialize)]
pub struct AcquireSummary {
    /// The nominal array (from the controller).
    pub nominal: LedGeometry,
    /// The geometry used for the acquisition order and the reconstruction.
    pub geometry: LedGeometry,
    /// The objective's entrance pupil distance above the sample, mm, as given (None:
    /// telecentric). dataset.toml has no key for it: a later `fpm reconstruct` of the
    /// dataset needs `--entrance-pupil-mm` again.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub entrance_pupil_mm: Option<f64>,
    /// Where it came from: acquisition.json says "calibration.json", "board" (the
    /// calibration stored on the controller) or "nominal".
    #[serde(serialize_with = "fpm_host::calibration::serialize_short")]
    pub geometry_source: GeometrySource,
    /// The calibration stored on the board, as read at the start (None: none, or the
    /// firmware predates stored geometry).
    pub board_calibration: Option<BoardCalibration>,
    /// The settings the camera reported it applied (`fpm/camera/<id>/settings`: pixel
    /// format and bit depth, region, binning, exposure, gain, trigger, pixel pitch), if
    /// its driver publishes them.
    pub camera_settings: Option<serde_json::Value>,
    /// Calibration captures.
    pub calibration: Vec<CaptureReport>,
    /// The full capture.
    pub capture: CaptureReport,
    /// The second capture of the frames the first one missed, if any.
    pub retake: Option<CaptureReport>,
    /// Frames written to the dataset.
    pub frames_in_dataset: usize,
    /// Of those, the frames an earlier run had taken (a resumed acquisition; 0 else).
    pub frames_before: usize,
    /// LEDs without a frame after the retake.
    pub still_missing: Vec<LedIndex>,
    /// Last frame → final image, ms (with reconstruction).
    pub last_frame_to_final_ms: Option<f64>,
    /// Streaming updates per frame, µs (mean over frames; all tiles).
    pub update_us_mean: Option<f64>,
    /// Tiles the streaming reconstruction used.
    pub tiles: Option<usize>,
    /// How the final image was made: "streamed" (the stream, finished), or "dataset"
    /// (the stream was not trusted: frames were relabelled after it got them).
    pub reconstruction: Option<&'static str>,
}
