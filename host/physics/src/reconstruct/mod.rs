//! EPRY (Ou, Zheng & Yang 2014): the object spectrum and the pupil recovered together.
//!
//! * [`epry`]: the solver state and one frame's update;
//! * [`schedule`]: the pass loop and the adaptive step size;
//! * [`refine`]: each LED's illumination frequency refined inside the passes;
//! * [`refocus`]: how far out of focus the frames were taken, from their shifts;
//! * [`offline`]: one square field with every frame at hand;
//! * [`streaming`]: one square field fed frame by frame while an acquisition runs;
//! * [`tiled`]: the full field of view in tiles, offline and streaming alike;
//! * [`flatten`]: the clear background's low-order phase taken off each tile;
//! * [`contrast`]: whether the result explains its bright-field frames;
//! * [`gamma`]: the display gamma of frames saved for viewing, read from the frames.

pub mod contrast;
pub mod epry;
pub mod flatten;
pub mod gamma;
pub mod offline;
pub mod refine;
pub mod refocus;
pub mod schedule;
pub mod streaming;
pub mod tiled;

pub use contrast::{ContrastFit, ContrastSums};
pub use epry::{
    amplitude, complex_nrmse, defaults, limits, remove_illumination_curvature, Epry, Settings,
    NOISE_BAND_SIGMA,
};
pub use flatten::{flatten_background_phase, Flatten, Flattening};
pub use gamma::{GammaCandidate, GammaScan};
pub use offline::{run, run_amplitudes, Amplitudes, Field, Lit, Outcome, Shot};
pub use refine::{BoardFit, Refine, RefinedLeds};
pub use schedule::StepSchedule;
pub use streaming::Streaming;
pub use tiled::{Band, Banded, TileLayout, TileResult, TiledError, TiledOutcome, TiledStreaming};
