//! `fpm virtual-camera`: the virtual rig's camera ([`fpm_rig::camera`]).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use crate::units::positive_mm;

/// Run a simulated camera on a virtual rig.
#[derive(Args, Debug, Clone)]
pub struct VirtualCameraArgs {
    /// The virtual rig to watch (`fpm emulator --rig NAME`).
    #[arg(long)]
    pub rig: String,
    /// Publish frames as this camera (`fpm/camera/<NAME>/frames`).
    #[arg(long, default_value = "0")]
    pub camera: String,
    /// Sensor width, pixels (and height, unless `--height` is given).
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Sensor height, pixels, for a non-square sensor (the scene is rendered on a
    /// square field and the sensor's rows are cut from its middle, optical axis kept at
    /// (width/2, height/2)).
    #[arg(long)]
    pub height: Option<usize>,
    /// Seed of the hidden geometry, the sample and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Hidden array offset Δx, mm (default: random up to ±2 mm by seed).
    #[arg(long, allow_hyphen_values = true)]
    pub dx_mm: Option<f64>,
    /// Hidden Δy, mm.
    #[arg(long, allow_hyphen_values = true)]
    pub dy_mm: Option<f64>,
    /// Hidden rotation, degrees (default: random up to ±5° by seed).
    #[arg(long, allow_hyphen_values = true)]
    pub theta_deg: Option<f64>,
    /// Hidden LED-to-sample distance, mm (default: random 87–97 mm by seed).
    #[arg(long)]
    pub height_mm: Option<f64>,
    /// Image through an objective that is not telecentric, its entrance pupil this
    /// many mm above the focal plane (a camera lens, a simple low-power objective):
    /// each point sees the pupil centred on its own chief ray. Hidden like the array:
    /// only truth.json states it.
    #[arg(long, value_parser = positive_mm)]
    pub entrance_pupil_mm: Option<f64>,
    /// Write the hidden truth here once listening (truth.json, virtual-camera.json,
    /// truth_amplitude.tif, truth_phase.tif), for scoring; truth.json appears last.
    #[arg(long)]
    pub truth_dir: Option<PathBuf>,
    /// A slide this wide (µm, square) instead of one field's sample: each exposure
    /// shows the part of it under the stage's X, Y (`fpm scan`), the stage off by its
    /// hidden error and the slide's surface tilted; the slide's truth, and where each
    /// field really was, go to --truth-dir.
    #[arg(long)]
    pub slide_um: Option<f64>,
    /// With --slide-um: the stage misses each commanded position by up to this much,
    /// µm (repeatably: a position error of the lead screws).
    #[arg(long, default_value_t = 20.0)]
    pub stage_error_um: f64,
    /// With --slide-um: the slide's tilt, µm of height per mm (direction random; the
    /// focus a scan must follow).
    #[arg(long, default_value_t = 3.0)]
    pub slide_tilt_um_per_mm: f64,
    /// Encode the frames for display with this gamma (e.g. 2.2), as a camera with
    /// its Gamma feature on (at 1/2.2) does; the camera reports it with its
    /// settings, as `fpm camera run` reports a GenICam camera's, and the acquisition
    /// states it in the dataset.
    #[arg(long, value_parser = display_gamma)]
    pub display_gamma: Option<f64>,
    /// Sensor readout time added after each exposure, ms.
    #[arg(long, default_value_t = 5.0)]
    pub readout_ms: f64,
    /// Fault injection: never publish the frame with this number (repeatable).
    #[arg(long)]
    pub drop_frame: Vec<u64>,
    /// Fault injection: deliver every frame this much later, ms (a slow driver).
    #[arg(long, default_value_t = 0.0)]
    pub late_ms: f64,
    /// The camera's own clock: this many seconds ahead of the controller's (a real
    /// camera counts from its own power-up).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub clock_offset_s: f64,
    /// The camera's clock runs this many ppm fast (negative: slow).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub clock_drift_ppm: f64,
    /// Random jitter of each frame's stamp, ms (uniform, this wide).
    #[arg(long, default_value_t = 0.0)]
    pub clock_jitter_ms: f64,
}

/// A display gamma a dataset can state: above 0, at most 5.
fn display_gamma(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(g) if fpm_host::dataset::CameraSection::is_valid_gamma(g) => Ok(g),
        _ => Err(format!("{text}: a gamma above 0 and at most 5 (e.g. 2.2)")),
    }
}

/// Run it.
pub fn run(a: VirtualCameraArgs) -> Result<()> {
    fpm_rig::camera::run(fpm_rig::camera::VirtualCamera {
        rig: a.rig,
        camera: a.camera,
        size: a.size,
        height: a.height,
        seed: a.seed,
        dx_mm: a.dx_mm,
        dy_mm: a.dy_mm,
        theta_deg: a.theta_deg,
        height_mm: a.height_mm,
        entrance_pupil_mm: a.entrance_pupil_mm,
        truth_dir: a.truth_dir,
        slide_um: a.slide_um,
        stage_error_um: a.stage_error_um,
        slide_tilt_um_per_mm: a.slide_tilt_um_per_mm,
        display_gamma: a.display_gamma,
        readout_ms: a.readout_ms,
        drop_frame: a.drop_frame,
        late_ms: a.late_ms,
        clock_offset_s: a.clock_offset_s,
        clock_drift_ppm: a.clock_drift_ppm,
        clock_jitter_ms: a.clock_jitter_ms,
    })
}
