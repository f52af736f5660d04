//! The docs/dataset.md §5 dataset format on real files: lossless round trips, other labs'
//! data, and bad datasets that must fail with errors naming the key or frame.

use std::path::Path;
use std::process::Command;

use fpm_host::dataset::{
    CameraSection, Dataset, FrameEntry, LedSection, Manifest, Pixels, SystemSection,
};
use fpm_physics::{LedGeometry, LedIndex, LedList, ListedLed};
use fpm_tests::{data_dir, fpm_bin, TempDir};
use ndarray::Array2;

fn manifest(frames: usize) -> Manifest {
    Manifest {
        system: SystemSection {
            wavelength_um: 0.47,
            na: 0.1,
            magnification: 4.0,
            pixel_size_um: 2.4,
        },
        led: LedSection {
            rows: Some(21),
            cols: Some(21),
            pitch_mm: Some(2.5),
            height_mm: 92.0,
            center: Some(LedIndex::new(10, 10)),
            offset_mm: [0.1, -0.2],
            rotation_deg: 1.5,
            tilt_deg: [0.0, 0.0],
            rings: None,
            position: None,
            na: None,
        },
        camera: CameraSection {
            dark_level: 100.0,
            bit_depth: Some(12),
            ..CameraSection::default()
        },
        source: None,
        frames: (0..frames)
            .map(|k| FrameEntry {
                also: vec![],
                file: String::new(),
                led: LedIndex::new((k % 21) as u8, ((k * 7) % 21) as u8),
                defocus_um: if k == 0 { 0.0 } else { -35.5 },
                exposure_ms: 2.5 + k as f64,
            })
            .collect(),
        entrance_pupil_mm: None,
    }
}

fn frames(n: usize, w: usize, h: usize) -> Vec<Array2<u16>> {
    (0..n)
        .map(|k| {
            Array2::from_shape_fn((h, w), |(r, c)| {
                ((r * 131 + c * 17 + k * 1009) % 4096) as u16
            })
        })
        .collect()
}

#[test]
fn writing_then_reading_is_lossless() {
    let dir = TempDir::new("roundtrip");
    let m = manifest(5);
    let imgs = frames(5, 40, 30);
    Dataset::write(&dir.0, &m, &imgs).unwrap();
    let ds = Dataset::load(&dir.0).unwrap();
    assert_eq!(ds.frames.len(), 5);
    for (k, (f, img)) in ds.frames.iter().zip(&imgs).enumerate() {
        assert_eq!(f.raw.dim(), (30, 40));
        assert_eq!(
            f.raw,
            Pixels::U16(img.clone()),
            "frame {k} stays 16-bit, unchanged"
        );
        assert_eq!(f.entry.led, m.frames[k].led);
        assert_eq!(f.entry.defocus_um, m.frames[k].defocus_um);
        assert_eq!(f.entry.exposure_ms, m.frames[k].exposure_ms);
    }
    assert_eq!(ds.manifest.system, m.system);
    assert_eq!(ds.manifest.led, m.led);
    assert_eq!(ds.manifest.camera, m.camera);
    assert_eq!(ds.corrected(1)[[0, 0]], imgs[1][[0, 0]] as f32 - 100.0);
    assert_eq!(ds.saturation(), Some(4095.0 - 100.0));
}

#[test]
fn camera_flips_and_transpose_are_applied_on_load() {
    let dir = TempDir::new("flips");
    let m = manifest(1);
    let img = Array2::from_shape_fn((3, 4), |(r, c)| (r * 10 + c) as u16);
    Dataset::write(&dir.0, &m, std::slice::from_ref(&img)).unwrap();
    let toml_path = dir.0.join("dataset.toml");
    let text = std::fs::read_to_string(&toml_path).unwrap();
    std::fs::write(&toml_path, text.replace("flip_x = false", "flip_x = true")).unwrap();
    let ds = Dataset::load(&dir.0).unwrap();
    assert_eq!(ds.frames[0].raw.to_f32()[[1, 0]], 13.0, "columns reversed");
    let text = std::fs::read_to_string(&toml_path).unwrap();
    std::fs::write(
        &toml_path,
        text.replace("flip_x = true", "flip_x = false")
            .replace("transpose = false", "transpose = true"),
    )
    .unwrap();
    let ds = Dataset::load(&dir.0).unwrap();
    assert_eq!(ds.frames[0].raw.dim(), (4, 3));
    assert_eq!(
        ds.frames[0].raw.to_f32()[[3, 1]],
        13.0,
        "rows and columns swapped"
    );
}

#[test]
fn the_vendored_usaf_dataset_from_another_lab_loads() {
    let ds = Dataset::load(&data_dir().join("zuo-usaf-11x11")).unwrap();
    assert_eq!(ds.frames.len(), 121);
    assert_eq!(ds.frames[0].raw.dim(), (128, 128));
    assert_eq!(ds.manifest.led.rows, Some(11));
    assert_eq!(ds.manifest.camera.bit_depth, Some(8));
    // Bright-field frames (rows 4–6, cols 4–6) are far brighter than dark-field ones.
    let mean = |k: usize| ds.frames[k].raw.to_f32().mean().unwrap();
    let centre = ds
        .frames
        .iter()
        .position(|f| f.entry.led == LedIndex::new(5, 5))
        .unwrap();
    let corner = ds
        .frames
        .iter()
        .position(|f| f.entry.led == LedIndex::new(0, 0))
        .unwrap();
    assert!(
        mean(centre) > 10.0 * mean(corner),
        "{} vs {}",
        mean(centre),
        mean(corner)
    );
    // Its frames were saved with a display gamma: a stored v is the light 255·(v/255)^2.2.
    assert_eq!(ds.manifest.camera.gamma, Some(2.2));
    let whole = fpm_physics::frame::Region::whole((128, 128));
    let light = ds.measured(centre).intensity(whole);
    let stored = ds.frames[centre].raw.to_f32();
    for (&v, &i) in stored.iter().zip(&light).step_by(97) {
        let expected = 255.0 * (v / 255.0).powf(2.2);
        assert!(
            (i - expected).abs() <= 1e-3 * expected.max(1.0),
            "{v} read as {i}"
        );
    }
}

/// Write a good dataset, break it with `edit`, and return the load error's text.
fn broken(tag: &str, edit: impl FnOnce(&Path)) -> String {
    let dir = TempDir::new(tag);
    Dataset::write(&dir.0, &manifest(3), &frames(3, 16, 16)).unwrap();
    edit(&dir.0);
    let err = Dataset::load(&dir.0).expect_err("a broken dataset must not load");
    format!("{err}")
}

fn edit_toml(dir: &Path, f: impl FnOnce(String) -> String) {
    let p = dir.join("dataset.toml");
    let t = std::fs::read_to_string(&p).unwrap();
    std::fs::write(&p, f(t)).unwrap();
}

#[test]
fn bad_datasets_fail_naming_the_key_or_frame() {
    let e = broken("unknown", |d| {
        edit_toml(d, |t| {
            t.replace("na = 0.1", "na = 0.1\nnumerical_aperture = 0.2")
        })
    });
    assert!(e.contains("numerical_aperture"), "{e}");

    let e = broken("missing", |d| {
        std::fs::remove_file(d.join("frames/r01_c07_z-36.tif")).unwrap()
    });
    assert!(e.contains("frame 1") && e.contains("does not exist"), "{e}");

    let e = broken("size", |d| {
        let small = Array2::<u16>::zeros((8, 16));
        fpm_host::dataset::image_io::write_tiff_u16(
            &d.join("frames/r02_c14_z-36.tif"),
            small.view(),
        )
        .unwrap();
    });
    assert!(
        e.contains("frame 2") && e.contains("16x8") && e.contains("differs"),
        "{e}"
    );

    let e = broken("led", |d| {
        edit_toml(d, |t| t.replacen("led = [1,", "led = [21,", 1))
    });
    assert!(
        e.contains("frame 1") && e.contains("outside the 21x21 array"),
        "{e}"
    );

    let e = broken("nan", |d| {
        edit_toml(d, |t| {
            t.replacen("exposure_ms = 3.5", "exposure_ms = nan", 1)
        })
    });
    assert!(e.contains("frame 1") && e.contains("exposure_ms"), "{e}");

    let e = broken("na", |d| {
        edit_toml(d, |t| t.replace("na = 0.1", "na = 1.5"))
    });
    assert!(e.contains("system.na"), "{e}");

    let e = broken("notimage", |d| {
        std::fs::write(d.join("frames/r00_c00.tif"), b"not a tiff").unwrap()
    });
    assert!(e.contains("frame 0") && e.contains("TIFF"), "{e}");

    // Colour sensors: a mosaic needs its channel, a channel needs a mosaic, the
    // pattern must be one of the four, and a mosaic's channel pixels need even sizes.
    let colour = |keys: &'static str| {
        move |d: &Path| edit_toml(d, |t| t.replace("[camera]\n", &format!("[camera]\n{keys}")))
    };
    let e = broken("bayer-no-channel", colour("bayer = \"RGGB\"\n"));
    assert!(e.contains("camera.channel"), "{e}");
    let e = broken("channel-no-bayer", colour("channel = \"G\"\n"));
    assert!(
        e.contains("camera.channel") && e.contains("camera.bayer"),
        "{e}"
    );
    let e = broken(
        "bayer-pattern",
        colour("bayer = \"RGBG\"\nchannel = \"G\"\n"),
    );
    assert!(e.contains("RGBG"), "{e}");
    let e = broken("bayer-odd", |d| {
        colour("bayer = \"RGGB\"\nchannel = \"R\"\n")(d);
        for f in [
            "frames/r00_c00.tif",
            "frames/r01_c07_z-36.tif",
            "frames/r02_c14_z-36.tif",
        ] {
            let odd = Array2::<u16>::zeros((15, 16));
            fpm_host::dataset::image_io::write_tiff_u16(&d.join(f), odd.view()).unwrap();
        }
    });
    assert!(e.contains("frame 0") && e.contains("even"), "{e}");

    // A display gamma: positive and finite, and only with a bit depth (its full scale).
    let e = broken("gamma-zero", colour("gamma = 0.0\n"));
    assert!(e.contains("camera.gamma") && e.contains("above 0"), "{e}");
    let e = broken("gamma-no-depth", |d| {
        edit_toml(d, |t| t.replace("bit_depth = 12\n", "gamma = 2.2\n"))
    });
    assert!(e.contains("camera.gamma") && e.contains("bit_depth"), "{e}");
    // A ring array: rows, cols and center say what the rings do, and every frame's LED
    // is on a ring.
    let rings = |rows: &'static str, extra: &'static str| {
        move |d: &Path| {
            edit_toml(d, |t| {
                let ringed = format!("center = [0, 0]\n{extra}");
                t.replace("rows = 21\ncols = 21\n", rows)
                    .replace("center = [10, 10]\n", &ringed)
            })
        }
    };
    let e = broken(
        "rings-rows",
        rings("rows = 21\ncols = 21\n", "rings = [1, 8, 12]\n"),
    );
    assert!(
        e.contains("led.rows/cols/center") && e.contains("number of rings"),
        "{e}"
    );
    let e = broken(
        "rings-first",
        rings("rows = 2\ncols = 8\n", "rings = [3, 8]\n"),
    );
    assert!(
        e.contains("rings = [3, 8]") && e.contains("centre LED"),
        "{e}"
    );
    // The manifest's frames light (1, 7) and (2, 14): ring 2 holds 12.
    let e = broken(
        "rings-led",
        rings("rows = 3\ncols = 12\n", "rings = [1, 8, 12]\n"),
    );
    assert!(
        e.contains("frame 2") && e.contains("not on the rings"),
        "{e}"
    );
    // `fpm reconstruct --camera-gamma` is checked as the key is (without a bit depth,
    // integer frames' sample type gives the full scale).
    let dir = TempDir::new("gamma-flag");
    Dataset::write(&dir.0, &manifest(3), &frames(3, 16, 16)).unwrap();
    edit_toml(&dir.0, |t| t.replace("bit_depth = 12\n", ""));
    let out = dir.0.join("out");
    for (gamma, why) in [("0", "above 0"), ("5.5", "at most 5")] {
        let run = fpm(&[
            "reconstruct",
            &dir.0.to_string_lossy(),
            "--out",
            &out.to_string_lossy(),
            "--camera-gamma",
            gamma,
        ]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && stderr.contains("camera.gamma") && stderr.contains(why),
            "--camera-gamma {gamma}: {stderr}"
        );
    }
}

fn fpm(args: &[&str]) -> std::process::Output {
    Command::new(fpm_bin()).args(args).output().unwrap()
}

/// A simulated calibration set in `out`: the array 2.1 mm, 1.4 mm off, turned −4°,
/// 95 mm below the sample.
fn simulate_calibration(out: &Path) {
    let run = fpm(&[
        "simulate",
        "calibration",
        "--out",
        &out.to_string_lossy(),
        "--dx-mm",
        "-2.1",
        "--dy-mm",
        "1.4",
        "--theta-deg",
        "-4",
        "--height-mm",
        "95",
        "--seed",
        "3",
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

#[test]
fn simulate_then_calibrate_recovers_the_hidden_array() {
    let dir = TempDir::new("simcal");
    let d = dir.0.to_string_lossy().into_owned();
    simulate_calibration(&dir.0);
    let plot = dir.0.join("residuals.png");
    let out = fpm(&["calibrate", &d, "--plot", &plot.to_string_lossy()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cal: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.0.join("calibration.json")).unwrap())
            .unwrap();
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.0.join("truth.json")).unwrap()).unwrap();
    let err = |k: &str| (cal[k].as_f64().unwrap() - truth[k].as_f64().unwrap()).abs();
    assert!(
        err("dx_mm") * 1e3 <= 10.0 && err("dy_mm") * 1e3 <= 10.0,
        "{cal}"
    );
    assert!(err("theta_deg") <= 0.1 && err("height_mm") <= 0.5, "{cal}");
    assert!(cal["uncertainty"]["height_mm"].as_f64().unwrap() > 0.0);
    assert_eq!(cal["leds"].as_array().unwrap().len(), 25);
    let png = std::fs::read(&plot).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

/// A calibration dataset whose frames are replaced by `frame(k, led, defocus)`.
fn calibration_with(
    tag: &str,
    frame: impl Fn(usize, LedIndex, f64) -> Array2<u16>,
) -> (TempDir, String) {
    let dir = TempDir::new(tag);
    let mut m = manifest(0);
    m.frames.push(FrameEntry {
        also: vec![],
        file: String::new(),
        led: LedIndex::new(10, 10),
        defocus_um: 0.0,
        exposure_ms: 10.0,
    });
    for r in 8..=12 {
        for c in 8..=12 {
            m.frames.push(FrameEntry {
                also: vec![],
                file: String::new(),
                led: LedIndex::new(r, c),
                defocus_um: 200.0,
                exposure_ms: 10.0,
            });
        }
    }
    let imgs: Vec<_> = m
        .frames
        .iter()
        .enumerate()
        .map(|(k, f)| frame(k, f.led, f.defocus_um))
        .collect();
    Dataset::write(&dir.0, &m, &imgs).unwrap();
    let out = fpm(&["calibrate", &dir.0.to_string_lossy()]);
    assert!(!out.status.success(), "must fail");
    (dir, String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn calibration_refuses_datasets_without_a_feature_or_light() {
    let (_d, e) = calibration_with("flat", |_, _, _| Array2::from_elem((64, 64), 300));
    assert!(e.contains("no contrast"), "{e}");

    // A feature in the reference, but every defocused frame dark.
    let (_d, e) = calibration_with("dark", |k, _, _| {
        Array2::from_shape_fn((64, 64), |(r, c)| {
            if k == 0 && (28..36).contains(&r) && (28..36).contains(&c) {
                2000
            } else {
                100
            }
        })
    });
    assert!(
        e.contains("usable bright-field frames") && e.contains("too dim"),
        "{e}"
    );

    // No in-focus reference under the centre LED.
    let dir = TempDir::new("noref");
    let mut m = manifest(0);
    m.frames.push(FrameEntry {
        also: vec![],
        file: String::new(),
        led: LedIndex::new(9, 9),
        defocus_um: 200.0,
        exposure_ms: 1.0,
    });
    Dataset::write(&dir.0, &m, &frames(1, 32, 32)).unwrap();
    let out = fpm(&["calibrate", &dir.0.to_string_lossy()]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("no in-focus reference frame"));
}

/// The manifest of [`manifest`] with its grid written as a list of the same LEDs'
/// places (every frame's LED and the centre among them).
fn listed_manifest(frames: usize) -> Manifest {
    let mut m = manifest(frames);
    let grid = m.geometry();
    let leds = grid
        .leds()
        .into_iter()
        .map(|led| {
            let (p, q) = grid.grid_offset(led);
            ListedLed {
                led,
                x_mm: p * grid.pitch_mm,
                y_mm: q * grid.pitch_mm,
                z_mm: if led.row == 0 { 1.5 } else { 0.0 },
            }
        })
        .collect();
    m.led = LedSection::of(&LedGeometry::listed(
        LedList::new(leds).unwrap(),
        grid.height_mm,
        None,
    ));
    m.led.offset_mm = [0.1, -0.2];
    m.led.rotation_deg = 1.5;
    m
}

#[test]
fn a_listed_layout_round_trips_and_places_its_leds_as_listed() {
    let dir = TempDir::new("listed");
    let m = listed_manifest(5);
    Dataset::write(&dir.0, &m, &frames(5, 16, 12)).unwrap();
    let text = std::fs::read_to_string(dir.0.join("dataset.toml")).unwrap();
    assert!(
        text.contains("[[led.position]]") && !text.contains("rows"),
        "{text}"
    );
    let ds = Dataset::load(&dir.0).unwrap();
    assert_eq!(ds.manifest.led, m.led);
    let (listed, grid) = (ds.manifest.geometry(), manifest(1).geometry());
    assert_eq!(listed.center, grid.center);
    assert!((listed.pitch_mm - 2.5).abs() < 1e-12);
    // Listed where the grid puts them, the row-0 LEDs 1.5 mm farther off.
    for led in [
        LedIndex::new(10, 10),
        LedIndex::new(3, 17),
        LedIndex::new(0, 4),
    ] {
        let (a, b) = (grid.led_position_3d_mm(led), listed.led_position_3d_mm(led));
        let deeper = if led.row == 0 { 1.5 } else { 0.0 };
        // The 1.5° turn leaves a depth along the board's normal a depth.
        assert!(
            (a.0 - b.0).abs() < 1e-9
                && (a.1 - b.1).abs() < 1e-9
                && (b.2 - a.2 - deeper).abs() < 1e-9,
            "{led}: grid {a:?}, listed {b:?}"
        );
    }
}

#[test]
fn an_na_list_places_each_led_where_its_angle_points_at_the_stated_height() {
    let dir = TempDir::new("na-list");
    Dataset::write(&dir.0, &manifest(1), &frames(1, 16, 12)).unwrap();
    edit_toml(&dir.0, |t| {
        let led = t.find("[led]").unwrap();
        let camera = t.find("[camera]").unwrap();
        let section = "[led]\nheight_mm = 50.0\n\n[[led.na]]\nled = [0, 0]\nna = [0.0, 0.0]\n\n\
                       [[led.na]]\nled = [0, 1]\nna = [0.1, -0.2]\n\n";
        let frames = t[camera..].replace("led = [0, 0]", "led = [0, 1]");
        format!("{}{section}{frames}", &t[..led])
    });
    let ds = Dataset::load(&dir.0).unwrap();
    let g = ds.manifest.geometry();
    let (x, y, h) = g.led_position_3d_mm(LedIndex::new(0, 1));
    let cos = (1.0f64 - 0.01 - 0.04).sqrt();
    assert!((x - 5.0 / cos).abs() < 1e-9 && (y + 10.0 / cos).abs() < 1e-9 && h == 50.0);
    // Seen from the field's centre, the LED is at the NA the file gave.
    let system = ds.manifest.system();
    let f = g.illumination_frequency(LedIndex::new(0, 1), 0.0, 0.0, system.wavelength_um);
    let na = (-f.0 * system.wavelength_um, -f.1 * system.wavelength_um);
    assert!(
        (na.0 - 0.1).abs() < 1e-12 && (na.1 + 0.2).abs() < 1e-12,
        "{na:?}"
    );
    assert_eq!(g.center, LedIndex::new(0, 0));
}

#[test]
fn bad_led_lists_fail_naming_the_key_or_frame() {
    let write_listed = |tag: &str, edit: &dyn Fn(String) -> String| {
        let dir = TempDir::new(tag);
        Dataset::write(&dir.0, &listed_manifest(3), &frames(3, 16, 16)).unwrap();
        edit_toml(&dir.0, edit);
        format!(
            "{}",
            Dataset::load(&dir.0).expect_err("a broken list must not load")
        )
    };
    // The frames light (0, 0), (1, 7), (2, 14): LED (1, 7) listed twice, (2, 14) as (2, 15).
    let e = write_listed("twice", &|t| t.replacen("led = [1, 8]", "led = [1, 7]", 1));
    assert!(
        e.contains("led.position") && e.contains("(1, 7) is listed twice"),
        "{e}"
    );
    let e = write_listed("unlisted", &|t| {
        t.replacen("led = [2, 14]", "led = [22, 14]", 1)
    });
    assert!(
        e.contains("frame 2") && e.contains("not one of the listed LEDs"),
        "{e}"
    );
    let e = write_listed("rows", &|t| t.replace("[led]\n", "[led]\nrows = 21\n"));
    assert!(
        e.contains("led.rows/cols") && e.contains("leave rows and cols out"),
        "{e}"
    );
    let e = write_listed("both", &|t| {
        t.replace(
            "[camera]",
            "[[led.na]]\nled = [0, 0]\nna = [0.0, 0.0]\n\n[camera]",
        )
    });
    assert!(e.contains("led.position/led.na"), "{e}");
    let e = write_listed("units", &|t| t.replacen("x_mm = ", "x_mm = \"", 1));
    assert!(e.contains("x_mm"), "{e}");
    let e = write_listed("centre", &|t| {
        t.replace("center = [10, 10]", "center = [30, 30]")
    });
    assert!(
        e.contains("led.center") && e.contains("not one of the listed"),
        "{e}"
    );
    // An NA at or beyond 1 places no LED.
    let e = broken("na-one", |d| {
        edit_toml(d, |t| {
            let led = t.find("[led]").unwrap();
            let camera = t.find("[camera]").unwrap();
            format!(
                "{}[led]\nheight_mm = 50.0\n\n[[led.na]]\nled = [0, 0]\nna = [0.8, 0.7]\n\n{}",
                &t[..led],
                &t[camera..]
            )
        })
    });
    assert!(e.contains("led.na") && e.contains("NAx² + NAy² < 1"), "{e}");
    // A grid without its pitch names the key.
    let e = broken("no-pitch", |d| {
        edit_toml(d, |t| t.replace("pitch_mm = 2.5\n", ""))
    });
    assert!(e.contains("led.pitch_mm") && e.contains("absent"), "{e}");
}

/// A calibration set whose array is stated as a list of its LEDs' places (ids kept)
/// calibrates to the same placement as when stated as a grid: the list's rigid
/// placement is the grid's.
#[test]
fn a_listed_array_calibrates_to_the_placement_its_grid_does() {
    let dir = TempDir::new("simcal-listed");
    let grid = dir.0.join("grid");
    simulate_calibration(&grid);
    let listed = dir.0.join("listed");
    std::fs::create_dir_all(listed.join("frames")).unwrap();
    let mut m = fpm_host::dataset::DatasetOnDisk::open(&grid)
        .unwrap()
        .manifest;
    for f in &m.frames {
        std::fs::copy(grid.join(&f.file), listed.join(&f.file)).unwrap();
    }
    let g = m.geometry();
    let leds = g
        .leds()
        .into_iter()
        .map(|led| {
            let (p, q) = g.grid_offset(led);
            ListedLed {
                led,
                x_mm: p * g.pitch_mm,
                y_mm: q * g.pitch_mm,
                z_mm: 0.0,
            }
        })
        .collect();
    m.led = LedSection::of(&LedGeometry::listed(
        LedList::new(leds).unwrap(),
        g.height_mm,
        None,
    ));
    m.write(&listed).unwrap();
    let calibrated = |d: &Path| -> serde_json::Value {
        let out = fpm(&["calibrate", &d.to_string_lossy()]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_str(&std::fs::read_to_string(d.join("calibration.json")).unwrap()).unwrap()
    };
    let (a, b) = (calibrated(&grid), calibrated(&listed));
    for k in ["dx_mm", "dy_mm", "theta_deg", "height_mm"] {
        let (x, y) = (a[k].as_f64().unwrap(), b[k].as_f64().unwrap());
        assert!((x - y).abs() < 1e-6, "{k}: grid {x}, listed {y}");
    }
    assert_eq!(b["leds"].as_array().unwrap().len(), 25);
}
