//! OME-Zarr (NGFF 0.4 on Zarr v2) of a reconstruction: amplitude and phase as two
//! channels of one image, a multiscale pyramid (each level half the last, down to one
//! chunk), chunked and zlib-compressed, with the pixel size in µm: what napari and
//! the `zarr` package open, and what a gigapixel mosaic needs to be browsed.
//!
//! Written by hand (JSON beside zlib-compressed raw chunks), not with `zarrs`: what is
//! written is three small JSON documents and one file per chunk, about 150 lines here,
//! where `zarrs` would bring its store, codec and array-subset machinery (and their
//! dependency tree) to every build of fpm-host for the same bytes. Its output is checked
//! by the readers that matter in the Python tests: the `zarr` package, and ome-zarr-py's
//! Reader (what napari's OME-Zarr plugin builds its layers from).

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use ndarray::{Array2, ArrayView2};
use rustfft::num_complex::Complex32;
use serde_json::json;

use crate::pyramid::halve;

/// Chunk side, pixels: a 256² float32 chunk is 256 KiB before compression.
pub const CHUNK: usize = 256;

/// One channel of one level as Zarr v2 chunks under `level_dir/<c>/<y>/<x>` (edge
/// chunks padded with NaN, as the `.zarray` fill value says).
fn write_chunks(level_dir: &Path, channel: usize, image: ArrayView2<'_, f32>) -> Result<()> {
    let (h, w) = image.dim();
    for cy in 0..h.div_ceil(CHUNK) {
        let dir = level_dir.join(channel.to_string()).join(cy.to_string());
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for cx in 0..w.div_ceil(CHUNK) {
            let mut raw = Vec::with_capacity(CHUNK * CHUNK * 4);
            for r in cy * CHUNK..(cy + 1) * CHUNK {
                for c in cx * CHUNK..(cx + 1) * CHUNK {
                    let v = if r < h && c < w {
                        image[[r, c]]
                    } else {
                        f32::NAN
                    };
                    raw.extend_from_slice(&v.to_le_bytes());
                }
            }
            let path = dir.join(cx.to_string());
            let file = std::fs::File::create(&path)
                .with_context(|| format!("creating {}", path.display()))?;
            let mut z = flate2::write::ZlibEncoder::new(file, flate2::Compression::new(5));
            z.write_all(&raw)
                .and_then(|_| z.finish().map(drop))
                .with_context(|| format!("writing {}", path.display()))?;
        }
    }
    Ok(())
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// The 0.5 % and 99.5 % points of `image` (the display window napari starts with).
fn window(image: ArrayView2<'_, f32>) -> (f32, f32) {
    let mut v: Vec<f32> = image.iter().copied().filter(|x| x.is_finite()).collect();
    match fpm_physics::stats::quantiles(&mut v, [0.005, 0.995]) {
        Some([lo, hi]) => (lo, hi),
        None => (0.0, 1.0),
    }
}

/// Write `object` (sampled at `pixel_um`) as the OME-Zarr group `dir`: channel 0 the
/// amplitude, channel 1 the phase (radians), levels `0`, `1`, … each half the last.
pub fn write(dir: &Path, object: &Array2<Complex32>, pixel_um: f64) -> Result<()> {
    write_objects(dir, &[("", object)], pixel_um)
}

/// Write several complex images of one field (a colour reconstruction's channels,
/// each named) as one OME-Zarr group: the amplitudes first (channels 0…k−1, labelled
/// `amplitude <name>`), then the phases (k…2k−1); one name `""` gives plain
/// `amplitude` and `phase`, as [`write`].
pub fn write_objects(
    dir: &Path,
    objects: &[(&str, &Array2<Complex32>)],
    pixel_um: f64,
) -> Result<()> {
    write_placed(dir, objects, pixel_um, (0.0, 0.0))
}

/// [`write_objects`] with the first pixel at `origin_um` (x, y) in the sample's (or
/// the slide's) coordinates: a translation after each level's scale, as NGFF 0.4 has
/// it, so that viewers put a mosaic where the stage had it.
pub fn write_placed(
    dir: &Path,
    objects: &[(&str, &Array2<Complex32>)],
    pixel_um: f64,
    origin_um: (f64, f64),
) -> Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("replacing {}", dir.display()))?;
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let k = objects.len();
    let mut levels: Vec<(Array2<f32>, Array2<Complex32>)> = objects
        .iter()
        .map(|(_, o)| (o.mapv(|z| z.norm()), (*o).clone()))
        .collect();
    let mut datasets = vec![];
    // Display windows of the full-size level: the amplitudes', then the phases'.
    let mut windows = vec![(0.0, 1.0); 2 * k];
    for level in 0.. {
        let (h, w) = levels.first().map_or((0, 0), |l| l.1.dim());
        let level_dir = dir.join(level.to_string());
        for (i, (amplitude, complex)) in levels.iter().enumerate() {
            let phase = complex.mapv(|z| z.arg());
            if level == 0 {
                windows[i] = window(amplitude.view());
                windows[k + i] = window(phase.view());
            }
            write_chunks(&level_dir, i, amplitude.view())?;
            write_chunks(&level_dir, k + i, phase.view())?;
        }
        write_json(
            &level_dir.join(".zarray"),
            &json!({
                "zarr_format": 2,
                "shape": [2 * k, h, w],
                "chunks": [1, CHUNK, CHUNK],
                "dtype": "<f4",
                "compressor": {"id": "zlib", "level": 5},
                "fill_value": "NaN",
                "order": "C",
                "filters": null,
                "dimension_separator": "/",
            }),
        )?;
        let scale = pixel_um * (1u64 << level) as f64;
        // A level's pixel k covers 2^level pixels of level 0: its centre sits half of
        // that (less half a pixel) further on.
        let half = 0.5 * (scale - pixel_um);
        let mut transforms = vec![json!({"type": "scale", "scale": [1.0, scale, scale]})];
        if origin_um != (0.0, 0.0) {
            transforms.push(json!({"type": "translation", "translation": [0.0, origin_um.1 + half, origin_um.0 + half]}));
        }
        datasets.push(json!({
            "path": level.to_string(),
            "coordinateTransformations": transforms,
        }));
        if h.max(w) <= CHUNK || h < 2 || w < 2 {
            break;
        }
        levels = levels
            .iter()
            .map(|(a, c)| halve(a.view(), c.view()))
            .collect();
    }
    write_json(&dir.join(".zgroup"), &json!({"zarr_format": 2}))?;
    let label = |what: &str, name: &str| {
        if name.is_empty() {
            what.to_string()
        } else {
            format!("{what} {name}")
        }
    };
    let labels: Vec<String> = objects
        .iter()
        .map(|(n, _)| label("amplitude", n))
        .chain(objects.iter().map(|(n, _)| label("phase", n)))
        .collect();
    let channel = |label: &str, (lo, hi): (f32, f32)| {
        json!({
            "label": label,
            "color": "FFFFFF",
            "active": true,
            "window": {"start": lo, "end": hi, "min": lo, "max": hi},
        })
    };
    let metadata: Vec<String> = labels
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if i >= k {
                format!("{l} (radians)")
            } else {
                l.clone()
            }
        })
        .collect();
    write_json(
        &dir.join(".zattrs"),
        &json!({
            "multiscales": [{
                "version": "0.4",
                "name": "fpm reconstruction",
                "axes": [
                    {"name": "c", "type": "channel"},
                    {"name": "y", "type": "space", "unit": "micrometer"},
                    {"name": "x", "type": "space", "unit": "micrometer"},
                ],
                "datasets": datasets,
                "type": "2x2 mean (amplitude: mean |z|; phase: arg of the mean z)",
                "metadata": {"channels": metadata},
            }],
            "omero": {
                "version": "0.4",
                "channels": labels.iter().zip(&windows).map(|(l, w)| channel(l, *w)).collect::<Vec<_>>(),
                "rdefs": {"model": "greyscale"},
            },
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pyramid_levels_halve_and_keep_the_phase_unwrapped_in_the_mean() {
        // Four pixels at phase ±(π − 0.1): the mean of the numbers is 0, the argument
        // of the mean field is π (the right answer).
        let z = |p: f32| Complex32::from_polar(2.0, p);
        let p = std::f32::consts::PI - 0.1;
        let object = Array2::from_shape_vec((2, 2), vec![z(p), z(-p), z(-p), z(p)]).unwrap();
        let amplitude = object.mapv(|v| v.norm());
        let (a, c) = halve(amplitude.view(), object.view());
        assert_eq!(a.dim(), (1, 1));
        assert!((a[[0, 0]] - 2.0).abs() < 1e-6);
        assert!((c[[0, 0]].arg().abs() - std::f32::consts::PI).abs() < 1e-5);
    }
}
