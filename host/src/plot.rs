//! Minimal raster plots (no fonts): enough to see a calibration's residuals at a glance.

/// An RGB canvas.
pub struct Canvas {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

impl Canvas {
    /// A white canvas.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            rgb: vec![255; width * height * 3],
        }
    }

    /// Set one pixel (clipped).
    pub fn dot(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            let i = (y as usize * self.width + x as usize) * 3;
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A line (Bresenham), `thick` pixels wide.
    pub fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: [u8; 3], thick: i64) {
        let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let (x, y) = (
                (x0 + t * (x1 - x0)).round() as i64,
                (y0 + t * (y1 - y0)).round() as i64,
            );
            for dx in -(thick / 2)..=(thick / 2) {
                for dy in -(thick / 2)..=(thick / 2) {
                    self.dot(x + dx, y + dy, c);
                }
            }
        }
    }

    /// A circle outline of radius `r`.
    pub fn circle(&mut self, (cx, cy): (f64, f64), r: f64, c: [u8; 3]) {
        let n = (r * 8.0).ceil().max(16.0) as usize;
        for k in 0..n {
            let a = k as f64 / n as f64 * std::f64::consts::TAU;
            self.dot(
                (cx + r * a.cos()).round() as i64,
                (cy + r * a.sin()).round() as i64,
                c,
            );
        }
    }

    /// A cross of half-size `r`.
    pub fn cross(&mut self, (cx, cy): (f64, f64), r: f64, c: [u8; 3]) {
        self.line((cx - r, cy - r), (cx + r, cy + r), c, 1);
        self.line((cx - r, cy + r), (cx + r, cy - r), c, 1);
    }
}

/// One LED on a residual plot: measured and fitted shift (µm), and whether it was used.
pub struct ShiftPoint {
    /// Measured (bias-corrected) shift.
    pub measured: [f64; 2],
    /// Fitted shift.
    pub fitted: [f64; 2],
    /// In the fit.
    pub used: bool,
}

/// Plot measured shifts (crosses) against fitted ones (circles) in the sample plane,
/// with residual vectors (red) magnified `gain` times; left-out LEDs in grey.
/// Returns the canvas and the magnification used.
pub fn residual_plot(points: &[ShiftPoint], size: usize) -> (Canvas, f64) {
    let mut c = Canvas::new(size, size);
    let extent = points
        .iter()
        .flat_map(|p| {
            [
                p.measured[0].abs(),
                p.measured[1].abs(),
                p.fitted[0].abs(),
                p.fitted[1].abs(),
            ]
        })
        .fold(1e-9, f64::max)
        * 1.15;
    let scale = (size as f64 / 2.0) / extent;
    let to_px = |v: [f64; 2]| {
        (
            size as f64 / 2.0 + v[0] * scale,
            size as f64 / 2.0 + v[1] * scale,
        )
    };
    // axes through zero shift
    let mid = size as f64 / 2.0;
    c.line((0.0, mid), (size as f64, mid), [200, 200, 200], 1);
    c.line((mid, 0.0), (mid, size as f64), [200, 200, 200], 1);
    let worst = points
        .iter()
        .filter(|p| p.used)
        .map(|p| (p.measured[0] - p.fitted[0]).hypot(p.measured[1] - p.fitted[1]))
        .fold(1e-12, f64::max);
    // Magnify residuals so the largest used one is 1/12 of the plot.
    let gain = (size as f64 / 12.0) / (worst * scale);
    for p in points {
        let (fp, mp) = (to_px(p.fitted), to_px(p.measured));
        if p.used {
            c.circle(fp, 6.0, [40, 90, 200]);
            let tip = (fp.0 + (mp.0 - fp.0) * gain, fp.1 + (mp.1 - fp.1) * gain);
            c.line(fp, tip, [220, 30, 30], 2);
            c.cross(mp, 3.0, [0, 0, 0]);
        } else {
            c.circle(fp, 6.0, [170, 170, 170]);
            c.cross(mp, 3.0, [170, 170, 170]);
        }
    }
    (c, gain)
}
