//! A small safe layer over libaravis: open a camera by id or address, set and read its
//! features, stream into buffers the driver owns. Everything runs on one thread; each
//! object releases its GObject reference when dropped.

mod ffi;

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::sync::Arc;
use std::time::Duration;

use ffi::Api;

/// A failed aravis call: which step, and what aravis said.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{what}: {message}")]
pub struct AravisError {
    /// The step that failed (e.g. "setting PixelFormat to Mono12Packed").
    pub what: String,
    /// aravis's message.
    pub message: String,
}

type Result<T> = std::result::Result<T, AravisError>;

fn error(what: impl Into<String>, message: impl Into<String>) -> AravisError {
    AravisError {
        what: what.into(),
        message: message.into(),
    }
}

/// The loaded library.
pub struct Aravis {
    api: Arc<Api>,
}

/// A camera as the device list reports it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DeviceInfo {
    /// The id to open it by.
    pub id: String,
    /// Its address (IP for GigE Vision, bus path for USB3 Vision).
    pub address: String,
    /// Vendor.
    pub vendor: String,
    /// Model.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// "GigEVision", "USB3Vision", ...
    pub protocol: String,
}

fn text(p: *const c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: aravis returns NUL-terminated strings that live at least until the
        // next call on the same object; copied at once.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}

fn c_string(what: &str, s: &str) -> Result<CString> {
    CString::new(s).map_err(|_| error(what, format!("{s:?} contains a NUL byte")))
}

impl Aravis {
    /// Load libaravis 0.8.
    pub fn load() -> Result<Self> {
        let api = Api::load().map_err(|m| error("loading libaravis", m))?;
        Ok(Self { api: Arc::new(api) })
    }

    /// The library's version.
    pub fn version(&self) -> (u32, u32, u32) {
        // SAFETY: plain getters without arguments.
        unsafe {
            (
                (self.api.arv_get_major_version)(),
                (self.api.arv_get_minor_version)(),
                (self.api.arv_get_micro_version)(),
            )
        }
    }

    /// Every camera aravis finds. **Sends GigE Vision discovery broadcasts on every
    /// network interface** (and enumerates USB3 Vision devices); to reach one known
    /// camera without any broadcast, [`Aravis::open`] it by address.
    pub fn discover(&self) -> Vec<DeviceInfo> {
        let api = &self.api;
        // SAFETY: the index stays below arv_get_n_devices; the strings are copied.
        unsafe {
            (api.arv_update_device_list)();
            (0..(api.arv_get_n_devices)())
                .map(|i| DeviceInfo {
                    id: text((api.arv_get_device_id)(i)),
                    address: text((api.arv_get_device_address)(i)),
                    vendor: text((api.arv_get_device_vendor)(i)),
                    model: text((api.arv_get_device_model)(i)),
                    serial: text((api.arv_get_device_serial_nbr)(i)),
                    protocol: text((api.arv_get_device_protocol)(i)),
                })
                .collect()
        }
    }

    /// Open a camera by its device id or its IP address. By address, aravis talks to
    /// that address only (no discovery broadcast) and has the camera stream to the
    /// interface that reaches it.
    pub fn open(&self, id_or_address: &str) -> Result<Camera> {
        let what = format!("opening camera {id_or_address}");
        let name = c_string(&what, id_or_address)?;
        let api = self.api.clone();
        let ptr = call(&api, &what, |e| unsafe {
            // SAFETY: a valid C string and error slot.
            (api.arv_camera_new)(name.as_ptr(), e)
        })?;
        if ptr.is_null() {
            return Err(error(what, "no such camera"));
        }
        Ok(Camera { api, ptr })
    }
}

/// Run an aravis call with a GError slot; a set error becomes an [`AravisError`].
fn call<T>(api: &Api, what: &str, f: impl FnOnce(ffi::Err) -> T) -> Result<T> {
    let mut err: *mut ffi::GError = std::ptr::null_mut();
    let out = f(&mut err);
    if err.is_null() {
        return Ok(out);
    }
    // SAFETY: aravis set a valid GError, which we own and free once read.
    let message = unsafe {
        let m = text((*err).message);
        (api.g_error_free)(err);
        m
    };
    Err(error(what, message))
}

/// An open camera.
pub struct Camera {
    api: Arc<Api>,
    ptr: *mut ffi::Camera,
}

impl Drop for Camera {
    fn drop(&mut self) {
        // SAFETY: we hold one reference, from arv_camera_new.
        unsafe { (self.api.g_object_unref)(self.ptr) }
    }
}

macro_rules! getter_text {
    ($(#[$doc:meta])* $name:ident, $f:ident, $what:literal) => {
        $(#[$doc])*
        pub fn $name(&self) -> Result<String> {
            let p = call(&self.api, $what, |e| unsafe { (self.api.$f)(self.ptr, e) })?;
            Ok(text(p))
        }
    };
}

impl Camera {
    getter_text!(
        /// Vendor name.
        vendor, arv_camera_get_vendor_name, "reading the vendor name");
    getter_text!(
        /// Model name.
        model, arv_camera_get_model_name, "reading the model name");
    getter_text!(
        /// Serial number.
        serial, arv_camera_get_device_serial_number, "reading the serial number");
    getter_text!(
        /// Device id.
        device_id, arv_camera_get_device_id, "reading the device id");
    getter_text!(
        /// The pixel format's name (e.g. "Mono12Packed").
        pixel_format, arv_camera_get_pixel_format_as_string, "reading PixelFormat");

    /// Whether this is a GigE Vision camera.
    pub fn is_gige(&self) -> bool {
        // SAFETY: a live camera.
        unsafe { (self.api.arv_camera_is_gv_device)(self.ptr) != 0 }
    }

    /// Sensor size, pixels.
    pub fn sensor_size(&self) -> Result<(i32, i32)> {
        let (mut w, mut h): (c_int, c_int) = (0, 0);
        call(&self.api, "reading the sensor size", |e| unsafe {
            (self.api.arv_camera_get_sensor_size)(self.ptr, &mut w, &mut h, e)
        })?;
        Ok((w, h))
    }

    /// Set the region of interest.
    pub fn set_region(&self, x: i32, y: i32, width: i32, height: i32) -> Result<()> {
        call(&self.api, "setting the region of interest", |e| unsafe {
            (self.api.arv_camera_set_region)(self.ptr, x, y, width, height, e)
        })
    }

    /// The region of interest (x, y, width, height).
    pub fn region(&self) -> Result<(i32, i32, i32, i32)> {
        let (mut x, mut y, mut w, mut h): (c_int, c_int, c_int, c_int) = (0, 0, 0, 0);
        call(&self.api, "reading the region of interest", |e| unsafe {
            (self.api.arv_camera_get_region)(self.ptr, &mut x, &mut y, &mut w, &mut h, e)
        })?;
        Ok((x, y, w, h))
    }

    /// Set the binning.
    pub fn set_binning(&self, dx: i32, dy: i32) -> Result<()> {
        call(&self.api, "setting the binning", |e| unsafe {
            (self.api.arv_camera_set_binning)(self.ptr, dx, dy, e)
        })
    }

    /// The binning (horizontal, vertical).
    pub fn binning(&self) -> Result<(i32, i32)> {
        let (mut dx, mut dy): (c_int, c_int) = (0, 0);
        call(&self.api, "reading the binning", |e| unsafe {
            (self.api.arv_camera_get_binning)(self.ptr, &mut dx, &mut dy, e)
        })?;
        Ok((dx, dy))
    }

    /// Set PixelFormat by name.
    pub fn set_pixel_format(&self, name: &str) -> Result<()> {
        let what = format!("setting PixelFormat to {name}");
        let c = c_string(&what, name)?;
        call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_set_pixel_format_from_string)(self.ptr, c.as_ptr(), e)
        })
    }

    /// The pixel formats the camera offers.
    pub fn pixel_formats(&self) -> Result<Vec<String>> {
        let mut n: u32 = 0;
        let list = call(&self.api, "listing pixel formats", |e| unsafe {
            (self.api.arv_camera_dup_available_pixel_formats_as_strings)(self.ptr, &mut n, e)
        })?;
        if list.is_null() {
            return Ok(vec![]);
        }
        // SAFETY: `n` entries; the container is ours to free, the strings are not.
        unsafe {
            let names = (0..n as usize).map(|i| text(*list.add(i))).collect();
            (self.api.g_free)(list as *mut c_void);
            Ok(names)
        }
    }

    /// Set the exposure time, µs.
    pub fn set_exposure_us(&self, us: f64) -> Result<()> {
        call(&self.api, "setting the exposure time", |e| unsafe {
            (self.api.arv_camera_set_exposure_time)(self.ptr, us, e)
        })
    }

    /// The exposure time, µs.
    pub fn exposure_us(&self) -> Result<f64> {
        call(&self.api, "reading the exposure time", |e| unsafe {
            (self.api.arv_camera_get_exposure_time)(self.ptr, e)
        })
    }

    /// Whether the camera has a gain control.
    pub fn gain_available(&self) -> Result<bool> {
        call(&self.api, "checking for a gain control", |e| unsafe {
            (self.api.arv_camera_is_gain_available)(self.ptr, e) != 0
        })
    }

    /// Set the gain (the camera's unit, usually dB).
    pub fn set_gain(&self, gain: f64) -> Result<()> {
        call(&self.api, "setting the gain", |e| unsafe {
            (self.api.arv_camera_set_gain)(self.ptr, gain, e)
        })
    }

    /// The gain.
    pub fn gain(&self) -> Result<f64> {
        call(&self.api, "reading the gain", |e| unsafe {
            (self.api.arv_camera_get_gain)(self.ptr, e)
        })
    }

    /// Trigger each frame from `source` ("Line0", "Software", ...): TriggerMode On for
    /// FrameStart, every other trigger off.
    pub fn set_trigger(&self, source: &str) -> Result<()> {
        let what = format!("setting the trigger to {source}");
        let c = c_string(&what, source)?;
        call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_set_trigger)(self.ptr, c.as_ptr(), e)
        })
    }

    /// Free-running: every trigger off.
    pub fn clear_triggers(&self) -> Result<()> {
        call(&self.api, "switching triggers off", |e| unsafe {
            (self.api.arv_camera_clear_triggers)(self.ptr, e)
        })
    }

    /// Fire a software trigger.
    pub fn software_trigger(&self) -> Result<()> {
        call(&self.api, "firing a software trigger", |e| unsafe {
            (self.api.arv_camera_software_trigger)(self.ptr, e)
        })
    }

    /// Set a string or enumeration feature.
    pub fn set_string(&self, feature: &str, value: &str) -> Result<()> {
        let what = format!("setting {feature} to {value}");
        let f = c_string(&what, feature)?;
        let v = c_string(&what, value)?;
        call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_set_string)(self.ptr, f.as_ptr(), v.as_ptr(), e)
        })
    }

    /// Read a string or enumeration feature.
    pub fn string(&self, feature: &str) -> Result<String> {
        let what = format!("reading {feature}");
        let f = c_string(&what, feature)?;
        let p = call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_get_string)(self.ptr, f.as_ptr(), e)
        })?;
        Ok(text(p))
    }

    /// Read a float feature.
    pub fn float(&self, feature: &str) -> Result<f64> {
        let what = format!("reading {feature}");
        let f = c_string(&what, feature)?;
        call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_get_float)(self.ptr, f.as_ptr(), e)
        })
    }

    /// Read a boolean feature.
    pub fn boolean(&self, feature: &str) -> Result<bool> {
        let what = format!("reading {feature}");
        let f = c_string(&what, feature)?;
        call(&self.api, &what, |e| unsafe {
            (self.api.arv_camera_get_boolean)(self.ptr, f.as_ptr(), e) != 0
        })
    }

    /// Whether the camera has `feature` and it is available now.
    pub fn has_feature(&self, feature: &str) -> bool {
        let Ok(f) = CString::new(feature) else {
            return false;
        };
        call(&self.api, "", |e| unsafe {
            (self.api.arv_camera_is_feature_available)(self.ptr, f.as_ptr(), e) != 0
        })
        .unwrap_or(false)
    }

    /// Bytes per frame.
    pub fn payload(&self) -> Result<usize> {
        call(&self.api, "reading the payload size", |e| unsafe {
            (self.api.arv_camera_get_payload)(self.ptr, e) as usize
        })
    }

    /// A stream for this camera's frames (its receive thread starts at once).
    pub fn stream(&self) -> Result<Stream> {
        let ptr = call(&self.api, "creating the stream", |e| unsafe {
            (self.api.arv_camera_create_stream)(
                self.ptr,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                e,
            )
        })?;
        if ptr.is_null() {
            return Err(error("creating the stream", "aravis returned no stream"));
        }
        Ok(Stream {
            api: self.api.clone(),
            ptr,
            gige: self.is_gige(),
        })
    }

    /// Start acquiring.
    pub fn start(&self) -> Result<()> {
        call(&self.api, "starting the acquisition", |e| unsafe {
            (self.api.arv_camera_start_acquisition)(self.ptr, e)
        })
    }

    /// Stop acquiring.
    pub fn stop(&self) -> Result<()> {
        call(&self.api, "stopping the acquisition", |e| unsafe {
            (self.api.arv_camera_stop_acquisition)(self.ptr, e)
        })
    }
}

/// A stream's counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct StreamStats {
    /// Buffers filled completely.
    pub completed: u64,
    /// Buffers that failed (missing packets, timeouts, size mismatch).
    pub failures: u64,
    /// Frames lost because no buffer was free.
    pub underruns: u64,
    /// GigE Vision: packets the camera sent again on request.
    pub resent_packets: u64,
    /// GigE Vision: packets never received.
    pub missing_packets: u64,
}

/// A camera's frame stream.
pub struct Stream {
    api: Arc<Api>,
    ptr: *mut ffi::Stream,
    gige: bool,
}

impl Drop for Stream {
    fn drop(&mut self) {
        // SAFETY: we hold one reference, from arv_camera_create_stream; its thread
        // stops and its queued buffers are freed with it.
        unsafe { (self.api.g_object_unref)(self.ptr) }
    }
}

impl Stream {
    /// Give the stream a buffer to fill.
    pub fn push(&self, buffer: Buffer) {
        // SAFETY: ownership of the buffer's reference passes to the stream.
        unsafe { (self.api.arv_stream_push_buffer)(self.ptr, buffer.ptr) };
        std::mem::forget(buffer);
    }

    /// A new buffer of `size` bytes for this stream.
    pub fn new_buffer(&self, size: usize) -> Result<Buffer> {
        // SAFETY: plain allocation.
        let ptr = unsafe { (self.api.arv_buffer_new_allocate)(size) };
        if ptr.is_null() {
            return Err(error("allocating a frame buffer", format!("{size} bytes")));
        }
        Ok(Buffer {
            api: self.api.clone(),
            ptr,
        })
    }

    /// The next filled buffer (successful or not), or None after `timeout`.
    pub fn pop(&self, timeout: Duration) -> Option<Buffer> {
        // SAFETY: a live stream; a returned buffer's reference is ours.
        let ptr = unsafe {
            (self.api.arv_stream_timeout_pop_buffer)(self.ptr, timeout.as_micros() as u64)
        };
        (!ptr.is_null()).then(|| Buffer {
            api: self.api.clone(),
            ptr,
        })
    }

    /// The stream's counters so far.
    pub fn stats(&self) -> StreamStats {
        let mut s = StreamStats::default();
        // SAFETY: a live stream; a GigE Vision stream is an ArvGvStream.
        unsafe {
            (self.api.arv_stream_get_statistics)(
                self.ptr,
                &mut s.completed,
                &mut s.failures,
                &mut s.underruns,
            );
            if self.gige {
                (self.api.arv_gv_stream_get_statistics)(
                    self.ptr,
                    &mut s.resent_packets,
                    &mut s.missing_packets,
                );
            }
        }
        s
    }
}

/// A frame buffer, filled by the stream.
pub struct Buffer {
    api: Arc<Api>,
    ptr: *mut ffi::Buffer,
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // SAFETY: we hold one reference.
        unsafe { (self.api.g_object_unref)(self.ptr) }
    }
}

impl Buffer {
    /// Whether the frame arrived whole.
    pub fn is_complete(&self) -> bool {
        // SAFETY: a live buffer.
        unsafe { (self.api.arv_buffer_get_status)(self.ptr) == ffi::BUFFER_STATUS_SUCCESS }
    }

    /// aravis's status code (0 = success, 3 = missing packets, ...).
    pub fn status(&self) -> i32 {
        // SAFETY: a live buffer.
        unsafe { (self.api.arv_buffer_get_status)(self.ptr) }
    }

    /// The frame's bytes as the camera sent them.
    pub fn data(&self) -> &[u8] {
        let mut size = 0usize;
        // SAFETY: aravis returns the buffer's data and its filled size; the memory
        // lives as long as the buffer, which this borrow cannot outlive.
        unsafe {
            let p = (self.api.arv_buffer_get_data)(self.ptr, &mut size) as *const u8;
            if p.is_null() {
                &[]
            } else {
                std::slice::from_raw_parts(p, size)
            }
        }
    }

    /// The camera's timestamp of the frame, ns (its own clock).
    pub fn timestamp_ns(&self) -> u64 {
        // SAFETY: a live buffer.
        unsafe { (self.api.arv_buffer_get_timestamp)(self.ptr) }
    }

    /// When the host received the frame, ns since the Unix epoch.
    pub fn system_timestamp_ns(&self) -> u64 {
        // SAFETY: a live buffer.
        unsafe { (self.api.arv_buffer_get_system_timestamp)(self.ptr) }
    }

    /// The camera's frame (block) id.
    pub fn frame_id(&self) -> u64 {
        // SAFETY: a live buffer.
        unsafe { (self.api.arv_buffer_get_frame_id)(self.ptr) }
    }

    /// Image width, height and PFNC pixel format.
    pub fn image(&self) -> (u32, u32, u32) {
        // SAFETY: a live, successfully filled buffer (callers check is_complete).
        unsafe {
            (
                (self.api.arv_buffer_get_image_width)(self.ptr).max(0) as u32,
                (self.api.arv_buffer_get_image_height)(self.ptr).max(0) as u32,
                (self.api.arv_buffer_get_image_pixel_format)(self.ptr),
            )
        }
    }
}
