//! The virtual stage: publishes where it was told to go on the rig (`fpm-rig-bus`),
//! where the virtual camera reads it before each exposure (and adds the stage's hidden
//! error). It is the rig's focus stage ([`fpm_acquire::FocusStage`]) and its XYZ stage
//! ([`fpm_stage::Stage`]: X and Y move over the slide, Z is the defocus, −Z toward the
//! LEDs).

use std::time::Duration;

use anyhow::Result;
use fpm_acquire::{FocusStage, Slide, StagePosition};
use fpm_rig_bus::{Stage, StageControl};
use fpm_stage::{Limits, Position, StageError, StageInfo, Target};

/// The rig's motorised stage.
pub struct VirtualStage {
    control: StageControl,
    rig: String,
    state: Stage,
    /// Where the sample's focus is, as a defocus on the bus (0 until a scan refocuses).
    sample_focus_um: f64,
}

/// A real motor needs time to settle; the camera reads the stage before its next
/// exposure.
const SETTLE: Duration = Duration::from_millis(100);

impl VirtualStage {
    /// The stage of rig `rig`.
    pub fn open(rig: &str) -> Result<Self> {
        Ok(Self {
            control: StageControl::create(rig)?,
            rig: rig.into(),
            state: Stage::default(),
            sample_focus_um: 0.0,
        })
    }

    fn publish(&mut self) -> Result<(), StageError> {
        self.control
            .set(self.state)
            .map_err(|e| StageError::Disconnected {
                port: format!("virtual rig {}", self.rig),
                during: "publishing the stage position".into(),
                reason: e.to_string(),
            })?;
        std::thread::sleep(SETTLE);
        Ok(())
    }

    fn here(&self) -> Position {
        Position {
            x_um: self.state.x_um,
            y_um: self.state.y_um,
            z_um: -self.state.defocus_um,
        }
    }
}

impl FocusStage for VirtualStage {
    fn move_to(&mut self, to: StagePosition) -> Result<()> {
        (self.state.defocus_um, self.state.slide) = match to.slide {
            Slide::Sample => (to.defocus_um + self.sample_focus_um, Stage::SAMPLE),
            Slide::CalibrationTarget => (to.defocus_um, Stage::CALIBRATION_TARGET),
        };
        self.publish()?;
        Ok(())
    }

    fn refocus_sample(&mut self, defocus_um: f64) -> Result<()> {
        self.sample_focus_um -= defocus_um;
        Ok(())
    }

    fn as_scan_stage(&mut self) -> Option<&mut dyn fpm_acquire::scan::ScanStage> {
        Some(self)
    }
}

impl fpm_stage::Stage for VirtualStage {
    fn info(&self) -> StageInfo {
        StageInfo {
            firmware: "virtual stage".into(),
            port: format!("virtual rig {}", self.rig),
            can_home: true,
            limits: Limits::default(),
        }
    }

    fn position(&mut self) -> Result<Position, StageError> {
        Ok(self.here())
    }

    fn move_to(&mut self, target: Target) -> Result<Position, StageError> {
        let here = self.here();
        self.state.x_um = target.x_um.unwrap_or(here.x_um);
        self.state.y_um = target.y_um.unwrap_or(here.y_um);
        self.state.defocus_um = -target.z_um.unwrap_or(here.z_um);
        self.publish()?;
        Ok(self.here())
    }

    fn home(&mut self) -> Result<Position, StageError> {
        self.state.x_um = 0.0;
        self.state.y_um = 0.0;
        self.state.defocus_um = 0.0;
        self.publish()?;
        Ok(self.here())
    }
}
