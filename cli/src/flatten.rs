//! `--flatten-background` and `--background-block-um`, shared by `fpm reconstruct` and
//! `fpm acquire`.

use clap::Args;
use fpm_physics::reconstruct::Flatten;

use crate::units::positive_um;

/// Whether the clear background's low-order phase is taken off.
#[derive(Args, Debug, Clone, Copy, Default)]
pub struct FlattenArgs {
    /// Take the clear background's low-order phase off (for samples on clear glass:
    /// cells, smears, targets, sections with glass between). EPRY leaves the slowest
    /// phase modes (offset, ramps, bowls, astigmatism over tens of µm) wherever the
    /// field's edges push it; here they are fitted, block by block, to the pixels at
    /// the clear amplitude (objects clipped out) and divided out. Not for samples
    /// without clear glass (confluent cells, tissue filling the field): their own slow
    /// phase would go with it. report.json says what was taken off.
    #[arg(long)]
    pub flatten_background: bool,
    /// With --flatten-background: the block side, µm. Default: three periods of the
    /// LED spacing in frequency (52 µm for a 2.5 mm pitch at 92 mm, λ 0.47 µm).
    #[arg(long, requires = "flatten_background", value_parser = positive_um)]
    pub background_block_um: Option<f64>,
}

impl FlattenArgs {
    /// The settings' value.
    pub fn flatten(&self) -> Flatten {
        match (self.flatten_background, self.background_block_um) {
            (false, _) => Flatten::Keep,
            (true, Some(um)) => Flatten::BlockUm(um),
            (true, None) => Flatten::Auto,
        }
    }
}
