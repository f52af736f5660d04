//! The optical system and the LED array (docs/dataset.md §1–2).

use serde::{Deserialize, Serialize};

pub use fpm_protocol::LedIndex;

use crate::led_list::LedList;

/// Microscope and camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct System {
    /// Illumination wavelength, µm.
    pub wavelength_um: f64,
    /// Objective numerical aperture.
    pub na: f64,
    /// Objective magnification.
    pub magnification: f64,
    /// Camera pixel pitch, µm.
    pub pixel_size_um: f64,
    /// Distance from the sample up to the objective's entrance pupil, mm: where the
    /// chief rays of off-axis points aim. `None`: telecentric (chief rays parallel to
    /// the axis). Camera lenses and simple low-power objectives are not telecentric;
    /// their pupil, seen from a point x off the axis, is centred on the direction
    /// −x/p, so every LED's angle to it changes across the field (docs/dataset.md §2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub entrance_pupil_mm: Option<f64>,
}

impl System {
    /// The first value outside the range any microscope's falls in, as (its name, the
    /// value, the range in words): a value outside is a typo or a unit slip (nm for µm)
    /// that would otherwise reconstruct nonsense. None when all are in range.
    pub fn out_of_range(&self) -> Option<(&'static str, f64, &'static str)> {
        let within = |v: f64, lo: f64, hi: f64| v.is_finite() && (lo..=hi).contains(&v);
        [
            (
                "wavelength_um",
                self.wavelength_um,
                within(self.wavelength_um, 0.1, 20.0),
                "must be 0.1-20 µm (a wavelength in µm: 0.47 for blue)",
            ),
            (
                "na",
                self.na,
                self.na.is_finite() && self.na > 0.0 && self.na < 1.0,
                "must be in (0, 1)",
            ),
            (
                "magnification",
                self.magnification,
                within(self.magnification, 0.01, 1000.0),
                "must be 0.01-1000",
            ),
            (
                "pixel_size_um",
                self.pixel_size_um,
                within(self.pixel_size_um, 0.05, 100.0),
                "must be 0.05-100 µm (the camera's pixel pitch)",
            ),
            (
                "entrance_pupil_mm",
                self.entrance_pupil_mm.unwrap_or(1.0),
                self.entrance_pupil_mm
                    .is_none_or(|p| p.is_finite() && p > 0.0),
                "must be a positive distance in mm (absent: telecentric)",
            ),
        ]
        .into_iter()
        .find(|&(_, _, ok, _)| !ok)
        .map(|(name, v, _, why)| (name, v, why))
    }

    /// The pdcFPM paper's microscope: λ 0.47 µm, NA 0.1, 4×, 2.4 µm camera pixels.
    pub const fn paper() -> Self {
        Self {
            wavelength_um: 0.47,
            na: 0.1,
            magnification: 4.0,
            pixel_size_um: 2.4,
            entrance_pupil_mm: None,
        }
    }

    /// The spatial frequency (cycles/µm) of the chief ray at sample point (x, y) µm:
    /// the centre of the pupil as that point sees it. Zero everywhere for a
    /// telecentric objective.
    pub fn chief_ray_frequency(&self, x_um: f64, y_um: f64) -> (f64, f64) {
        match self.entrance_pupil_mm {
            None => (0.0, 0.0),
            Some(p_mm) => {
                let p = p_mm * 1e3;
                let r = (x_um * x_um + y_um * y_um + p * p).sqrt() * self.wavelength_um;
                (-x_um / r, -y_um / r)
            }
        }
    }

    /// Camera pixel projected onto the sample, µm.
    pub fn sample_pixel_um(&self) -> f64 {
        self.pixel_size_um / self.magnification
    }

    /// Pupil cut-off frequency NA/λ, cycles/µm.
    pub fn cutoff(&self) -> f64 {
        self.na / self.wavelength_um
    }

    /// Sample-plane position (µm) of camera pixel (col, row) on a `width × height`
    /// sensor: the optical axis is at (width/2, height/2).
    pub fn pixel_to_sample(&self, col: f64, row: f64, width: usize, height: usize) -> (f64, f64) {
        let d = self.sample_pixel_um();
        (
            (col - (width / 2) as f64) * d,
            (row - (height / 2) as f64) * d,
        )
    }

    /// Inverse of [`Self::pixel_to_sample`].
    pub fn sample_to_pixel(&self, x_um: f64, y_um: f64, width: usize, height: usize) -> (f64, f64) {
        let d = self.sample_pixel_um();
        (
            x_um / d + (width / 2) as f64,
            y_um / d + (height / 2) as f64,
        )
    }
}

/// Unit propagation direction (s_x, s_y, s_z) of light from an LED at `led_mm` = (x, y,
/// distance below the sample), mm, at sample point `at_um`: for LEDs placed one by one
/// (a board with LEDs off its grid); [`LedGeometry::direction`] for a grid.
pub fn direction_from(led_mm: (f64, f64, f64), at_um: (f64, f64)) -> [f64; 3] {
    let v = [
        at_um.0 - led_mm.0 * 1e3,
        at_um.1 - led_mm.1 * 1e3,
        led_mm.2 * 1e3,
    ];
    let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / r, v[1] / r, v[2] / r]
}

/// The most rings a [`Rings`] layout holds.
pub const MAX_RINGS: usize = 16;

/// LEDs on concentric rings instead of a grid (ring arrays, as several labs build
/// their FPM illuminators; docs/dataset.md §1.2): ring r holds `count(r)` LEDs at
/// radius r × pitch, LED j at 360°·j/count(r) from the board's +x toward +y. Ring 0
/// is the centre LED. An LED is (row, col) = (ring, j).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "Vec<u16>", into = "Vec<u16>")]
pub struct Rings {
    counts: [u8; MAX_RINGS],
    len: usize,
}

impl Rings {
    /// Rings of `counts` LEDs, from the centre out: one LED at the centre, each ring
    /// 1–256 LEDs (LED indices are 0–255), at most [`MAX_RINGS`] rings.
    pub fn new(counts: &[u16]) -> Result<Self, crate::Invalid> {
        let invalid = |message: String| crate::Invalid::new("rings", message);
        if counts.is_empty() || counts.len() > MAX_RINGS {
            return Err(invalid(format!(
                "{counts:?}: give 1 to {MAX_RINGS} rings, the centre LED first"
            )));
        }
        if counts[0] != 1 {
            return Err(invalid(format!(
                "{counts:?}: ring 0 is the centre LED alone (1, not {})",
                counts[0]
            )));
        }
        let mut packed = [0u8; MAX_RINGS];
        for (k, &n) in counts.iter().enumerate() {
            if !(1..=256).contains(&n) {
                return Err(invalid(format!(
                    "{counts:?}: ring {k} holds {n} LEDs; each holds 1 to 256"
                )));
            }
            packed[k] = (n - 1) as u8;
        }
        Ok(Self {
            counts: packed,
            len: counts.len(),
        })
    }

    /// Rings, the centre LED's included.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Never: ring 0 always holds the centre LED.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// LEDs on ring `r` (0 beyond the last ring).
    pub fn count(&self, r: usize) -> usize {
        if r < self.len {
            self.counts[r] as usize + 1
        } else {
            0
        }
    }

    /// The most LEDs on one ring.
    pub fn widest(&self) -> usize {
        (0..self.len).map(|r| self.count(r)).max().unwrap_or(0)
    }

    /// The position of `led` on the board in pitches (ring radius, angle).
    fn offset(&self, led: LedIndex) -> (f64, f64) {
        let (r, n) = (led.r() as f64, self.count(led.r()).max(1) as f64);
        let angle = std::f64::consts::TAU * led.c() as f64 / n;
        (r * angle.cos(), r * angle.sin())
    }
}

impl TryFrom<Vec<u16>> for Rings {
    type Error = crate::Invalid;
    fn try_from(counts: Vec<u16>) -> Result<Self, crate::Invalid> {
        Self::new(&counts)
    }
}

impl From<Rings> for Vec<u16> {
    fn from(r: Rings) -> Vec<u16> {
        (0..r.len).map(|k| r.count(k) as u16).collect()
    }
}

/// Where an LED array sits against its nominal place: offset, turn, height and tilt
/// (the six numbers a calibration fits, a refinement's board carries and a simulation
/// hides), or their 1σ. Files carry it flattened: `dx_mm`, `dy_mm`, `theta_deg`,
/// `height_mm`, and `tilt_x_deg`, `tilt_y_deg` (0 when absent). [`LedGeometry`] holds
/// the same numbers beside its grid ([`LedGeometry::placement`],
/// [`LedGeometry::placed_at`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Placement {
    /// Lateral offset Δx, mm.
    pub dx_mm: f64,
    /// Lateral offset Δy, mm.
    pub dy_mm: f64,
    /// Rotation θ about the optical axis, degrees (from +x toward +y).
    pub theta_deg: f64,
    /// Distance from the LED plane to the sample, mm.
    pub height_mm: f64,
    /// Tilt of the board about its x axis through the centre LED, degrees.
    #[serde(default)]
    pub tilt_x_deg: f64,
    /// Tilt about its y axis, degrees.
    #[serde(default)]
    pub tilt_y_deg: f64,
}

impl Placement {
    /// From (Δx, Δy, θ, h, tilt x, tilt y), in the units above.
    pub const fn from_array(v: [f64; 6]) -> Self {
        let [dx_mm, dy_mm, theta_deg, height_mm, tilt_x_deg, tilt_y_deg] = v;
        Self {
            dx_mm,
            dy_mm,
            theta_deg,
            height_mm,
            tilt_x_deg,
            tilt_y_deg,
        }
    }
}
/// A regular LED grid below the sample (docs/dataset.md §1), LEDs on rings
/// ([`Rings`]) or LEDs where a list puts them ([`LedList`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LedGeometry {
    /// Grid rows.
    pub rows: usize,
    /// Grid columns.
    pub cols: usize,
    /// Pitch, mm.
    pub pitch_mm: f64,
    /// Distance from the LED plane to the sample, mm.
    pub height_mm: f64,
    /// Nominal centre LED.
    pub center: LedIndex,
    /// Lateral offset Δx, mm.
    pub dx_mm: f64,
    /// Lateral offset Δy, mm.
    pub dy_mm: f64,
    /// Rotation θ about the optical axis, degrees (from +x toward +y).
    pub theta_deg: f64,
    /// Tilt of the board about its x axis through the centre LED, degrees: LEDs on
    /// the board's +y side sit farther from the sample by y·sin(tilt).
    #[serde(default)]
    pub tilt_x_deg: f64,
    /// Tilt of the board about its y axis through the centre LED, degrees: LEDs on
    /// the board's +x side sit farther from the sample by x·sin(tilt).
    #[serde(default)]
    pub tilt_y_deg: f64,
    /// LEDs on concentric rings `pitch_mm` apart in radius, not on a grid; `rows` is
    /// then the number of rings, `cols` the largest ring's LEDs, `center` (0, 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings: Option<Rings>,
    /// LEDs where a list puts them in the array's own frame, not on a grid; the list's
    /// origin takes the centre LED's place (at (Δx, Δy), `height_mm` below the sample,
    /// θ and the tilts turning about it). `rows`, `cols` bound the ids, `center` is the
    /// LED nearest the origin and `pitch_mm` the typical spacing
    /// ([`LedList::typical_spacing_mm`]), for what needs a grid's numbers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub list: Option<LedList>,
}

impl LedGeometry {
    /// The pdcFPM paper's array, nominally placed: 21×21 LEDs at 2.5 mm, 92 mm below the
    /// sample, centre LED (10, 10), no offset or rotation.
    pub const fn paper() -> Self {
        Self::grid(21, 21, 2.5, 92.0, LedIndex::new(10, 10))
    }

    /// A `rows` × `cols` grid `pitch_mm` apart, `height_mm` below the sample, `center`
    /// on the optical axis: nominally placed (no offset, turn or tilt).
    pub const fn grid(
        rows: usize,
        cols: usize,
        pitch_mm: f64,
        height_mm: f64,
        center: LedIndex,
    ) -> Self {
        Self {
            rows,
            cols,
            pitch_mm,
            height_mm,
            center,
            dx_mm: 0.0,
            dy_mm: 0.0,
            theta_deg: 0.0,
            tilt_x_deg: 0.0,
            tilt_y_deg: 0.0,
            rings: None,
            list: None,
        }
    }

    /// A ring array (`rings`, radii `pitch_mm` apart) at `height_mm`, nominally placed.
    pub fn ring_array(rings: Rings, pitch_mm: f64, height_mm: f64) -> Self {
        Self {
            rings: Some(rings),
            ..Self::grid(
                rings.len(),
                rings.widest(),
                pitch_mm,
                height_mm,
                LedIndex::new(0, 0),
            )
        }
    }

    /// LEDs where `list` puts them, its origin `height_mm` below the sample on the
    /// axis, nominally placed; `pitch_mm` the spacing heuristics use (None: the
    /// list's typical spacing).
    pub fn listed(list: LedList, height_mm: f64, pitch_mm: Option<f64>) -> Self {
        let bound = |f: fn(&crate::led_list::ListedLed) -> u8| {
            list.leds()
                .iter()
                .map(|l| f(l) as usize + 1)
                .max()
                .unwrap_or(1)
        };
        Self {
            list: Some(list),
            ..Self::grid(
                bound(|l| l.led.row),
                bound(|l| l.led.col),
                pitch_mm.unwrap_or_else(|| list.typical_spacing_mm()),
                height_mm,
                list.nearest_origin(),
            )
        }
    }

    /// The same array tilted about its x and y axes (through the centre LED) by
    /// the given angles, degrees.
    pub const fn tilted(self, tilt_x_deg: f64, tilt_y_deg: f64) -> Self {
        Self {
            tilt_x_deg,
            tilt_y_deg,
            ..self
        }
    }

    /// The same array moved by (Δx, Δy) mm, turned by θ degrees, at height h mm.
    pub const fn placed(self, dx_mm: f64, dy_mm: f64, theta_deg: f64, height_mm: f64) -> Self {
        Self {
            dx_mm,
            dy_mm,
            theta_deg,
            height_mm,
            ..self
        }
    }

    /// Where the array sits: its offset, turn, height and tilt.
    pub const fn placement(&self) -> Placement {
        Placement {
            dx_mm: self.dx_mm,
            dy_mm: self.dy_mm,
            theta_deg: self.theta_deg,
            height_mm: self.height_mm,
            tilt_x_deg: self.tilt_x_deg,
            tilt_y_deg: self.tilt_y_deg,
        }
    }

    /// The same grid placed as `p` says (tilt included).
    pub const fn placed_at(self, p: Placement) -> Self {
        Self {
            dx_mm: p.dx_mm,
            dy_mm: p.dy_mm,
            theta_deg: p.theta_deg,
            height_mm: p.height_mm,
            tilt_x_deg: p.tilt_x_deg,
            tilt_y_deg: p.tilt_y_deg,
            ..self
        }
    }

    /// Whether `other` is the same grid (rows, columns, pitch, centre LED), wherever
    /// either is placed.
    pub fn same_grid(&self, other: &LedGeometry) -> bool {
        (self.rows, self.cols, self.center, self.rings, self.list)
            == (
                other.rows,
                other.cols,
                other.center,
                other.rings,
                other.list,
            )
            && (self.pitch_mm - other.pitch_mm).abs() < 1e-6
    }

    /// Whether `led` is on this grid (on its rings, in its list).
    pub fn contains(&self, led: LedIndex) -> bool {
        match (&self.rings, &self.list) {
            (_, Some(list)) => list.get(led).is_some(),
            (Some(rings), None) => led.c() < rings.count(led.r()),
            (None, None) => led.r() < self.rows && led.c() < self.cols,
        }
    }

    /// Every LED, row by row (ring by ring; a list's by id).
    pub fn leds(&self) -> Vec<LedIndex> {
        if let Some(list) = &self.list {
            return list.leds().iter().map(|l| l.led).collect();
        }
        (0..self.rows.min(256))
            .flat_map(|r| (0..self.cols.min(256)).map(move |c| LedIndex::new(r as u8, c as u8)))
            .filter(|&led| self.contains(led))
            .collect()
    }

    /// Board offsets (p, q) of `led` from the centre LED, in pitches: (c − c₀, r − r₀)
    /// on a grid, (r·cos φ, r·sin φ) on rings; from a list's origin, its (x, y) / pitch
    /// (an LED not in the list at the origin).
    pub fn grid_offset(&self, led: LedIndex) -> (f64, f64) {
        if let Some(list) = &self.list {
            return list.get(led).map_or((0.0, 0.0), |l| {
                (l.x_mm / self.pitch_mm, l.y_mm / self.pitch_mm)
            });
        }
        match &self.rings {
            Some(rings) => rings.offset(led),
            None => (
                led.col as f64 - self.center.col as f64,
                led.row as f64 - self.center.row as f64,
            ),
        }
    }

    /// How far a listed LED sits off the board's plane, away from the sample, mm (0
    /// on grids and rings).
    pub fn board_depth_mm(&self, led: LedIndex) -> f64 {
        self.list
            .and_then(|list| list.get(led))
            .map_or(0.0, |l| l.z_mm)
    }

    /// Position (x, y) of `led` in mm.
    pub fn led_position_mm(&self, led: LedIndex) -> (f64, f64) {
        let (x, y, _) = self.led_position_3d_mm(led);
        (x, y)
    }

    /// Position (x, y) of `led` and its distance below the sample plane, mm. The board
    /// is turned by θ in its own plane, then tilted about y and about x through the
    /// centre LED, which sits at (Δx, Δy) and `height_mm` below the sample.
    pub fn led_position_3d_mm(&self, led: LedIndex) -> (f64, f64, f64) {
        let [x, y, depth] = board_offset(
            self.pitch_mm,
            self.theta_deg.to_radians(),
            (self.tilt_x_deg.to_radians(), self.tilt_y_deg.to_radians()),
            self.grid_offset(led),
            self.board_depth_mm(led),
        );
        (x + self.dx_mm, y + self.dy_mm, self.height_mm + depth)
    }

    /// Unit propagation direction (s_x, s_y, s_z) of light from `led` at sample point
    /// (x, y) µm.
    pub fn direction(&self, led: LedIndex, x_um: f64, y_um: f64) -> [f64; 3] {
        direction_from(self.led_position_3d_mm(led), (x_um, y_um))
    }

    /// Illumination spatial frequency f_i = (s_x, s_y)/λ at sample point (x, y),
    /// cycles/µm.
    pub fn illumination_frequency(
        &self,
        led: LedIndex,
        x_um: f64,
        y_um: f64,
        wavelength_um: f64,
    ) -> (f64, f64) {
        let s = self.direction(led, x_um, y_um);
        (s[0] / wavelength_um, s[1] / wavelength_um)
    }

    /// The illumination frequency of `led` at sample point (x, y) relative to the pupil's
    /// centre there ([`System::chief_ray_frequency`]), cycles/µm: where the frame reads
    /// the object's spectrum. The illumination frequency itself for a telecentric
    /// objective.
    pub fn pupil_frequency(
        &self,
        led: LedIndex,
        x_um: f64,
        y_um: f64,
        system: &System,
    ) -> (f64, f64) {
        let f = self.illumination_frequency(led, x_um, y_um, system.wavelength_um);
        let c = system.chief_ray_frequency(x_um, y_um);
        (f.0 - c.0, f.1 - c.1)
    }

    /// Whether `led` is bright-field at sample point (x, y): |f_i − f_chief| < NA/λ.
    pub fn is_bright_field(&self, led: LedIndex, x_um: f64, y_um: f64, system: &System) -> bool {
        let (fx, fy) = self.pupil_frequency(led, x_um, y_um, system);
        (fx * fx + fy * fy).sqrt() < system.cutoff()
    }

    /// Whether `led` is dark-field at every point of the rectangle of half-sides
    /// `half_um` (x, y) centred on the optical axis, µm. The illumination's sine relative
    /// to the chief ray grows with the distance from the point where the two meet (the
    /// point straight above the LED for a telecentric objective; x_led·p/(p + h) with an
    /// entrance pupil at p), so it is smallest at the rectangle's point nearest that one.
    pub fn is_dark_field_everywhere(
        &self,
        led: LedIndex,
        half_um: (f64, f64),
        system: &System,
    ) -> bool {
        let (lx, ly, lh) = self.led_position_3d_mm(led);
        let meet = system.entrance_pupil_mm.map_or(1.0, |p| p / (p + lh));
        let nearest = (
            (lx * 1e3 * meet).clamp(-half_um.0, half_um.0),
            (ly * 1e3 * meet).clamp(-half_um.1, half_um.1),
        );
        !self.is_bright_field(led, nearest.0, nearest.1, system)
    }

    /// Indices into `leds` ordered nearest-first: by |f_i − f_chief| at sample point
    /// `at_um`, equal radii by LED id (a frame repeated keeps its place). This is EPRY's order (it also copes with a
    /// wrongly chosen centre LED) and the acquisition's, so frames arrive in the order
    /// they are used.
    pub fn nearest_first(
        &self,
        leds: &[LedIndex],
        at_um: (f64, f64),
        system: &System,
    ) -> Vec<usize> {
        let radius: Vec<f64> = leds
            .iter()
            .map(|&led| {
                let f = self.pupil_frequency(led, at_um.0, at_um.1, system);
                f.0.hypot(f.1)
            })
            .collect();
        // Equal radii (symmetric LEDs, up to rounding) go by LED id, so the order does
        // not depend on the order of the dataset's frames (docs/dataset.md §5.4): a
        // spiral or a row-major file must reconstruct alike.
        let step = system.cutoff() * 1e-9;
        let mut order: Vec<usize> = (0..leds.len()).collect();
        order.sort_by_key(|&k| ((radius[k] / step).round() as i64, leds[k].row, leds[k].col));
        order
    }

    /// The defocus shift (µm) of a feature at (x, y) under `led` for a sample moved by
    /// `z_um` toward the LEDs: z·(x − x_led, y − y_led)/h (docs/dataset.md §3), with h
    /// the LED's own distance below the sample on a tilted board.
    pub fn defocus_shift_um(&self, led: LedIndex, x_um: f64, y_um: f64, z_um: f64) -> (f64, f64) {
        let (lx, ly, lh) = self.led_position_3d_mm(led);
        let h = lh * 1e3;
        (z_um * (x_um - lx * 1e3) / h, z_um * (y_um - ly * 1e3) / h)
    }
}

/// Where grid offset (p, q), `depth` off the board's plane (away from the sample, in
/// the pitch's units; 0 but for listed LEDs), sits relative to the centre LED on a
/// board of `pitch` turned by `theta` (radians) in its plane and tilted by `tilt`
/// (about x, about y; radians) through the centre LED: (x, y, depth below the centre
/// LED), in the pitch's units. The rotations apply in that order: θ, then about y,
/// then about x.
pub fn board_offset(
    pitch: f64,
    theta: f64,
    tilt: (f64, f64),
    (p, q): (f64, f64),
    depth: f64,
) -> [f64; 3] {
    let (s, c) = theta.sin_cos();
    let (a, b) = (pitch * (p * c - q * s), pitch * (p * s + q * c));
    let (sa, ca) = tilt.0.sin_cos();
    let (sb, cb) = tilt.1.sin_cos();
    // About y first: (a, b, depth) → (a·cos β − depth·sin β, b, a·sin β + depth·cos β).
    let w = a * sb + depth * cb;
    [a * cb - depth * sb, b * ca - w * sa, b * sa + w * ca]
}

/// Angular-spectrum transfer function for propagation by `z_um` at frequency (fx, fy):
/// exp(i2π z √(1/λ² − |f|²)); zero for evanescent frequencies. Returned as (re, im).
pub fn defocus_transfer(fx: f64, fy: f64, z_um: f64, wavelength_um: f64) -> (f64, f64) {
    let arg = 1.0 / (wavelength_um * wavelength_um) - fx * fx - fy * fy;
    if arg <= 0.0 {
        return (0.0, 0.0);
    }
    let phase = 2.0 * std::f64::consts::PI * z_um * arg.sqrt();
    (phase.cos(), phase.sin())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dark_field_everywhere_looks_at_the_point_of_the_field_nearest_the_led() {
        let system = System::paper();
        let g = LedGeometry::paper();
        // The first LED off the axis along x that is dark-field at the axis.
        let col = (g.center.col..g.cols as u8)
            .find(|&c| !g.is_bright_field(LedIndex::new(g.center.row, c), 0.0, 0.0, &system))
            .expect("a dark-field LED");
        let led = LedIndex::new(g.center.row, col);
        let (lx, _) = g.led_position_mm(led);
        // A field reaching halfway to the point under the LED, or all the way to it.
        let half = |x_um: f64| (x_um, x_um);
        assert!(g.is_dark_field_everywhere(led, half(1.0), &system));
        assert!(!g.is_dark_field_everywhere(led, half(lx.abs() * 1e3), &system));
        assert_eq!(
            g.is_dark_field_everywhere(led, half(lx.abs() * 500.0), &system),
            !g.is_bright_field(led, lx * 500.0, 0.0, &system)
        );
    }

    fn geometry() -> LedGeometry {
        LedGeometry::paper()
    }

    /// The paper's grid as a list of its LEDs' board positions.
    fn paper_as_list() -> LedGeometry {
        let grid = LedGeometry::paper();
        let leds = grid
            .leds()
            .into_iter()
            .map(|led| {
                let (p, q) = grid.grid_offset(led);
                crate::ListedLed {
                    led,
                    x_mm: p * grid.pitch_mm,
                    y_mm: q * grid.pitch_mm,
                    z_mm: 0.0,
                }
            })
            .collect();
        let list = LedList::new(leds).expect("a valid list");
        LedGeometry::listed(list, grid.height_mm, None)
    }

    #[test]
    fn the_nearest_first_order_does_not_depend_on_the_frames_order() {
        let (g, system) = (LedGeometry::paper(), System::paper());
        let row_major = g.leds();
        let mut reversed = row_major.clone();
        reversed.reverse();
        let ordered = |leds: &[LedIndex], at: (f64, f64)| -> Vec<LedIndex> {
            g.nearest_first(leds, at, &system)
                .into_iter()
                .map(|k| leds[k])
                .collect()
        };
        for at in [(0.0, 0.0), (150.0, -40.0)] {
            assert_eq!(ordered(&row_major, at), ordered(&reversed, at), "at {at:?}");
        }
        // The four LEDs next to the centre one are equally far: by id.
        let first: Vec<LedIndex> = ordered(&reversed, (0.0, 0.0))[1..5].to_vec();
        let ids = [(9, 10), (10, 9), (10, 11), (11, 10)].map(|(r, c)| LedIndex::new(r, c));
        assert_eq!(first, ids);
    }

    #[test]
    fn a_listed_grid_is_placed_as_the_grid_is() {
        let grid = LedGeometry::paper();
        let listed = paper_as_list();
        assert_eq!(
            (listed.rows, listed.cols, listed.center),
            (21, 21, grid.center)
        );
        assert!((listed.pitch_mm - 2.5).abs() < 1e-12);
        assert_eq!(listed.leds(), grid.leds());
        // The same offset, turn, height and tilt move every LED the same way.
        let p = Placement::from_array([0.7, -0.4, 3.0, 88.0, 1.5, -2.0]);
        let (grid, listed) = (grid.placed_at(p), listed.placed_at(p));
        for led in [
            LedIndex::new(0, 0),
            LedIndex::new(10, 10),
            LedIndex::new(3, 17),
        ] {
            let (a, b) = (grid.led_position_3d_mm(led), listed.led_position_3d_mm(led));
            assert!(
                (a.0 - b.0).abs() + (a.1 - b.1).abs() + (a.2 - b.2).abs() < 1e-9,
                "{led}: grid {a:?}, list {b:?}"
            );
        }
        assert!(!listed.contains(LedIndex::new(21, 0)));
    }

    #[test]
    fn a_listed_led_off_the_board_plane_is_that_much_farther() {
        let list = LedList::new(vec![
            crate::ListedLed {
                led: LedIndex::new(0, 0),
                x_mm: 0.0,
                y_mm: 0.0,
                z_mm: 0.0,
            },
            crate::ListedLed {
                led: LedIndex::new(0, 1),
                x_mm: 10.0,
                y_mm: 0.0,
                z_mm: -30.0,
            },
        ])
        .expect("a valid list");
        let g = LedGeometry::listed(list, 60.0, None);
        let (x, y, h) = g.led_position_3d_mm(LedIndex::new(0, 1));
        assert!((x - 10.0).abs() < 1e-12 && y.abs() < 1e-12 && (h - 30.0).abs() < 1e-12);
        // Tilted 90° about y, the LED's depth turns into −x: the board's normal
        // points along +x then.
        let (x, _, h) = g.tilted(0.0, 90.0).led_position_3d_mm(LedIndex::new(0, 1));
        assert!(
            (x - 30.0).abs() < 1e-9 && (h - 70.0).abs() < 1e-9,
            "{x} {h}"
        );
    }

    #[test]
    fn positions_follow_the_corrected_eq_1() {
        let mut g = geometry();
        g.theta_deg = 90.0;
        g.dx_mm = 1.0;
        // p = 1, q = 0 turns from +x to +y.
        let (x, y) = g.led_position_mm(LedIndex::new(10, 11));
        assert!((x - 1.0).abs() < 1e-12 && (y - 2.5).abs() < 1e-12);
        // p = 0, q = 1 turns from +y to −x.
        let (x, y) = g.led_position_mm(LedIndex::new(11, 10));
        assert!((x - (1.0 - 2.5)).abs() < 1e-12 && y.abs() < 1e-12);
    }

    #[test]
    fn light_from_an_led_at_plus_x_travels_toward_minus_x() {
        let g = geometry();
        let (fx, fy) = g.illumination_frequency(LedIndex::new(10, 11), 0.0, 0.0, 0.47);
        assert!(fx < 0.0 && fy.abs() < 1e-15);
        let expect = -2.5 / (2.5f64.powi(2) + 92.0f64.powi(2)).sqrt() / 0.47;
        assert!((fx - expect).abs() < 1e-12);
        // and a defocused feature moves the same way
        let (sx, _) = g.defocus_shift_um(LedIndex::new(10, 11), 0.0, 0.0, 200.0);
        assert!((sx - (-200.0 * 2.5 / 92.0)).abs() < 1e-9);
    }

    #[test]
    fn bright_field_is_within_the_pupil() {
        let g = geometry();
        let s = System::paper();
        assert!(g.is_bright_field(LedIndex::new(10, 10), 0.0, 0.0, &s));
        // NA 0.1 at 92 mm reaches ρ = 9.25 mm: 3 pitches in, 4 out.
        assert!(g.is_bright_field(LedIndex::new(10, 13), 0.0, 0.0, &s));
        assert!(!g.is_bright_field(LedIndex::new(10, 14), 0.0, 0.0, &s));
    }

    #[test]
    fn pixels_map_to_the_axis_at_half_width() {
        let s = System::paper();
        assert_eq!(s.pixel_to_sample(128.0, 128.0, 256, 256), (0.0, 0.0));
        assert_eq!(s.pixel_to_sample(129.0, 127.0, 256, 256), (0.6, -0.6));
        let (c, r) = s.sample_to_pixel(0.6, -0.6, 256, 256);
        assert!((c - 129.0).abs() < 1e-12 && (r - 127.0).abs() < 1e-12);
    }

    #[test]
    fn propagation_drops_evanescent_waves_and_is_unitary_otherwise() {
        assert_eq!(defocus_transfer(3.0, 0.0, 10.0, 0.47), (0.0, 0.0));
        let (re, im) = defocus_transfer(0.1, 0.05, 123.0, 0.47);
        assert!(((re * re + im * im) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ring_leds_sit_on_their_circles_and_turn_with_the_board() {
        let rings = Rings::new(&[1, 8, 12]).unwrap();
        let g = LedGeometry::ring_array(rings, 9.0, 110.0);
        assert_eq!((g.rows, g.cols, g.leds().len()), (3, 12, 21));
        assert!(g.contains(LedIndex::new(1, 7)) && !g.contains(LedIndex::new(1, 8)));
        // Ring 2, LED 3 of 12: 90° from +x, 18 mm out.
        let (x, y) = g.led_position_mm(LedIndex::new(2, 3));
        assert!(x.abs() < 1e-9 && (y - 18.0).abs() < 1e-9, "({x}, {y})");
        // θ turns it like a grid's LEDs, the offset moves it.
        let turned = g.placed(1.0, -2.0, 90.0, 110.0);
        let (x, y) = turned.led_position_mm(LedIndex::new(1, 0));
        assert!(
            (x - 1.0).abs() < 1e-9 && (y - 7.0).abs() < 1e-9,
            "({x}, {y})"
        );
        assert_eq!(g.led_position_mm(LedIndex::new(0, 0)), (0.0, 0.0));
        assert!(!g.same_grid(&LedGeometry::paper()));
        for bad in [&[][..], &[2, 8], &[1, 0], &[1, 257]] {
            assert!(Rings::new(bad).is_err(), "{bad:?}");
        }
        assert_eq!(Vec::<u16>::from(rings), vec![1, 8, 12]);
    }
}
