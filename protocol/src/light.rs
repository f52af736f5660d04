//! Lighting: colours, single LEDs, lists, on-device patterns and the current budget.

use heapless::Vec;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

use crate::limits::MAX_LEDS_PER_LIST;
use crate::LedIndex;

/// An RGB colour, 0–255 per channel, before global brightness.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Rgb {
    /// Red.
    pub r: u8,
    /// Green.
    pub g: u8,
    /// Blue.
    pub b: u8,
}

impl Rgb {
    /// All channels off.
    pub const OFF: Rgb = Rgb::new(0, 0, 0);
    /// All channels full.
    pub const WHITE: Rgb = Rgb::new(255, 255, 255);

    /// A colour from its channels.
    pub const fn new(r: u8, g: u8, b: u8) -> Self {
        Self { r, g, b }
    }

    /// Whether every channel is zero.
    pub const fn is_off(&self) -> bool {
        self.r == 0 && self.g == 0 && self.b == 0
    }
}

/// Request of [`crate::SetLedEndpoint`]: light one LED, everything else off.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetLed {
    /// The LED.
    pub led: LedIndex,
    /// Its colour.
    pub color: Rgb,
}

/// Request of [`crate::SetLedsEndpoint`]: light a list of LEDs in one colour.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SetLeds {
    /// The LEDs (duplicates allowed, lit once).
    pub leds: Vec<LedIndex, MAX_LEDS_PER_LIST>,
    /// Their colour.
    pub color: Rgb,
    /// `true`: add to what is lit; `false`: everything else off.
    pub keep_others: bool,
}

/// One half of the bright-field disc, for differential phase contrast.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Half {
    /// Rows above the centre LED (q < 0).
    Top,
    /// Rows below the centre LED (q > 0).
    Bottom,
    /// Columns left of the centre LED (p < 0).
    Left,
    /// Columns right of the centre LED (p > 0).
    Right,
}

/// A pattern the device computes from its geometry. An LED's illumination NA is
/// ρ/√(ρ² + h²), with ρ its distance from the centre LED and h the board's height.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Pattern {
    /// Every LED with NA ≤ `na` (the objective's NA gives the bright-field disc).
    BrightField {
        /// Outer NA, in (0, 1].
        na: f32,
    },
    /// Every LED with NA > `na`.
    DarkField {
        /// Inner NA, in (0, 1].
        na: f32,
    },
    /// Every LED with `inner` < NA ≤ `outer`.
    Annulus {
        /// Inner NA, in [0, 1).
        inner: f32,
        /// Outer NA, in (inner, 1].
        outer: f32,
    },
    /// The LEDs of the bright-field disc (NA ≤ `na`) strictly on one side of the centre.
    HalfCircle {
        /// Outer NA, in (0, 1].
        na: f32,
        /// Which half.
        half: Half,
    },
    /// Every LED on the board.
    All,
}

/// Request of [`crate::PatternEndpoint`].
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PatternRequest {
    /// The pattern.
    pub pattern: Pattern,
    /// Colour of every LED in it.
    pub color: Rgb,
}

/// What the device does with a request that would draw more than its budget.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BudgetPolicy {
    /// Refuse it with [`crate::DeviceError::OverBudget`]; nothing changes.
    Refuse,
    /// Light it with the global brightness lowered just enough to fit; the reply says
    /// so. Capture sequences always refuse, so frames stay comparable.
    Scale,
}

/// The current budget: the most channel current the LEDs may draw together.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BudgetConfig {
    /// Limit in mA; never above [`crate::Limits::max_current_ma`].
    pub limit_ma: u32,
    /// What happens above it.
    pub policy: BudgetPolicy,
}

/// Reply of every lighting request: what is lit now.
#[derive(Serialize, Deserialize, Schema, Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Lit {
    /// LEDs lit.
    pub leds_on: u16,
    /// Channel current drawn, mA (rounded up).
    pub current_ma: u32,
    /// Brightness in force for this state (lower than requested when scaled).
    pub brightness: u8,
    /// Whether the budget forced the brightness down.
    pub scaled: bool,
    /// Device time at which the new state is fully latched into the LEDs, µs.
    pub latched_us: u64,
}
