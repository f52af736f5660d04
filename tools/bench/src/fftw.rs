//! FFTW 3 (single precision) as a second opinion on the FFT floor, loaded when the
//! benchmark runs (Debian/Ubuntu: `apt install libfftw3-single3`), so that nothing in
//! `fpm` links it. A 2-D complex transform planned with `FFTW_MEASURE`, in place, on
//! FFTW's own aligned buffer, one thread: its best plan for the size.

use std::ffi::{c_char, c_int, c_uint, c_void, CStr};

use anyhow::{anyhow, bail, Context, Result};
use libloading::Library;
use rustfft::num_complex::Complex32;

/// Library names tried, most specific first.
const NAMES: [&str; 2] = ["libfftw3f.so.3", "libfftw3f.so"];
const FFTW_FORWARD: c_int = -1;
const FFTW_BACKWARD: c_int = 1;
const FFTW_MEASURE: c_uint = 0;

type Plan = *mut c_void;
type PlanDft2d =
    unsafe extern "C" fn(c_int, c_int, *mut Complex32, *mut Complex32, c_int, c_uint) -> Plan;
type Execute = unsafe extern "C" fn(Plan);
type DestroyPlan = unsafe extern "C" fn(Plan);
type Malloc = unsafe extern "C" fn(usize) -> *mut c_void;
type Free = unsafe extern "C" fn(*mut c_void);

/// A forward and an inverse `n × n` transform over one buffer.
pub(crate) struct FftwPair {
    n: usize,
    buffer: *mut Complex32,
    forward: Plan,
    inverse: Plan,
    execute: Execute,
    destroy: DestroyPlan,
    free: Free,
    /// FFTW's version string.
    pub version: String,
    // Last: the functions above live in it.
    _library: Library,
}

impl FftwPair {
    /// Load FFTW and plan both transforms for `n × n` (FFTW_MEASURE: it times the
    /// candidates, which takes a moment).
    pub(crate) fn new(n: usize) -> Result<Self> {
        if n == 0 || n > 1 << 15 {
            bail!("{n}: not a size to plan");
        }
        let library = NAMES
            .iter()
            // SAFETY: FFTW's initialisers have no preconditions.
            .find_map(|name| unsafe { Library::new(name) }.ok())
            .ok_or_else(|| {
                anyhow!(
                    "FFTW (single precision) not found as {}: install it for the second opinion (Debian/Ubuntu: apt install libfftw3-single3)",
                    NAMES.join(" or ")
                )
            })?;
        // SAFETY: the signatures are FFTW 3's (fftw3.h), `fftwf_complex` is `float[2]`,
        // laid out as `Complex32`.
        unsafe {
            let plan_2d: PlanDft2d = *library.get::<PlanDft2d>(b"fftwf_plan_dft_2d\0")?;
            let execute: Execute = *library.get::<Execute>(b"fftwf_execute\0")?;
            let destroy: DestroyPlan = *library.get::<DestroyPlan>(b"fftwf_destroy_plan\0")?;
            let malloc: Malloc = *library.get::<Malloc>(b"fftwf_malloc\0")?;
            let free: Free = *library.get::<Free>(b"fftwf_free\0")?;
            let version = library
                .get::<*const c_char>(b"fftwf_version\0")
                .ok()
                .map(|v| CStr::from_ptr(*v as *const c_char))
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "FFTW 3".into());
            let buffer = malloc(n * n * std::mem::size_of::<Complex32>()) as *mut Complex32;
            if buffer.is_null() {
                bail!("fftwf_malloc of {n}² complex values failed");
            }
            let side = n as c_int;
            let forward = plan_2d(side, side, buffer, buffer, FFTW_FORWARD, FFTW_MEASURE);
            let inverse = plan_2d(side, side, buffer, buffer, FFTW_BACKWARD, FFTW_MEASURE);
            let pair = Self {
                n,
                buffer,
                forward,
                inverse,
                execute,
                destroy,
                free,
                version,
                _library: library,
            };
            if forward.is_null() || inverse.is_null() {
                bail!("FFTW could not plan a {n}² transform");
            }
            Ok(pair)
        }
    }

    /// FFTW's buffer (planning overwrote it: fill it before use).
    pub(crate) fn buffer(&mut self) -> &mut [Complex32] {
        // SAFETY: `buffer` holds n² values, owned by self, and `&mut self` is unique.
        unsafe { std::slice::from_raw_parts_mut(self.buffer, self.n * self.n) }
    }

    /// The forward transform of the buffer, in place (unnormalised).
    #[cfg(test)]
    fn forward(&mut self) {
        // SAFETY: the plan was made for this buffer, which lives as long as self.
        unsafe { (self.execute)(self.forward) }
    }

    /// The forward then the inverse transform (unnormalised: the values grow by n²).
    pub(crate) fn pair(&mut self) {
        // SAFETY: as in `forward`.
        unsafe {
            (self.execute)(self.forward);
            (self.execute)(self.inverse);
        }
    }
}

impl Drop for FftwPair {
    fn drop(&mut self) {
        // SAFETY: made by this library for this object; nothing else holds them.
        unsafe {
            if !self.forward.is_null() {
                (self.destroy)(self.forward);
            }
            if !self.inverse.is_null() {
                (self.destroy)(self.inverse);
            }
            (self.free)(self.buffer as *mut c_void);
        }
    }
}

/// The FFTW pair for `n`, or why there is none (said, not fatal: a second opinion).
pub(crate) fn load(n: usize) -> std::result::Result<FftwPair, String> {
    FftwPair::new(n)
        .context("FFTW")
        .map_err(|e| format!("{e:#}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FFTW computes the same transform as rustfft (so timing one against the other
    /// compares like with like). The library comes with the test stacks `.ci/run`
    /// installs.
    #[test]
    fn fftw_transforms_as_rustfft_does() {
        let n = 64;
        let mut fftw = FftwPair::new(n).expect("FFTW (apt install libfftw3-single3)");
        let input: Vec<Complex32> = (0..n * n)
            .map(|k| {
                Complex32::new(
                    ((k * 37) % 101) as f32 / 101.0,
                    ((k * 11) % 17) as f32 / 17.0,
                )
            })
            .collect();
        fftw.buffer().copy_from_slice(&input);
        fftw.forward();
        // rustfft: rows, then columns.
        let plan = rustfft::FftPlanner::new().plan_fft_forward(n);
        let mut reference = input.clone();
        for row in reference.chunks_mut(n) {
            plan.process(row);
        }
        let mut column = vec![Complex32::default(); n];
        for c in 0..n {
            for r in 0..n {
                column[r] = reference[r * n + c];
            }
            plan.process(&mut column);
            for r in 0..n {
                reference[r * n + c] = column[r];
            }
        }
        let scale = reference.iter().map(|v| v.norm()).fold(0.0f32, f32::max);
        let worst = fftw
            .buffer()
            .iter()
            .zip(&reference)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5 * scale,
            "FFTW and rustfft differ by {worst} (scale {scale})"
        );
        // Forward then inverse gives n² times the input.
        fftw.buffer().copy_from_slice(&input);
        fftw.pair();
        let n2 = (n * n) as f32;
        let back = fftw
            .buffer()
            .iter()
            .zip(&input)
            .map(|(a, b)| (a / n2 - b).norm())
            .fold(0.0f32, f32::max);
        assert!(back < 1e-5, "the pair does not come back: {back}");
    }
}
