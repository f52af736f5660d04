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
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use ndarray::{Array2, ArrayView2};
use rustfft::num_complex::Complex32;
use serde_json::json;

use crate::pyramid::halve;

/// Chunk side, pixels: a 256² float32 chunk is 256 KiB before compression.
pub const CHUNK: usize = 256;

/// Chunk row `cy` of one channel of one level (`rows`: at most [`CHUNK`] rows) as
/// Zarr v2 chunks under `level_dir/<channel>/<cy>/<x>`, padded with NaN (the `.zarray`
/// fill value).
fn write_chunks(
    level_dir: &Path,
    cy: usize,
    channel: usize,
    rows: ArrayView2<'_, f32>,
) -> Result<()> {
    let (h, w) = rows.dim();
    let dir = level_dir.join(channel.to_string()).join(cy.to_string());
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    for cx in 0..w.div_ceil(CHUNK) {
        let mut raw = Vec::with_capacity(CHUNK * CHUNK * 4);
        for r in 0..CHUNK {
            for c in cx * CHUNK..(cx + 1) * CHUNK {
                let v = if r < h && c < w {
                    rows[[r, c]]
                } else {
                    f32::NAN
                };
                raw.extend_from_slice(&v.to_le_bytes());
            }
        }
        let path = dir.join(cx.to_string());
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut z = flate2::write::ZlibEncoder::new(file, flate2::Compression::new(5));
        z.write_all(&raw)
            .and_then(|_| z.finish().map(drop))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// The 0.5 % and 99.5 % points of `values` (the display window napari starts with).
fn window(mut values: Vec<f32>) -> (f32, f32) {
    values.retain(|x| x.is_finite());
    match fpm_physics::stats::quantiles(&mut values, [0.005, 0.995]) {
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
    let names: Vec<&str> = objects.iter().map(|(n, _)| *n).collect();
    let dim = objects.first().map_or((0, 0), |(_, o)| o.dim());
    let mut writer = Writer::create(dir, &names, dim, pixel_um, origin_um)?;
    let views: Vec<ArrayView2<'_, Complex32>> = objects.iter().map(|(_, o)| o.view()).collect();
    writer.push(&views)?;
    writer.finish().map(drop)
}

/// `.zgroup` and `.zattrs`: the multiscale's levels (`datasets`), the channels'
/// labels (amplitudes, then phases) and display `windows`.
fn write_metadata(
    dir: &Path,
    names: &[String],
    windows: &[(f32, f32)],
    datasets: Vec<serde_json::Value>,
) -> Result<()> {
    write_json(&dir.join(".zgroup"), &json!({"zarr_format": 2}))?;
    let label = |what: &str, name: &str| {
        if name.is_empty() {
            what.to_string()
        } else {
            format!("{what} {name}")
        }
    };
    let k = names.len();
    let labels: Vec<String> = names
        .iter()
        .map(|n| label("amplitude", n))
        .chain(names.iter().map(|n| label("phase", n)))
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
                "channels": labels.iter().zip(windows).map(|(l, w)| channel(l, *w)).collect::<Vec<_>>(),
                "rdefs": {"model": "greyscale"},
            },
        }),
    )
}

/// The longest side of the preview [`Writer::finish`] keeps: the first pyramid level
/// at most this big.
pub const PREVIEW_SIDE: usize = 2048;

/// Rows of one image at one pyramid level: the amplitude (mean |z| of the level
/// below) and the complex mean.
type Rows = (Array2<f32>, Array2<Complex32>);

/// One pyramid level being written: its size, the rows not yet written (a chunk row
/// is written once it is full), and how many chunk rows are out.
struct Level {
    dim: (usize, usize),
    /// Per image, the rows waiting for a full chunk row.
    pending: Vec<Rows>,
    chunk_rows_written: usize,
}

/// An OME-Zarr image written a band of rows at a time, its pyramid built as the rows
/// come: a slide far larger than memory is written with a few chunk rows per level
/// held. What [`write_placed`] writes at once, this writes from bands of any height.
pub struct Writer {
    dir: PathBuf,
    names: Vec<String>,
    pixel_um: f64,
    origin_um: (f64, f64),
    levels: Vec<Level>,
    /// Rows of level 0 received so far.
    rows_in: usize,
    /// Every `stride`-th pixel of level 0, per channel (amplitudes, then phases), for
    /// the display windows.
    samples: Vec<Vec<f32>>,
    stride: usize,
    /// With [`Writer::with_preview`]: the preview's level and the first image's rows
    /// of it so far.
    preview: Option<(usize, Vec<Rows>)>,
}

/// The smallest pyramid level at most [`PREVIEW_SIDE`] a side, of the first image.
pub struct Preview {
    pub amplitude: Array2<f32>,
    pub object: Array2<Complex32>,
    /// Its pixel, µm.
    pub pixel_um: f64,
}

/// Level sizes: each half the last (odd rows and columns dropped), down to one chunk.
fn level_dims((h, w): (usize, usize)) -> Vec<(usize, usize)> {
    let mut dims = vec![(h, w)];
    let (mut h, mut w) = (h, w);
    while h.max(w) > CHUNK && h >= 2 && w >= 2 {
        (h, w) = (h / 2, w / 2);
        dims.push((h, w));
    }
    dims
}

/// Rows of `a` then `b` (the same width).
fn stacked<'a, T: Clone>(a: &'a Array2<T>, b: ArrayView2<'a, T>) -> Result<Array2<T>> {
    Ok(ndarray::concatenate(ndarray::Axis(0), &[a.view(), b])?)
}

impl Writer {
    /// Start the OME-Zarr group `dir` (replaced if it exists) for `names.len()` complex
    /// images of `dim` (rows, columns), sampled at `pixel_um`, the first pixel at
    /// `origin_um` (x, y) in the slide's coordinates; names as [`write_objects`] has them.
    pub fn create(
        dir: &Path,
        names: &[&str],
        dim: (usize, usize),
        pixel_um: f64,
        origin_um: (f64, f64),
    ) -> Result<Self> {
        if dir.exists() {
            std::fs::remove_dir_all(dir).with_context(|| format!("replacing {}", dir.display()))?;
        }
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let k = names.len();
        let levels = level_dims(dim)
            .into_iter()
            .map(|(h, w)| Level {
                dim: (h, w),
                pending: (0..k)
                    .map(|_| (Array2::zeros((0, w)), Array2::zeros((0, w))))
                    .collect(),
                chunk_rows_written: 0,
            })
            .collect();
        // At most ~4 M samples per channel for the windows: every pixel of a field.
        let stride = (dim.0 * dim.1).div_ceil(1 << 22).max(1);
        Ok(Self {
            dir: dir.to_path_buf(),
            names: names.iter().map(|n| n.to_string()).collect(),
            pixel_um,
            origin_um,
            levels,
            rows_in: 0,
            samples: vec![Vec::new(); 2 * k],
            stride,
            preview: None,
        })
    }

    /// Also keep the first image's smallest pyramid level at most [`PREVIEW_SIDE`] a
    /// side, for [`Writer::finish`] to return.
    pub fn with_preview(mut self) -> Self {
        let level = self
            .levels
            .iter()
            .position(|l| l.dim.0.max(l.dim.1) <= PREVIEW_SIDE)
            .unwrap_or(self.levels.len() - 1);
        self.preview = Some((level, Vec::new()));
        self
    }

    /// The next rows of every image (one band per name, each as wide as the image and
    /// of the same height); NaN marks pixels without data.
    pub fn push(&mut self, bands: &[ArrayView2<'_, Complex32>]) -> Result<()> {
        let k = self.names.len();
        let (h, w) = self.levels[0].dim;
        let rows = bands.first().map_or(0, |b| b.nrows());
        if bands.len() != k || bands.iter().any(|b| b.dim() != (rows, w)) || self.rows_in + rows > h
        {
            bail!(
                "{}: a band of {rows} rows of {w} for {k} images, {} rows in of {h}",
                self.dir.display(),
                self.rows_in
            );
        }
        let mut level_in = Vec::with_capacity(k);
        for (i, band) in bands.iter().enumerate() {
            for (n, z) in band.iter().enumerate() {
                if (self.rows_in * w + n).is_multiple_of(self.stride) {
                    self.samples[i].push(z.norm());
                    self.samples[k + i].push(z.arg());
                }
            }
            level_in.push((band.mapv(|z| z.norm()), band.to_owned()));
        }
        self.rows_in += rows;
        self.feed(0, level_in, false)
    }

    /// Add rows to level `l`: full chunk rows are written and halved into level l + 1;
    /// `last` flushes what is left (the image's end).
    fn feed(&mut self, l: usize, rows: Vec<Rows>, last: bool) -> Result<()> {
        let k = self.names.len();
        if let (Some((level, kept)), Some((a, c))) = (self.preview.as_mut(), rows.first()) {
            if *level == l && a.nrows() > 0 {
                kept.push((a.clone(), c.clone()));
            }
        }
        let level = &mut self.levels[l];
        for (i, (a, c)) in rows.into_iter().enumerate() {
            let p = &mut level.pending[i];
            *p = (stacked(&p.0, a.view())?, stacked(&p.1, c.view())?);
        }
        loop {
            let have = self.levels[l].pending.first().map_or(0, |p| p.0.nrows());
            let take = if have >= CHUNK {
                CHUNK
            } else if last && have > 0 {
                have
            } else {
                break;
            };
            let level_dir = self.dir.join(l.to_string());
            let cy = self.levels[l].chunk_rows_written;
            let mut down = Vec::with_capacity(k);
            for i in 0..k {
                let (a, c) = {
                    let p = &mut self.levels[l].pending[i];
                    let head = (
                        p.0.slice(ndarray::s![..take, ..]).to_owned(),
                        p.1.slice(ndarray::s![..take, ..]).to_owned(),
                    );
                    *p = (
                        p.0.slice(ndarray::s![take.., ..]).to_owned(),
                        p.1.slice(ndarray::s![take.., ..]).to_owned(),
                    );
                    head
                };
                write_chunks(&level_dir, cy, i, a.view())?;
                write_chunks(&level_dir, cy, k + i, c.mapv(|z| z.arg()).view())?;
                down.push(halve(a.view(), c.view()));
            }
            self.levels[l].chunk_rows_written += 1;
            if l + 1 < self.levels.len() {
                self.feed(l + 1, down, false)?;
            }
        }
        if last && l + 1 < self.levels.len() {
            self.feed(
                l + 1,
                (0..k)
                    .map(|_| {
                        let w = self.levels[l + 1].dim.1;
                        (Array2::zeros((0, w)), Array2::zeros((0, w)))
                    })
                    .collect(),
                true,
            )?;
        }
        Ok(())
    }

    /// Write what is left and the group's metadata; the preview, if it was asked for
    /// ([`Writer::with_preview`]).
    pub fn finish(mut self) -> Result<Option<Preview>> {
        let (h, w) = self.levels[0].dim;
        if self.rows_in != h {
            bail!("{}: {} rows of {h} given", self.dir.display(), self.rows_in);
        }
        let k = self.names.len();
        let empty = (0..k)
            .map(|_| (Array2::zeros((0, w)), Array2::zeros((0, w))))
            .collect();
        self.feed(0, empty, true)?;
        let mut datasets = vec![];
        for (level, l) in self.levels.iter().enumerate() {
            let (h, w) = l.dim;
            write_json(
                &self.dir.join(level.to_string()).join(".zarray"),
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
            let scale = self.pixel_um * (1u64 << level) as f64;
            // A level's pixel k covers 2^level pixels of level 0: its centre sits half
            // of that (less half a pixel) further on.
            let half = 0.5 * (scale - self.pixel_um);
            let mut transforms = vec![json!({"type": "scale", "scale": [1.0, scale, scale]})];
            if self.origin_um != (0.0, 0.0) {
                transforms.push(json!({"type": "translation", "translation": [0.0, self.origin_um.1 + half, self.origin_um.0 + half]}));
            }
            datasets.push(json!({
                "path": level.to_string(),
                "coordinateTransformations": transforms,
            }));
        }
        let windows: Vec<(f32, f32)> = std::mem::take(&mut self.samples)
            .into_iter()
            .map(window)
            .collect();
        write_metadata(&self.dir, &self.names, &windows, datasets)?;
        let Some((level, kept)) = self.preview.take() else {
            return Ok(None);
        };
        if kept.is_empty() {
            bail!(
                "{}: an image without rows has no preview",
                self.dir.display()
            );
        }
        let amplitudes: Vec<_> = kept.iter().map(|(a, _)| a.view()).collect();
        let objects: Vec<_> = kept.iter().map(|(_, c)| c.view()).collect();
        Ok(Some(Preview {
            amplitude: ndarray::concatenate(ndarray::Axis(0), &amplitudes)?,
            object: ndarray::concatenate(ndarray::Axis(0), &objects)?,
            pixel_um: self.pixel_um * (1u64 << level) as f64,
        }))
    }
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

    /// Every file under `dir`, relative path → bytes.
    fn files(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
        let mut out = std::collections::BTreeMap::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let rel = p.strip_prefix(dir).unwrap().to_path_buf();
                    out.insert(rel, std::fs::read(&p).unwrap());
                }
            }
        }
        out
    }

    #[test]
    fn an_image_written_in_bands_of_any_height_is_the_image_written_at_once() {
        // 600 × 530: three levels (600, 300, 150 rows), odd sizes on the way, edge
        // chunks padded; NaN where there is no data.
        let (h, w) = (600, 530);
        let object = Array2::from_shape_fn((h, w), |(r, c)| {
            if r > 590 && c < 20 {
                Complex32::new(f32::NAN, f32::NAN)
            } else {
                Complex32::from_polar(1.0 + (r % 7) as f32 * 0.1, (c as f32 * 0.05).sin() * 3.0)
            }
        });
        let base = std::env::temp_dir().join(format!("fpm-zarr-bands-{}", std::process::id()));
        let (once, banded) = (base.join("once.zarr"), base.join("banded.zarr"));
        write_placed(&once, &[("", &object)], 0.5, (10.0, -4.0)).unwrap();
        let mut writer = Writer::create(&banded, &[""], (h, w), 0.5, (10.0, -4.0))
            .unwrap()
            .with_preview();
        let mut at = 0;
        for rows in [1, 37, 256, 255, 51] {
            writer
                .push(&[object.slice(ndarray::s![at..at + rows, ..])])
                .unwrap();
            at += rows;
        }
        assert_eq!(at, h);
        let preview = writer.finish().unwrap().expect("asked for");
        let (a, b) = (files(&once), files(&banded));
        assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
        assert!(a.keys().any(|k| k.starts_with("2")), "{:?}", a.keys());
        for (k, v) in &a {
            assert!(v == &b[k], "{} differs", k.display());
        }
        // The whole image is the preview (at most 2048 a side), NaN kept.
        assert_eq!(preview.object.dim(), (h, w));
        assert!((preview.pixel_um - 0.5).abs() < 1e-12);
        assert!(preview.amplitude[[595, 3]].is_nan());
        // Too many rows is refused, naming the store.
        let mut writer = Writer::create(&banded, &[""], (4, 4), 0.5, (0.0, 0.0)).unwrap();
        let err = writer
            .push(&[Array2::<Complex32>::zeros((5, 4)).view()])
            .unwrap_err();
        assert!(format!("{err}").contains("banded.zarr"), "{err}");
        std::fs::remove_dir_all(&base).unwrap();
    }
}
