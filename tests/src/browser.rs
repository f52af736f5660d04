//! A real browser for the HTML reports: Debian's headless Chromium renders a page to
//! a screenshot and dumps its DOM after load. Chromium is started with its background
//! networking off (this machine allows no traffic but loopback) and a fresh profile.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Where Debian installs it (`.ci/run` installs the package).
pub const CHROMIUM: &str = "/usr/bin/chromium";

/// What Chromium made of a page.
pub struct Rendered {
    /// The DOM after load, with the probe's attributes on `<body>`.
    pub dom: String,
    /// `<img>` elements on the page.
    pub images: usize,
    /// Of those, the ones that did not decode (missing or broken data).
    pub broken_images: usize,
    /// The screenshot (PNG).
    pub screenshot: PathBuf,
}

/// Render `page` in headless Chromium: a screenshot into `screenshot` and the DOM of a
/// copy of the page with a probe appended that counts images that failed to load (the
/// report itself has no script).
pub fn render(page: &Path, screenshot: &Path) -> Rendered {
    assert!(
        Path::new(CHROMIUM).exists(),
        "{CHROMIUM} is not installed: apt install chromium (.ci/run does)"
    );
    let profile = crate::TempDir::new("chromium-profile");
    let html = std::fs::read_to_string(page).unwrap_or_else(|e| panic!("{}: {e}", page.display()));
    let probe = "<script>window.addEventListener('load',()=>{const i=Array.from(document.images);\
                 document.body.setAttribute('data-images',i.length);\
                 document.body.setAttribute('data-broken-images',\
                 i.filter(x=>!(x.complete&&x.naturalWidth>0)).length);});</script>";
    let probed = page.with_file_name(format!(
        ".probe-{}-{}",
        std::process::id(),
        page.file_name()
            .and_then(|n| n.to_str())
            .unwrap_or("page.html")
    ));
    std::fs::write(&probed, html.replace("</body>", &format!("{probe}</body>")))
        .expect("writing the probed copy");
    let run = |extra: &[String], target: &Path| {
        let out = Command::new(CHROMIUM)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--hide-scrollbars",
                "--virtual-time-budget=5000",
            ])
            .arg(format!("--user-data-dir={}", profile.0.display()))
            .args(extra)
            .arg(format!(
                "file://{}",
                target.canonicalize().expect("page path").display()
            ))
            .output()
            .expect("running chromium");
        assert!(
            out.status.success(),
            "chromium failed on {}: {}",
            target.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let dom = run(&["--dump-dom".to_string()], &probed);
    let _ = std::fs::remove_file(&probed);
    run(
        &[
            "--window-size=1100,2400".to_string(),
            format!("--screenshot={}", screenshot.display()),
        ],
        page,
    );
    let attribute = |name: &str| -> usize {
        let key = format!("{name}=\"");
        let at = dom
            .find(&key)
            .unwrap_or_else(|| panic!("the probe did not run: no {name} in the DOM"))
            + key.len();
        dom[at..]
            .split('"')
            .next()
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{name} is not a count"))
    };
    Rendered {
        images: attribute("data-images"),
        broken_images: attribute("data-broken-images"),
        dom,
        screenshot: screenshot.to_path_buf(),
    }
}

/// How much of a screenshot is drawn on: the share of its pixels that are not
/// near-white, the share of its rows that hold any such pixel, and its size. A blank
/// page scores 0 on both.
pub fn ink(png_path: &Path) -> (f64, f64, (u32, u32)) {
    let file =
        std::fs::File::open(png_path).unwrap_or_else(|e| panic!("{}: {e}", png_path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .expect("a PNG screenshot");
    let mut buf = vec![0; reader.output_buffer_size().expect("PNG size")];
    let info = reader.next_frame(&mut buf).expect("PNG pixels");
    let channels = info.color_type.samples();
    let pixels = &buf[..info.buffer_size()];
    let inked = |p: &[u8]| p.iter().take(3).any(|&v| v < 200);
    let all = pixels.chunks(channels).filter(|p| inked(p)).count();
    let rows = pixels
        .chunks(info.line_size)
        .filter(|row| row.chunks(channels).any(inked))
        .count();
    (
        all as f64 / (pixels.len() / channels) as f64,
        rows as f64 / info.height as f64,
        (info.width, info.height),
    )
}

/// Drive `fpm serve`'s page at `page_url` (the address the service printed, token
/// included) in headless Chromium through `tools/browser/serve-page.mjs` (Playwright's
/// driver, `npm ci` in tools/browser: `.ci/run` does): what the script saw, as JSON.
pub fn drive_service_page(page_url: &str, screenshot: &Path) -> serde_json::Value {
    let tools = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/browser");
    assert!(
        tools.join("node_modules/playwright-core").exists(),
        "playwright-core is not installed: (cd tools/browser && npm ci) — .ci/run does"
    );
    let out = Command::new("node")
        .arg(tools.join("serve-page.mjs"))
        .arg(page_url)
        .arg(screenshot)
        .env("CHROMIUM", CHROMIUM)
        .output()
        .expect("running node");
    assert!(
        out.status.success(),
        "the page's driver failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "the page's driver said no JSON ({e}): {}",
            String::from_utf8_lossy(&out.stdout)
        )
    })
}

/// The mean and standard deviation of a grey PNG's pixels (a page's image, compared
/// with what the browser drew).
pub fn grey_stats(png: &[u8]) -> (f64, f64) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("PNG size")];
    let info = reader.next_frame(&mut buf).expect("PNG pixels");
    let channels = info.color_type.samples();
    let grey: Vec<f64> = buf[..info.buffer_size()]
        .chunks(channels)
        .map(|p| f64::from(p[0]))
        .collect();
    let n = grey.len() as f64;
    let mean = grey.iter().sum::<f64>() / n;
    let var = grey.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}
