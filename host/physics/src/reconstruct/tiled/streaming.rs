//! The tiled run updated as frames arrive.

use super::*;

/// Streaming EPRY over the full field: one [`Streaming`] per tile of the same
/// [`TileLayout`] an offline run uses, so frames of any size (a 20 MP sensor, a
/// non-square one) stream. The clear level comes from the first frame that is
/// bright-field on the axis (in a nearest-first acquisition, the axial LED's).
pub struct TiledStreaming {
    system: System,
    geometry: LedGeometry,
    settings: Settings,
    layout: TileLayout,
    tiles: Vec<Streaming>,
    clear_level: Option<f32>,
}

impl TiledStreaming {
    /// Nothing received yet, for `width × height` frames cut as `tile` says.
    pub fn new(
        system: System,
        geometry: LedGeometry,
        settings: Settings,
        width: usize,
        height: usize,
        tile: Option<usize>,
    ) -> Self {
        let layout = TileLayout::new(width, height, tile, &system, &geometry);
        let pixel_um = system.sample_pixel_um();
        let tiles = (0..layout.tiles.len())
            .map(|k| {
                Streaming::for_field(system, geometry, settings, layout.field(k, pixel_um, None))
            })
            .collect();
        Self {
            system,
            geometry,
            settings,
            layout,
            tiles,
            clear_level: None,
        }
    }

    /// How the frame is cut.
    pub fn layout(&self) -> &TileLayout {
        &self.layout
    }

    /// A frame arrived: every tile is updated with its share (or keeps it until it can
    /// be seeded). A frame of the wrong size is refused.
    pub fn push(&mut self, frame: &LitFrame<'_>) -> Result<(), TiledError> {
        let expected = (self.layout.height, self.layout.width);
        if frame.measured.dim() != expected {
            return Err(TiledError::Size {
                index: self.received(),
                led: frame.led,
                got: frame.measured.dim(),
                expected,
            });
        }
        if self.clear_level.is_none()
            && self
                .geometry
                .is_bright_field(frame.led, 0.0, 0.0, &self.system)
        {
            let level = frame.measured.mean_intensity();
            if level > 0.0 {
                self.clear_level = Some(level);
                for t in &mut self.tiles {
                    t.set_clear_level(level);
                }
            }
        }
        let (frame, _) = correct(
            *frame,
            &self.system,
            &self.geometry,
            self.settings.background,
        );
        for (t, tile) in self.tiles.iter_mut().zip(&self.layout.tiles) {
            t.push_measured(frame.led, &frame.measured, Region::from(*tile));
        }
        Ok(())
    }

    /// Frames received.
    pub fn received(&self) -> usize {
        self.tiles.first().map_or(0, Streaming::received)
    }

    /// The sample as it stands, blended over the tiles as the finish blends them (None
    /// until every tile has been seeded).
    pub fn snapshot(&mut self) -> Option<Array2<Complex32>> {
        let mut mosaic = Mosaic::new(
            self.layout.width,
            self.layout.height,
            self.settings.upsample.max(1),
            self.layout.overlap,
            self.layout.unblended,
        );
        let flatten = flatten_block(&self.system, &self.geometry, self.settings);
        for (t, tile) in self.tiles.iter_mut().zip(&self.layout.tiles) {
            let mut sample = t.snapshot_sample()?;
            if let Some(block) = flatten {
                flatten_background_phase(&mut sample, block);
            }
            mosaic.add(tile, &sample);
        }
        Some(mosaic.finish())
    }

    /// Run `passes` more passes over `frames` (every frame received, handed back) in
    /// each tile, and blend: the same finish as an offline run.
    pub fn finish(
        self,
        frames: &[LitFrame<'_>],
        passes: usize,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<TiledOutcome, TiledError> {
        check_sizes(frames)?;
        let level = self.clear_level.ok_or(TiledError::NoFrames)?;
        if let Some(k) = self.tiles.iter().position(|t| t.clear_level().is_none()) {
            let t = self.layout.tiles[k];
            return Err(TiledError::Tile { x0: t.x0, y0: t.y0 });
        }
        let starts = self.tiles.into_iter().map(Some).collect();
        let fixed = Fixed {
            system: &self.system,
            geometry: &self.geometry,
            settings: self.settings,
            clear_level: level,
        };
        solve(fixed, frames, passes, self.layout, starts, progress)
    }
}
