//! What `--refine-leds` found, for `report.json`, and the board fitted to it as a
//! placement file that `fpm reconstruct --calibration` reads back.

use std::path::Path;

use anyhow::{Context, Result};
use fpm_physics::reconstruct::RefinedLeds;
use fpm_physics::{LedGeometry, LedIndex, Placement};
use serde::Serialize;

/// The placement file written beside the report when the refined LEDs fit a board.
pub const BOARD_FILE: &str = "refined-board.json";

/// `refined_leds` in `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct RefinedLedsReport {
    /// How to read the positions.
    pub note: &'static str,
    /// RMS distance the refinement moved the LEDs from the geometry's places, mm.
    pub moved_rms_mm: f64,
    /// How far an LED on the axis moves per frequency bin of the tiles, mm: the
    /// positions come out to ~0.4 of it.
    pub bin_mm: f64,
    /// How far the data put the LEDs off the fitted board model, mm (τ, 1σ per axis):
    /// each LED's own move was shrunk by τ²/(τ² + its σ²), so LEDs of a well-built
    /// board and dim frames stay on the model. Perfect simulated boards read 0.12–0.15
    /// mm (the model's own error, which the moves also absorb); boards whose LEDs were
    /// off by 0.25 mm read 0.23–0.27; with dim, soft-floored dark field every board
    /// read 0.23–0.33 (the moves then carry the model's error: docs/results.md).
    pub led_scatter_mm: Option<f64>,
    /// Per LED.
    pub leds: Vec<RefinedLed>,
    /// The rigid, tilted board fitted to them (None when the fit failed).
    pub board: Option<BoardReport>,
    /// Against the simulation's truth, when the dataset has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus_truth: Option<LedPositionScore>,
}

/// One LED's place before and after.
#[derive(Debug, Clone, Serialize)]
pub struct RefinedLed {
    /// The LED.
    pub led: LedIndex,
    /// Where the geometry put it (x, y), mm, sample coordinates.
    pub given_mm: [f64; 2],
    /// Where the data put it, mm.
    pub refined_mm: [f64; 2],
    /// How far apart, mm.
    pub moved_mm: f64,
}

/// The board fitted to the refined positions, with its 1σ.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct BoardReport {
    /// The fitted values.
    #[serde(flatten)]
    pub value: Placement,
    /// 1σ of each, same names and units.
    pub uncertainty: Placement,
    /// RMS distance of the refined positions from the fitted board's, mm: LEDs off
    /// their grid, or the refinement's own noise.
    pub residual_rms_mm: f64,
}

impl BoardReport {
    /// One line for people: each number with its 1σ, then the residual.
    pub fn summary(&self) -> String {
        let (b, u) = (&self.value, &self.uncertainty);
        format!(
            "Δx {:.3} ± {:.3} mm, Δy {:.3} ± {:.3} mm, θ {:.3} ± {:.3}°, h {:.2} ± {:.2} mm, tilt {:.2} ± {:.2}° / {:.2} ± {:.2}°; LEDs off it by {:.3} mm RMS",
            b.dx_mm, u.dx_mm, b.dy_mm, u.dy_mm, b.theta_deg, u.theta_deg, b.height_mm,
            u.height_mm, b.tilt_x_deg, u.tilt_x_deg, b.tilt_y_deg, u.tilt_y_deg,
            self.residual_rms_mm
        )
    }
}

const NOTE: &str = "each LED placed where its refined illumination frequency points, at the height the geometry gives it (a direction cannot tell a lower LED from a nearer one); bright-field LEDs are pinned only by the pupil's edge and are less certain than dark-field ones";

impl RefinedLedsReport {
    /// The report of `refined`.
    pub fn new(refined: &RefinedLeds) -> Self {
        let leds = refined
            .leds
            .iter()
            .zip(&refined.given_mm)
            .zip(&refined.refined_mm)
            .map(|((&led, g), r)| RefinedLed {
                led,
                given_mm: [g.0, g.1],
                refined_mm: [r.0, r.1],
                moved_mm: (r.0 - g.0).hypot(r.1 - g.1),
            })
            .collect();
        let board = refined.board.map(|b| {
            let g = b.geometry;
            BoardReport {
                value: g.placement(),
                uncertainty: Placement::from_array(b.sigma),
                residual_rms_mm: b.residual_rms_mm,
            }
        });
        Self {
            note: NOTE,
            moved_rms_mm: refined.moved_rms_mm(),
            bin_mm: refined.bin_mm,
            led_scatter_mm: refined.scatter_mm,
            leds,
            board,
            versus_truth: None,
        }
    }
}

/// Above this many mm per bin, refined positions are too coarse to place single LEDs
/// (0.44 mm RMS from 64-px tiles at 1.1 mm per bin, worse than the 0.37 mm the
/// test board's LEDs were off), and the board fitted to them missed a 1° tilt.
pub const COARSE_BIN_MM: f64 = 0.8;

/// What a user must know before trusting refined positions.
pub fn warnings(r: &RefinedLedsReport) -> Vec<String> {
    let mut out = vec![];
    if r.bin_mm > COARSE_BIN_MM {
        out.push(format!(
            "the LED positions were refined in tiles where one frequency bin is {:.2} mm of LED travel: single positions and the fitted board are coarse (larger tiles, --tile, place them finer); the refinement still helps the image",
            r.bin_mm
        ));
    }
    out
}

/// The fitted board as a placement file (docs/dataset.md, "calibration.json": the
/// four keys, the tilts, the grid) for `fpm reconstruct --calibration`.
#[derive(Serialize)]
struct BoardFile<'a> {
    source: &'static str,
    #[serde(flatten)]
    board: &'a BoardReport,
    nominal: LedGeometry,
}

/// Write `board` (fitted on `grid`) into `dir`/[`BOARD_FILE`].
pub fn write_board(board: &BoardReport, grid: &LedGeometry, dir: &Path) -> Result<()> {
    let path = dir.join(BOARD_FILE);
    let file = BoardFile {
        source: "fpm reconstruct --refine-leds: a rigid, tilted board fitted to the refined LED positions",
        board,
        nominal: *grid,
    };
    std::fs::write(&path, serde_json::to_string_pretty(&file)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// How far the LED positions of a reconstruction are from a simulation's truth
/// (scored by the truth module): RMS over the
/// LEDs, mm, of the geometry's places and of the refined ones.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LedPositionScore {
    /// The geometry's places.
    pub given_rms_mm: f64,
    /// The refined places.
    pub refined_rms_mm: f64,
}
