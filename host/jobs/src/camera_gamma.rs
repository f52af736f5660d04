//! `--camera-gamma auto`: the display gamma of a dataset's frames read from the frames
//! ([`fpm_physics::reconstruct::gamma`]), for data saved as viewable images whose
//! encoding nobody wrote down. Only the central rows of each frame are read.

use anyhow::{bail, Context, Result};
use fpm_physics::frame::LitFrame;
use fpm_physics::reconstruct::gamma::{self, GammaScan};
use fpm_physics::reconstruct::Settings;
use fpm_physics::{LedGeometry, System};
use rayon::prelude::*;

use crate::dataset::{DatasetOnDisk, Pixels};

/// Scan the in-focus frames of `ds` through `system` and `geometry` for the gamma
/// that explains them best (`progress(done, total)` counts candidates; `screened`: see
/// [`gamma::scan`]). The full scale is the dataset's bit depth, else the frames'
/// sample type's.
pub fn scan(
    ds: &DatasetOnDisk,
    system: &System,
    geometry: &LedGeometry,
    settings: Settings,
    passes: usize,
    screened: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<GammaScan> {
    let context = || format!("reading the camera gamma of {}", ds.dir.display());
    let indices = ds.in_focus();
    if indices.is_empty() {
        bail!(
            "{}: no in-focus frames (defocus_um = 0) to read a gamma from",
            ds.dir.display()
        );
    }
    let (h, w) = ds.dim();
    let side = gamma::side(system, geometry, (h, w));
    let rows = (h - side) / 2..(h - side) / 2 + side;
    let pixels: Vec<Pixels> = indices
        .par_iter()
        .map(|&k| ds.rows(k, rows.clone()))
        .collect::<Result<_, _>>()
        .with_context(context)?;
    let frames: Vec<LitFrame> = indices
        .iter()
        .zip(&pixels)
        .map(|(&k, p)| LitFrame {
            led: ds.manifest.frames[k].led,
            also: &ds.manifest.frames[k].also,
            measured: ds.measured(k, p),
        })
        .collect();
    let camera = &ds.manifest.camera;
    let full_scale = match camera.bit_depth {
        Some(bits) => crate::dataset::full_scale(bits),
        None => match gamma::full_scale_of(&frames[0].measured.counts) {
            Some(f) => f,
            None => bail!(
                "{}: the frames are floats, which no display encoding stores: --camera-gamma auto needs integer frames",
                ds.dir.display()
            ),
        },
    };
    gamma::scan(
        system,
        geometry,
        &frames,
        gamma::Stored {
            full_scale,
            dark_counts: camera.dark_level as f32,
        },
        settings,
        passes,
        screened,
        progress,
    )
    .with_context(context)
}
