//! `fpm import`: other labs' files, written as each lab's own public code reads them
//! (tests/import_sources/export.py, with scipy and h5py), imported and reconstructed.
//! A simulated acquisition (full wave-optics model, hidden truth) must come back to
//! the complex NRMSE it has as an fpm dataset; the same file with one convention broken
//! on purpose (an angle's sign, the axes, the units) must be refused by name or
//! reconstruct clearly worse, so each test would catch an importer that got that
//! convention wrong.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use fpm_tests::{fpm_bin, fpm_stdout, python_with_numpy, simulate_centred, workspace, TempDir};

/// Write `dataset` as `format` into `out` (export.py's `extra`: `--mutate …`, `--v73`).
fn export(format: &str, dataset: &Path, out: &Path, extra: &[&str]) {
    let run = Command::new(python_with_numpy())
        .arg(workspace().join("tests/import_sources/export.py"))
        .args([format, &dataset.to_string_lossy(), &out.to_string_lossy()])
        .args(extra)
        .output()
        .expect("running export.py");
    assert!(
        run.status.success(),
        "export.py {format}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// `fpm import FORMAT SRC --out OUT EXTRA…`.
fn import(format: &str, src: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(fpm_bin())
        .args(["import", format])
        .arg(src)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .expect("running fpm import")
}

fn import_ok(format: &str, src: &Path, out: &Path, extra: &[&str]) {
    let run = import(format, src, out, extra);
    assert!(
        run.status.success(),
        "fpm import {format} {}: {}",
        src.display(),
        String::from_utf8_lossy(&run.stderr)
    );
}

fn import_refused(format: &str, src: &Path, out: &Path, extra: &[&str]) -> String {
    let run = import(format, src, out, extra);
    assert!(!run.status.success(), "{} must be refused", src.display());
    String::from_utf8_lossy(&run.stderr).into_owned()
}

/// A 128² acquisition of a centred 21 × 21 array (92 mm, 2.5 mm pitch) with its truth.
fn simulated(dir: &TempDir) -> PathBuf {
    let sim = dir.0.join("sim");
    simulate_centred(&sim, "128", "5", &[]);
    sim
}

/// The complex NRMSE of `dataset` reconstructed against `truth_of`'s hidden truth.
fn nrmse(dataset: &Path, truth_of: &Path) -> f64 {
    for f in ["truth.json", "truth_amplitude.tif", "truth_phase.tif"] {
        if dataset != truth_of {
            std::fs::copy(truth_of.join(f), dataset.join(f)).unwrap();
        }
    }
    let out = dataset.with_extension("out");
    let run = Command::new(fpm_bin())
        .args(["reconstruct", &dataset.to_string_lossy(), "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    report["versus_truth"]["complex_nrmse"].as_f64().unwrap()
}

/// `[source]` of the dataset in `dir`, as text.
fn source_section(dir: &Path) -> String {
    let toml = std::fs::read_to_string(dir.join("dataset.toml")).unwrap();
    toml[toml.find("[source]").expect("a [source] section")..].to_string()
}

/// Each of `mutations` of `sim` written as `format` (file `MUTATION.ext`), imported
/// with `args` and reconstructed: its complex NRMSE.
fn broken(
    dir: &TempDir,
    sim: &Path,
    format: &str,
    ext: &str,
    mutations: &[&'static str],
    args: &[&str],
) -> Vec<(&'static str, f64)> {
    mutations
        .iter()
        .map(|&mutation| {
            let file = dir.0.join(format!("{mutation}.{ext}"));
            export(format, sim, &file, &["--mutate", mutation]);
            let ds = dir.0.join(mutation);
            import_ok(format, &file, &ds, args);
            (mutation, nrmse(&ds, sim))
        })
        .collect()
}

/// The error of importing `sim` written as `format` with its units broken.
fn units_refused(dir: &TempDir, sim: &Path, format: &str, ext: &str, args: &[&str]) -> String {
    let file = dir.0.join(format!("units.{ext}"));
    export(format, sim, &file, &["--mutate", "units"]);
    import_refused(format, &file, &dir.0.join("units"), args)
}

/// The imported set within 1 % of the original's NRMSE, each broken one past 1.5×.
fn assert_caught(format: &str, original: f64, imported: &[(&str, f64)], broken: &[(&str, f64)]) {
    eprintln!("{format}: complex NRMSE {original:.4} as simulated, imported {imported:?}; broken {broken:?}");
    for (tag, e) in imported {
        assert!(
            (e - original).abs() < 0.01 * original,
            "{format} {tag}: {e} against {original}"
        );
    }
    for (what, e) in broken {
        assert!(
            e > &(1.5 * original),
            "{format} with its {what} wrong: {e} against {original}"
        );
    }
}

const SYSTEM: &[&str] = &[
    "--wavelength-um",
    "0.47",
    "--na",
    "0.1",
    "--magnification",
    "4",
    "--pixel-size-um",
    "2.4",
];

/// Caltech's FPM_software files, v5 and v7.3: NA_list's sign and column order as its
/// reconstruction reads them, lambda and dpix_c in µm; no LED distance (plane waves).
#[test]
fn caltech_files_v5_and_v73_reconstruct_as_the_dataset_they_came_from() {
    let dir = TempDir::new("import-caltech");
    let sim = simulated(&dir);
    let original = nrmse(&sim, &sim);
    let mut results = vec![];
    for (tag, extra) in [("v5", &[][..]), ("v73", &["--v73"][..])] {
        let mat = dir.0.join(format!("{tag}.mat"));
        export("caltech-mat", &sim, &mat, extra);
        let ds = dir.0.join(tag);
        import_ok("caltech-mat", &mat, &ds, &["--height-mm", "92"]);
        results.push((tag, nrmse(&ds, &sim)));
    }
    // Without a distance the LEDs are placed as plane waves would be, and it says so.
    let plane = dir.0.join("plane");
    import_ok("caltech-mat", &dir.0.join("v5.mat"), &plane, &[]);
    assert!(
        source_section(&plane).contains("plane waves"),
        "{}",
        source_section(&plane)
    );
    let plane_waves = nrmse(&plane, &sim);
    let broken = broken(
        &dir,
        &sim,
        "caltech-mat",
        "mat",
        &["sign", "axes"],
        &["--height-mm", "92"],
    );
    eprintln!("caltech-mat as plane waves: {plane_waves:.4}");
    assert_caught("caltech-mat", original, &results, &broken);
    // lambda and dpix_c in metres are refused by name.
    let e = units_refused(&dir, &sim, "caltech-mat", "mat", &[]);
    assert!(e.contains("`lambda`") && e.contains("µm"), "{e}");
}

/// The Zheng lab's files: imlow_HDR amplitudes in LED_location.m's spiral, positions
/// from xint/yint and the code's pitch and height, wlength in metres.
#[test]
fn zheng_files_reconstruct_as_the_dataset_they_came_from() {
    let dir = TempDir::new("import-zheng");
    let sim = simulated(&dir);
    // The reference's 15 × 15 array: the central LEDs of the simulated 21 × 21.
    let central = dir.0.join("central");
    let mut m = fpm_host::dataset::DatasetOnDisk::open(&sim)
        .unwrap()
        .manifest;
    m.frames
        .retain(|f| f.led.r().abs_diff(10) <= 7 && f.led.c().abs_diff(10) <= 7);
    assert_eq!(m.frames.len(), 225);
    std::fs::create_dir_all(central.join("frames")).unwrap();
    for f in &m.frames {
        std::fs::copy(sim.join(&f.file), central.join(&f.file)).unwrap();
    }
    m.write(&central).unwrap();
    let original = nrmse(&central, &sim);
    let args: Vec<&str> = ["--pitch-mm", "2.5", "--height-mm", "92"]
        .iter()
        .chain(SYSTEM)
        .copied()
        .collect();
    let mat = dir.0.join("zheng.mat");
    export("zheng-mat", &sim, &mat, &[]);
    let ds = dir.0.join("zheng");
    import_ok("zheng-mat", &mat, &ds, &args);
    let imported = nrmse(&ds, &sim);
    let source = source_section(&ds);
    assert!(
        source.contains("amplitude") && source.contains("spiral"),
        "{source}"
    );
    let broken = broken(&dir, &sim, "zheng-mat", "mat", &["sign", "axes"], &args);
    assert_caught(
        "zheng-mat (the central 15 x 15)",
        original,
        &[("v5", imported)],
        &broken,
    );
    let e = units_refused(&dir, &sim, "zheng-mat", "mat", &args);
    assert!(e.contains("`wlength`") && e.contains("metres"), "{e}");
}

/// PtyLab's HDF5: encoder in metres with its columns (rows, columns), wavelength, dxd
/// and zled in metres.
#[test]
fn ptylab_files_reconstruct_as_the_dataset_they_came_from() {
    let dir = TempDir::new("import-ptylab");
    let sim = simulated(&dir);
    let original = nrmse(&sim, &sim);
    let h5 = dir.0.join("fpm.h5");
    export("ptylab-h5", &sim, &h5, &[]);
    let ds = dir.0.join("imported");
    import_ok("ptylab-h5", &h5, &ds, &[]);
    let imported = nrmse(&ds, &sim);
    let broken = broken(&dir, &sim, "ptylab-h5", "h5", &["sign", "axes"], &[]);
    assert_caught("ptylab-h5", original, &[("h5", imported)], &broken);
    let e = units_refused(&dir, &sim, "ptylab-h5", "h5", &[]);
    assert!(e.contains("`wavelength`") && e.contains("metres"), "{e}");
}

/// A multi-page TIFF of float intensities beside a CSV of LED positions in mm.
#[test]
fn a_tiff_stack_and_a_csv_reconstruct_as_the_dataset_they_came_from() {
    let dir = TempDir::new("import-tiff-csv");
    let sim = simulated(&dir);
    let original = nrmse(&sim, &sim);
    let args: Vec<&str> = ["--height-mm", "92"]
        .iter()
        .chain(SYSTEM)
        .copied()
        .collect();
    let tiff = dir.0.join("frames.tif");
    export("tiff-csv", &sim, &tiff, &[]);
    let ds = dir.0.join("imported");
    import_ok("tiff-csv", &tiff, &ds, &args);
    let imported = nrmse(&ds, &sim);
    let broken = broken(
        &dir,
        &sim,
        "tiff-csv",
        "tif",
        &["sign", "axes", "units"],
        &args,
    );
    assert_caught("tiff-csv", original, &[("tif", imported)], &broken);
    // What the files cannot say is asked for by option; a column without its unit is
    // refused by name.
    let e = import_refused(
        "tiff-csv",
        &tiff,
        &dir.0.join("no-system"),
        &["--height-mm", "92"],
    );
    assert!(
        e.contains("--wavelength-um") && e.contains("--pixel-size-um"),
        "{e}"
    );
    let csv = dir.0.join("frames.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    std::fs::write(&csv, text.replacen("x_mm", "x", 1)).unwrap();
    let e = import_refused("tiff-csv", &tiff, &dir.0.join("no-unit"), &args);
    assert!(e.contains("`x`") && e.contains("unit"), "{e}");
}

#[test]
fn import_lists_its_formats_and_refuses_an_unknown_one() {
    let list = fpm_stdout(&["import", "--list"]);
    for name in ["zheng-mat", "caltech-mat", "ptylab-h5", "tiff-csv"] {
        assert!(list.contains(name), "{list}");
    }
    let dir = TempDir::new("import-unknown");
    let e = import_refused("tian-txt", &dir.0, &dir.0.join("out"), &[]);
    assert!(e.contains("tian-txt") && e.contains("caltech-mat"), "{e}");
    // Not a .mat file at all: named.
    let junk = dir.0.join("junk.mat");
    std::fs::write(&junk, b"not matlab").unwrap();
    let e = import_refused("caltech-mat", &junk, &dir.0.join("out"), &[]);
    assert!(e.contains("junk.mat") && e.contains("not a MATLAB"), "{e}");
}
