//! fpm-host as a library: a reconstruction job and a simulation checked before they
//! run, and a dataset whose optics no microscope has refused by key.

use std::path::PathBuf;

use fpm_host::reconstruction::{GeometryChoice, Job};
use fpm_host::simulation::{AcquisitionSet, Scene};
use fpm_physics::reconstruct::Settings;

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("fpm-host-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Each out-of-range setting is refused up front, named.
#[test]
fn a_job_names_the_setting_out_of_range() {
    let refused = |job: Job, name: &str| {
        let e = job.validate().expect_err(name).to_string();
        assert!(e.starts_with(name), "{name}: {e}");
    };
    let with = |settings: Settings| Job {
        settings,
        ..Job::default()
    };
    assert!(Job::default().validate().is_ok());
    refused(
        with(Settings {
            upsample: 0,
            ..Settings::default()
        }),
        "upsample 0",
    );
    refused(
        with(Settings {
            alpha: 0.0,
            ..Settings::default()
        }),
        "alpha",
    );
    refused(
        with(Settings {
            beta: f32::NAN,
            ..Settings::default()
        }),
        "beta",
    );
    refused(
        with(Settings {
            defocus_um: f64::INFINITY,
            ..Settings::default()
        }),
        "refocus_um",
    );
    refused(
        Job {
            passes: 0,
            ..Job::default()
        },
        "passes 0",
    );
    refused(
        Job {
            tile: Some(4),
            ..Job::default()
        },
        "tile 4",
    );
    refused(
        Job {
            frame_memory_gb: -1.0,
            ..Job::default()
        },
        "frame_memory_gb",
    );
    refused(
        Job {
            entrance_pupil_mm: Some(0.0),
            ..Job::default()
        },
        "entrance_pupil_mm",
    );
    refused(
        Job {
            geometry: GeometryChoice::LedHeightMm(-90.0),
            ..Job::default()
        },
        "led_height_mm",
    );
}

/// A simulation too large for memory is refused before it allocates (it aborted on a
/// 320 GB allocation).
#[test]
fn a_simulation_too_large_is_refused_before_it_allocates() {
    let scene = Scene {
        size: 100_000,
        ..Scene::default()
    };
    let out = scratch("sim-too-large");
    let e = fpm_host::simulation::write_acquisition(&scene, &AcquisitionSet::default(), &out)
        .expect_err("100000 px");
    assert!(e.to_string().contains("size 100000"), "{e}");
    assert!(!out.exists());
}

/// A dataset stating a wavelength no microscope has (1e30 µm) is refused, naming the
/// key, instead of reconstructing nonsense; then a real job runs on the same dataset
/// with the wavelength put right, through the library alone.
#[test]
fn a_dataset_with_impossible_optics_is_refused_by_key() {
    let out = scratch("optics");
    let scene = Scene {
        size: 32,
        ..Scene::default()
    };
    fpm_host::simulation::write_acquisition(&scene, &AcquisitionSet::default(), &out).unwrap();
    let manifest = out.join("dataset.toml");
    let good = std::fs::read_to_string(&manifest).unwrap();
    let line = good
        .lines()
        .find(|l| l.trim_start().starts_with("wavelength_um"))
        .unwrap();
    std::fs::write(&manifest, good.replace(line, "wavelength_um = 1e30")).unwrap();
    let job = Job {
        passes: 1,
        ..Job::default()
    };
    let e = job.run(&out, &|_| {}).err().expect("refused");
    let text = format!("{e:#}");
    assert!(
        text.contains("system.wavelength_um") && text.contains("dataset.toml"),
        "{text}"
    );
    std::fs::write(&manifest, good).unwrap();
    let finished = job.run(&out, &|_| {}).unwrap();
    let scores = finished
        .reconstruction
        .report
        .versus_truth
        .expect("scored against truth.json");
    assert!(scores.complex_nrmse.is_finite());
    std::fs::remove_dir_all(&out).unwrap();
}
