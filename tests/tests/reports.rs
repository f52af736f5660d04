//! The HTML reports of `fpm calibrate`, `fpm reconstruct` and `fpm dpc` in a real browser
//! (Debian's headless Chromium): each page renders (not blank, every image decodes),
//! carries the run's numbers as its JSON states them, and stands alone (no script,
//! nothing fetched). The acquisition's report is checked the same way in `demo.rs`.

use std::path::Path;

use fpm_tests::browser::{self, Rendered};
use fpm_tests::{data_dir, fpm_stdout, TempDir};

fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Render `page` and check what every report must be; returns what Chromium made of it.
fn rendered_report(page: &Path, images: usize, shots: &Path) -> Rendered {
    assert!(page.is_file(), "{} was not written", page.display());
    let html = std::fs::read_to_string(page).unwrap();
    assert!(
        !html.contains("<script"),
        "{}: the report has a script",
        page.display()
    );
    assert!(
        !html.contains("http://") && !html.contains("https://"),
        "{}: the report refers to the network",
        page.display()
    );
    let name = page.file_name().unwrap().to_string_lossy();
    let r = browser::render(page, &shots.join(format!("{name}.png")));
    assert_eq!(r.images, images, "{}: images on the page", page.display());
    assert_eq!(
        r.broken_images,
        0,
        "{}: images that did not decode",
        page.display()
    );
    let (ink, rows, size) = browser::ink(&r.screenshot);
    assert_eq!(size, (1100, 2400), "screenshot size");
    assert!(
        ink > 0.01 && rows > 0.3,
        "{}: the page rendered nearly blank ({ink:.3} of the pixels, {rows:.2} of the rows inked)",
        page.display()
    );
    assert!(r.dom.contains("No warnings.") || r.dom.contains("class=\"warn\""));
    r
}

#[test]
fn the_calibration_report_renders_with_its_numbers_and_charts() {
    let dir = TempDir::new("report-calibration");
    let data = dir.0.join("cal");
    let data_s = data.to_string_lossy();
    fpm_stdout(&["simulate", "calibration", "--out", &data_s, "--seed", "5"]);
    let svg = dir.0.join("residuals.svg");
    fpm_stdout(&["calibrate", &data_s, "--plot", &svg.to_string_lossy()]);
    let r = rendered_report(&data.join("calibration.html"), 2, &dir.0);
    let cal = json(&data.join("calibration.json"));
    let u = &cal["uncertainty"];
    let number = |v: &serde_json::Value| v.as_f64().expect("a number");
    for (key, unit) in [("dx_mm", "mm"), ("dy_mm", "mm"), ("theta_deg", "°")] {
        let cell = format!(
            "id=\"{key}\">{:+.4} ± {:.4} {unit}<",
            number(&cal[key]),
            number(&u[key])
        );
        assert!(r.dom.contains(&cell), "{cell} not on the page");
    }
    let h = format!(
        "id=\"height_mm\">{:.3} ± {:.3} mm",
        number(&cal["height_mm"]),
        number(&u["height_mm"])
    );
    assert!(r.dom.contains(&h), "{h} not on the page");
    // Every defocused frame has its row; the command that made it is there to copy.
    let leds = cal["leds"].as_array().unwrap();
    assert!(leds.len() >= 20);
    assert_eq!(r.dom.matches("<tr><td class=\"num\">(").count(), leds.len());
    assert!(r.dom.contains("fpm calibrate"), "no command line");
    // The charts as files too, and --plot as SVG with its axes in µm.
    for f in ["calibration_residuals", "calibration_array"] {
        for ext in ["png", "svg"] {
            assert!(data.join("plots").join(format!("{f}.{ext}")).is_file());
        }
    }
    let svg = std::fs::read_to_string(&svg).unwrap();
    assert!(svg.contains("shift x at the sample (µm)") && svg.contains("Residuals drawn ×"));
}

#[test]
fn the_reconstruction_report_of_real_data_renders_with_its_numbers() {
    let dir = TempDir::new("report-reconstruction");
    let out = dir.0.join("rec");
    let usaf = data_dir().join("zuo-usaf-11x11");
    fpm_stdout(&[
        "reconstruct",
        &usaf.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--passes",
        "3",
    ]);
    // Two previews and three charts.
    let r = rendered_report(&out.join("report.html"), 5, &dir.0);
    let report = json(&out.join("report.json"));
    let last = report["error_per_pass"].as_array().unwrap().last().unwrap();
    let cell = format!("id=\"final_error\">{:.4}<", last.as_f64().unwrap());
    assert!(r.dom.contains(&cell), "{cell} not on the page");
    assert!(r.dom.contains("fpm reconstruct"), "no command line");
    // The frames are decoded from the set's display gamma, and the page says how well
    // the result explains the bright-field frames.
    let fit = &report["bright_field_fit"];
    let cell = format!(
        "id=\"bright_field_fit\">measured ≈ {:.3} × modelled",
        fit["gain"].as_f64().unwrap()
    );
    assert!(r.dom.contains(&cell), "{cell} not on the page");
    assert!(
        r.dom.contains("the dataset's gamma 2.2"),
        "no gamma on the page"
    );
    // The dataset's LED positions are used as stated: the page says they are not ours.
    assert!(
        r.dom.contains("not calibrated"),
        "no warning about the geometry"
    );
    for f in ["error_per_pass", "pupil", "led_positions"] {
        assert!(
            out.join("plots").join(format!("{f}.svg")).is_file(),
            "{f}.svg"
        );
    }
}

#[test]
fn a_large_reconstruction_is_shown_shrunk_in_its_report() {
    let dir = TempDir::new("report-large");
    let ds = dir.0.join("ds");
    let out = dir.0.join("rec");
    fpm_stdout(&[
        "simulate",
        "acquisition",
        "--out",
        &ds.to_string_lossy(),
        "--size",
        "64",
    ]);
    // 64 camera pixels at U = 40: a 2560² object, over the page's 2048.
    fpm_stdout(&[
        "reconstruct",
        &ds.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--upsample",
        "40",
        "--passes",
        "1",
    ]);
    let r = rendered_report(&out.join("report.html"), 5, &dir.0);
    assert!(
        r.dom.contains("shown 2× smaller"),
        "the captions say the previews are shrunk"
    );
    let png_side = |p: &Path| {
        let bytes = std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        let word = |at: usize| {
            u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
        };
        (word(16), word(20))
    };
    assert_eq!(
        png_side(&out.join("amplitude.png")),
        (2560, 2560),
        "full size beside the page"
    );
    assert_eq!(
        png_side(&out.join("plots/amplitude-page.png")),
        (1280, 1280)
    );
    let page = std::fs::metadata(out.join("report.html"))
        .map(|m| m.len())
        .unwrap_or(0);
    let size = |name: &str| std::fs::metadata(out.join(name)).map_or(0, |m| m.len());
    // The full pair embedded would take 4/3 of their bytes (base64) and more; the
    // shrunk pair a quarter of their pixels.
    let full = size("amplitude.png") + size("phase.png");
    assert!(
        page < full,
        "the page ({page} B) embeds less than the full amplitude.png and phase.png ({full} B)"
    );
}

#[test]
fn the_dpc_report_of_real_data_renders_and_says_the_sample_is_not_weak() {
    let dir = TempDir::new("report-dpc");
    let out = dir.0.join("dpc");
    let usaf = data_dir().join("zuo-usaf-11x11");
    fpm_stdout(&[
        "dpc",
        &usaf.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
    ]);
    // The phase and absorption previews.
    let r = rendered_report(&out.join("report.html"), 2, &dir.0);
    let report = json(&out.join("dpc.json"));
    for half in report["halves"].as_array().unwrap() {
        let row = format!(
            "<td class=\"num\">{}</td><td class=\"num\">{}</td>",
            half["half"].as_str().unwrap(),
            half["leds"].as_array().unwrap().len()
        );
        assert!(r.dom.contains(&row), "{row} not on the page");
    }
    // The USAF target's opaque bars are no weak object: the page says so, with what
    // to do instead.
    assert!(r.dom.contains("not weak") && r.dom.contains("fpm reconstruct"));
    assert!(r.dom.contains("fpm dpc"), "no command line");
}

/// A colour reconstruction's page: the sRGB preview, a row per colour with its
/// wavelength and score as report.json states them, and the one-calibration warning.
#[test]
fn the_colour_report_renders_each_channel_and_warns_of_one_calibration() {
    let dir = TempDir::new("report-colour");
    let data = dir.0.join("rgb");
    let cal = dir.0.join("cal");
    fpm_tests::simulate_centred(
        &data,
        "48",
        "1",
        &["--colors", "red,green,blue", "--spectral-samples", "1"],
    );
    fpm_tests::simulate_centred_calibration(&cal, "256", "1", &["--colors", "green"]);
    fpm_stdout(&["calibrate", &cal.to_string_lossy()]);
    let out = dir.0.join("out");
    let green = cal.join("green/calibration.json");
    fpm_stdout(&[
        "reconstruct",
        &data.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--calibration",
        &green.to_string_lossy(),
        "--passes",
        "3",
    ]);
    let r = rendered_report(&out.join("report.html"), 1, &dir.0);
    let report = json(&out.join("report.json"));
    for c in report["channels"].as_array().unwrap() {
        let row = format!(
            "<td class=\"num\">{}</td><td class=\"num\">{:.1} nm</td>",
            c["name"].as_str().unwrap(),
            c["wavelength_um"].as_f64().unwrap() * 1e3
        );
        assert!(r.dom.contains(&row), "{row} not on the page");
        let score = format!(
            "{:.3}",
            c["versus_truth"]["complex_nrmse"].as_f64().unwrap()
        );
        assert!(r.dom.contains(&score), "{score} not on the page");
    }
    assert!(r.dom.contains("one calibration") && r.dom.contains("calibrate each colour"));
    assert!(r.dom.contains("fpm reconstruct"), "no command line");
}
