//! The virtual focus stage: an [`fpm_acquire::FocusStage`] that publishes its position
//! on the rig (`fpm-rig-bus`), where the virtual camera reads it before each exposure.

use std::time::Duration;

use anyhow::Result;
use fpm_acquire::{FocusStage, Slide, StagePosition};
use fpm_rig_bus::{Stage, StageControl};

/// The rig's motorised stage.
pub struct VirtualStage {
    control: StageControl,
}

impl VirtualStage {
    /// The stage of rig `rig`.
    pub fn open(rig: &str) -> Result<Self> {
        Ok(Self {
            control: StageControl::create(rig)?,
        })
    }
}

impl FocusStage for VirtualStage {
    fn move_to(&mut self, to: StagePosition) -> Result<()> {
        self.control.set(Stage {
            defocus_um: to.defocus_um,
            slide: match to.slide {
                Slide::Sample => Stage::SAMPLE,
                Slide::CalibrationTarget => Stage::CALIBRATION_TARGET,
            },
            ..Stage::default()
        })?;
        // The stage service keeps its last value: the camera reads it before its next
        // exposure. A real motor needs time to settle too.
        std::thread::sleep(Duration::from_millis(100));
        Ok(())
    }
}
