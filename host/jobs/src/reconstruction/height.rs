//! The LED height read from the frames' bright/dark-field edge ([`BoundaryCheck`]),
//! taken over the dataset's when the two disagree beyond [`WEIGH_SIGMA`] and the
//! frames themselves fit it clearly better: the run is done at both heights (each
//! refocused as the run is), and the edge's is kept only where it lowers the frames'
//! error by [`EDGE_MUST_LOWER_ERROR_BY`]. Why both: the edge reads h well where the
//! pupil cuts the light sharply (simulated sets stated 8 mm off: the edge within 2 mm of
//! the truth), but soft vignetting moves it (the vendored ring-array set: 91 mm for its
//! 110, where its frames fit worse). The whole field is weighed, not a central square:
//! on the ring-array set the centre (which the vignetting spares) fit 91 mm 2 % better,
//! the whole field 1.7 % worse.

use serde::Serialize;

use super::{BoundaryCheck, Report};

/// How many σ apart the edge's h and the dataset's must be for the run to weigh them
/// on the frames (the warning alone waits for [`super::DISAGREE_SIGMA`]).
pub const WEIGH_SIGMA: f64 = 3.0;

/// The share by which the edge's height must lower the frames' error to be taken.
pub const EDGE_MUST_LOWER_ERROR_BY: f64 = 0.05;

/// The dataset's LED height and the edge's, weighed on the frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeightChoice {
    /// The dataset's height, mm.
    pub stated_mm: f64,
    /// The edge's height, mm.
    pub edge_mm: f64,
    /// The edge's 1σ with the NA's, mm.
    pub edge_sigma_mm: f64,
    /// The frames' error (mean over tiles of the relative amplitude error, last pass)
    /// reconstructed at the dataset's height.
    pub stated_error: f64,
    /// The same at the edge's height.
    pub edge_error: f64,
    /// Whether the run took the edge's height.
    pub edge_taken: bool,
}

impl HeightChoice {
    /// Weigh the run at the dataset's height (`stated`) against the run at the edge's
    /// (`at_edge`), `edge` read from the first.
    pub fn weigh(stated: &Report, at_edge: &Report, edge: &BoundaryCheck) -> Self {
        let last = |r: &Report| r.error_per_pass.last().copied().unwrap_or(f64::NAN);
        let (stated_error, edge_error) = (last(stated), last(at_edge));
        Self {
            stated_mm: stated.geometry.height_mm,
            edge_mm: at_edge.geometry.height_mm,
            edge_sigma_mm: edge.sigma_with_na_mm,
            stated_error,
            edge_error,
            edge_taken: edge_error < (1.0 - EDGE_MUST_LOWER_ERROR_BY) * stated_error,
        }
    }

    /// Whether the frames fit the dataset's height at least as well as the edge's.
    pub fn stated_fits_better(&self) -> bool {
        self.stated_error <= self.edge_error
    }
}

/// What the CLI and the report page say of it.
impl std::fmt::Display for HeightChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "weighed on the frames: their error {:.4} at the dataset's {:.2} mm, {:.4} at the edge's {:.2} mm: {}",
            self.stated_error,
            self.stated_mm,
            self.edge_error,
            self.edge_mm,
            if self.edge_taken {
                "reconstructed at the edge's"
            } else {
                "kept the dataset's"
            }
        )
    }
}

/// Whether the edge's height is far enough from the geometry's to weigh the two.
pub fn worth_weighing(edge: &BoundaryCheck) -> bool {
    edge.difference_sigma.abs() > WEIGH_SIGMA
}

/// `geometry` at the edge's height.
pub fn at_edge(
    geometry: &fpm_physics::LedGeometry,
    edge: &BoundaryCheck,
) -> fpm_physics::LedGeometry {
    fpm_physics::LedGeometry {
        height_mm: edge.estimate.height_mm,
        ..*geometry
    }
}
