//! EPRY fed frame by frame as an acquisition runs. Frames may arrive in any order; each
//! updates the estimate at once (from the first bright-field frame on, which seeds the
//! object), a snapshot can be taken at any time, and [`Streaming::finish`] runs the
//! remaining passes nearest-first over every frame received, exactly as the offline
//! run does. The stream keeps no copy of the frames: the caller keeps them (it writes
//! them to the dataset anyway) and hands them back to `finish`.

use crate::optics::LedIndex;
use rustfft::num_complex::Complex32;

use super::offline::{illumination_radius_um, Amplitudes, Field, Lit, Outcome, Shot};
use super::schedule::{passes_over, PassFrame};
use super::{amplitude, Epry, Settings};
use crate::frame::{Measured, Region};
use crate::optics::{LedGeometry, System};
use crate::Image;

/// Streaming EPRY over one square field (a whole frame, or one tile of it).
pub struct Streaming {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    field: Field,
    /// Frames that arrived before the estimate could be seeded, as intensities, with
    /// their noise bands in the same units.
    waiting: Vec<(LedIndex, Image, f32)>,
    /// LEDs of the frames used so far, in arrival order.
    used: Vec<LedIndex>,
    epry: Option<Epry>,
    /// The clear level the amplitudes are normalised by, once known.
    scale: Option<f32>,
    /// Whether the stream may take the clear level from its own seed frame (a whole
    /// field); a tile waits for the level its stream shares ([`Self::set_clear_level`]).
    own_scale: bool,
}

impl Streaming {
    /// Nothing received yet; the whole frame is the field (its centre on the axis), the
    /// clear level is the first bright-field frame's mean.
    pub fn new(system: System, geometry: LedGeometry, settings: Settings) -> Self {
        Self {
            own_scale: true,
            ..Self::for_field(system, geometry, settings, Field::default())
        }
    }

    /// Nothing received yet, for `field` (a tile: its centre, its free border, and the
    /// clear level shared by all tiles; without one in `field`, the stream waits for
    /// [`Self::set_clear_level`] before it seeds).
    pub fn for_field(
        system: System,
        geometry: LedGeometry,
        settings: Settings,
        field: Field,
    ) -> Self {
        Self {
            system,
            geometry,
            settings,
            field,
            waiting: vec![],
            used: vec![],
            epry: None,
            scale: field.clear_level.filter(|l| *l > 0.0),
            own_scale: false,
        }
    }

    fn frequency(&self, led: LedIndex) -> (f64, f64) {
        let (x, y) = self.field.centre_um;
        self.geometry.pupil_frequency(led, x, y, &self.system)
    }

    fn bright_field(&self, led: LedIndex) -> bool {
        let (x, y) = self.field.centre_um;
        self.geometry.is_bright_field(led, x, y, &self.system)
    }

    /// A frame (intensity per ms) arrived. Returns whether the estimate was updated.
    pub fn push(&mut self, led: LedIndex, image: Image) -> bool {
        if self.epry.is_none() {
            self.waiting.push((led, image, 0.0));
            return self.try_seed();
        }
        let amp = amplitude(&(image / self.scale.unwrap_or(1.0)));
        self.update(led, &amp, 0.0);
        true
    }

    /// A measured frame arrived; this field is `region` of it. Returns whether the
    /// estimate was updated.
    pub fn push_measured(&mut self, led: LedIndex, frame: &Measured<'_>, region: Region) -> bool {
        match (self.epry.is_some(), self.scale) {
            (true, Some(scale)) => {
                let amp = frame.amplitude(region, scale);
                self.update(led, &amp, frame.intensity_band(scale));
                true
            }
            _ => {
                let band = frame.intensity_band(1.0);
                self.waiting.push((led, frame.intensity(region), band));
                self.try_seed()
            }
        }
    }

    /// The clear level (intensity per ms of a clear sample under the reference LED),
    /// when a tiled stream learns it from the whole frame.
    pub fn set_clear_level(&mut self, level: f32) {
        if self.epry.is_none() && level > 0.0 {
            self.scale = Some(level);
            self.try_seed();
        }
    }

    /// Seed from the first bright-field frame that arrived (its own mean is the clear
    /// level unless one was given), then replay the frames that waited.
    fn try_seed(&mut self) -> bool {
        if self.epry.is_some() {
            return false;
        }
        let Some(seed) = self
            .waiting
            .iter()
            .position(|(led, _, _)| self.bright_field(*led))
        else {
            return false;
        };
        let scale = match self.scale {
            Some(s) => s,
            None if !self.own_scale => return false,
            None => match self.waiting[seed].1.mean().filter(|m| *m > 0.0) {
                Some(m) => m,
                None => return false,
            },
        };
        self.scale = Some(scale);
        let mut epry = Epry::new(
            &self.system,
            &(&self.waiting[seed].1 / scale),
            self.settings,
        );
        epry.set_free_border(self.field.free_border);
        epry.apply_illumination_curvature(
            self.system.wavelength_um,
            illumination_radius_um(
                &self.system,
                &self.geometry,
                self.waiting[seed].0,
                self.field.centre_um,
            ),
        );
        self.epry = Some(epry);
        // Earlier (dark-field) frames first, as they arrived, then the seed and the rest.
        for (led, image, band) in std::mem::take(&mut self.waiting) {
            let amp = amplitude(&(image / scale));
            self.update(led, &amp, band / scale);
        }
        true
    }

    /// Update with a frame's amplitude and its noise band ([`Epry::update_within`]).
    fn update(&mut self, led: LedIndex, amplitude: &Image, band: f32) {
        let f = self.frequency(led);
        if let Some(e) = self.epry.as_mut() {
            e.update_within(amplitude, band, f, false);
        }
        self.used.push(led);
    }

    /// Frames received.
    pub fn received(&self) -> usize {
        self.used.len() + self.waiting.len()
    }

    /// The clear level in use (None before seeding).
    pub fn clear_level(&self) -> Option<f32> {
        self.scale.filter(|_| self.epry.is_some())
    }

    /// The object as it stands (None before the first bright-field frame).
    pub fn snapshot(&mut self) -> Option<ndarray::Array2<Complex32>> {
        self.epry.as_mut().map(Epry::object)
    }

    /// The sample as it stands, the illumination's curvature divided out (None before
    /// the first bright-field frame): what a tiled snapshot blends.
    pub fn snapshot_sample(&mut self) -> Option<ndarray::Array2<Complex32>> {
        self.epry.as_mut().map(Epry::sample)
    }

    /// Run `passes` more passes over `shots` (intensity per ms: every frame received,
    /// handed back), nearest-first, with the adaptive step size and the pupil learned
    /// from the bright-field frames, as [`super::run`] does offline.
    pub fn finish(self, shots: &[Shot<'_>], passes: usize) -> Option<Outcome> {
        let scale = self.clear_level()?;
        let leds: Vec<LedIndex> = shots.iter().map(|s| s.led).collect();
        let amplitudes: Vec<Image> = shots
            .iter()
            .map(|s| amplitude(&(s.image / scale)))
            .collect();
        let also: Vec<Vec<LedIndex>> = shots.iter().map(|s| s.also.to_vec()).collect();
        let frames = Amplitudes {
            leds: &leds,
            also: &also,
            images: &amplitudes,
            bands: &[],
        };
        self.finish_amplitudes(frames, passes, |_, _| {})
    }

    /// [`Self::finish`] on amplitudes already normalised by [`Self::clear_level`].
    pub fn finish_amplitudes(
        mut self,
        frames: Amplitudes<'_>,
        passes: usize,
        progress: impl FnMut(usize, usize),
    ) -> Option<Outcome> {
        let mut epry = self.epry.take()?;
        let Amplitudes {
            leds,
            also,
            images: amplitudes,
            bands,
        } = frames;
        let lit = Lit { leds, also };
        let order = lit.nearest_first(&self.geometry, self.field.centre_um, &self.system);
        let initial = *order.first()?;
        let others: Vec<Vec<(f64, f64)>> = (0..leds.len())
            .map(|k| lit.of(k).skip(1).map(|l| self.frequency(l)).collect())
            .collect();
        let frames: Vec<PassFrame<'_>> = order
            .iter()
            .map(|&k| PassFrame {
                amplitude: &amplitudes[k],
                band: bands.get(k).copied().unwrap_or(0.0),
                frequency: self.frequency(leds[k]),
                also: &others[k],
            })
            .collect();
        // Every frame has already updated the object once as it arrived.
        let done = passes_over(&mut epry, &self.system, &frames, passes, 0, progress);
        Some(Outcome {
            epry,
            errors: done.errors,
            initial,
            frequencies: Outcome::unordered(&order, done.frequencies),
            led_scatter: done.led_scatter,
        })
    }
}
