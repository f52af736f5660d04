//! The tiled run fed band by band, for frames too many or too large to hold at once.

use super::*;

/// One band of a [`Banded`] run: the rows every frame must give, and its tiles (one
/// row of tiles).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Band {
    /// Frame rows `rows.start..rows.end`.
    pub rows: std::ops::Range<usize>,
    /// Its tiles' indices in the layout.
    pub tiles: Vec<usize>,
}

/// A tiled reconstruction fed band by band, for frames too many or too large to hold
/// at once (441 frames of 20 MP are 17.6 GB as 16-bit counts). What needs whole frames
/// is gathered first, one frame at a time ([`Self::observe`]: the clear level, each
/// dark-field frame's background); then each band of tile rows is solved from just
/// those rows of every frame ([`Self::solve_band`]) and blended at once, so neither
/// the frames nor the tiles' states are ever all in memory. The result equals
/// [`reconstruct`]'s bit for bit.
pub struct Banded {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    passes: usize,
    layout: TileLayout,
    leds: Vec<LedIndex>,
    /// The other LEDs of each multiplexed frame (empty: none).
    also: Vec<Vec<LedIndex>>,
    nearest: usize,
    /// How many bright-field LEDs light the frame nearest the axis (the clear level is
    /// one LED's).
    nearest_count: usize,
    /// Per frame once observed: its dark level, floor, whether the floor is soft and
    /// its noise band, after its background.
    corrections: Vec<Option<(f32, f32, bool, f32)>>,
    backgrounds: Vec<(LedIndex, FrameBackground)>,
    clear_level: Option<f32>,
    /// The clear glass in the frame nearest the axis ([`TiledOutcome::axis_clear_share`]).
    axis_clear_share: Option<f32>,
    assembly: Assembly,
    next_tile: usize,
    done: AtomicUsize,
}

impl Banded {
    /// A run over frames of `width × height`, frame `k` lit by the LEDs `lit[k]` (in
    /// the order the frames will be given; several for a multiplexed frame), cut as
    /// `tile` says ([`TileLayout::new`]).
    pub fn new(
        system: System,
        geometry: LedGeometry,
        settings: Settings,
        passes: usize,
        (height, width): (usize, usize),
        tile: Option<usize>,
        lit: Vec<Vec<LedIndex>>,
    ) -> Result<Self, TiledError> {
        if lit.iter().any(Vec::is_empty) {
            return Err(TiledError::NoFrames);
        }
        let leds: Vec<LedIndex> = lit.iter().map(|set| set[0]).collect();
        let also: Vec<Vec<LedIndex>> = lit.into_iter().map(|set| set[1..].to_vec()).collect();
        let lit = Lit {
            leds: &leds,
            also: &also,
        };
        let nearest = *lit
            .nearest_first(&geometry, (0.0, 0.0), &system)
            .first()
            .ok_or(TiledError::NoFrames)?;
        let nearest_count = lit.bright_field_count(nearest, &geometry, (0.0, 0.0), &system);
        let layout = TileLayout::new(width, height, tile, &system, &geometry);
        let assembly = Assembly::new(&system, &geometry, &layout, settings);
        Ok(Self {
            corrections: vec![None; leds.len()],
            system,
            geometry,
            settings,
            passes,
            layout,
            leds,
            also,
            nearest,
            nearest_count,
            backgrounds: vec![],
            clear_level: None,
            axis_clear_share: None,
            assembly,
            next_tile: 0,
            done: AtomicUsize::new(0),
        })
    }

    /// How the frame is cut.
    pub fn layout(&self) -> &TileLayout {
        &self.layout
    }

    /// The bands, top to bottom: one per row of tiles.
    pub fn bands(&self) -> Vec<Band> {
        let mut bands: Vec<Band> = vec![];
        for (k, t) in self.layout.tiles.iter().enumerate() {
            match bands.last_mut() {
                Some(b) if b.rows.start == t.y0 => b.tiles.push(k),
                _ => bands.push(Band {
                    rows: t.y0..t.y0 + t.size,
                    tiles: vec![k],
                }),
            }
        }
        bands
    }

    /// Frame `k` whole (in any order, each once, before any band): its size checked,
    /// its background measured, the clear level read if it is the frame nearest the
    /// axis.
    pub fn observe(&mut self, k: usize, frame: &LitFrame<'_>) -> Result<(), TiledError> {
        let expected = (self.layout.height, self.layout.width);
        if frame.measured.dim() != expected {
            return Err(TiledError::Size {
                index: k,
                led: frame.led,
                got: frame.measured.dim(),
                expected,
            });
        }
        if k == self.nearest {
            self.clear_level = Some(reference_level(k, frame)? / self.nearest_count as f32);
            self.axis_clear_share = clear_share(&frame.measured);
        }
        let (corrected, background) = correct(
            *frame,
            &self.system,
            &self.geometry,
            self.settings.background,
        );
        self.backgrounds.extend(background.map(|b| (frame.led, b)));
        if let Some(c) = self.corrections.get_mut(k) {
            *c = Some((
                corrected.measured.dark_level,
                corrected.measured.floor,
                corrected.measured.soft_floor,
                corrected.measured.band,
            ));
        }
        Ok(())
    }

    /// Solve `band` (the next in [`Self::bands`]' order) from `rows`: rows
    /// `band.rows` of every frame, in the order of the LEDs given to [`Self::new`], as
    /// measured (each frame's correction is applied here). `progress(done, total)`
    /// counts frame updates over the whole run.
    pub fn solve_band(
        &mut self,
        band: &Band,
        rows: &[LitFrame<'_>],
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<(), TiledError> {
        let clear_level = self.clear_level.ok_or(TiledError::BlackReference {
            index: self.nearest,
            led: self.leds[self.nearest],
        })?;
        let bad = |why: String| TiledError::Band {
            start: band.rows.start,
            end: band.rows.end,
            why,
        };
        if band.tiles.first() != Some(&self.next_tile) {
            return Err(bad(format!(
                "bands must come in order; tile {} is next",
                self.next_tile
            )));
        }
        if rows.len() != self.leds.len() {
            return Err(bad(format!(
                "{} frames given, the run has {}",
                rows.len(),
                self.leds.len()
            )));
        }
        let wanted = (band.rows.len(), self.layout.width);
        let mut frames = Vec::with_capacity(rows.len());
        for (index, (f, &led)) in rows.iter().zip(&self.leds).enumerate() {
            if f.led != led || self.also.get(index).is_some_and(|a| a.as_slice() != f.also) {
                return Err(bad(format!(
                    "frame {index} is lit by LEDs {:?}, the run has LED {led:?} and {:?} there",
                    f.leds().collect::<Vec<_>>(),
                    self.also.get(index)
                )));
            }
            if f.measured.dim() != wanted {
                return Err(bad(format!(
                    "frame {index} (LED {led:?}) is {:?} (rows, cols), the band {wanted:?}",
                    f.measured.dim()
                )));
            }
            let (dark_level, floor, soft_floor, band) = self.corrections[index]
                .ok_or_else(|| bad(format!("frame {index} (LED {led:?}) was not observed")))?;
            frames.push(LitFrame {
                led,
                also: f.also,
                measured: Measured {
                    dark_level,
                    floor,
                    soft_floor,
                    band,
                    ..f.measured
                },
            });
        }
        let total = self.layout.tiles.len() * self.passes * self.leds.len();
        let done = &self.done;
        let tick = |_: usize, _: usize| progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
        let job = TileJob {
            system: &self.system,
            geometry: &self.geometry,
            settings: self.settings,
            layout: &self.layout,
            leds: &self.leds,
            also: &self.also,
            clear_level,
            passes: self.passes,
            tick: &tick,
        };
        let starts = band.tiles.iter().map(|_| None).collect();
        let results = job.run(&band.tiles, starts, &frames, band.rows.start)?;
        for (&k, (result, outcome)) in band.tiles.iter().zip(results) {
            self.assembly.add(k, result, outcome);
        }
        self.next_tile = band.tiles.last().map_or(self.next_tile, |k| k + 1);
        Ok(())
    }

    /// Blend what the bands gave (every band must have been solved).
    pub fn finish(self) -> Result<TiledOutcome, TiledError> {
        if self.next_tile != self.layout.tiles.len() {
            let t = self.layout.tiles[self.next_tile];
            return Err(TiledError::Tile { x0: t.x0, y0: t.y0 });
        }
        let fixed = Fixed {
            system: &self.system,
            geometry: &self.geometry,
            settings: self.settings,
            clear_level: self.clear_level.ok_or(TiledError::NoFrames)?,
        };
        self.assembly.finish(
            fixed,
            self.layout,
            &self.leds,
            self.backgrounds,
            self.axis_clear_share,
        )
    }
}
