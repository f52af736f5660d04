//! The part of libaravis 0.8's C API the driver uses, loaded at run time.
//!
//! Loaded with `dlopen` rather than linked, so `fpm` builds and runs everywhere and
//! only `fpm camera` needs the library (Debian/Ubuntu: `libaravis-0.8-0`). Signatures
//! follow `arvcamera.h`, `arvstream.h`, `arvgvstream.h`, `arvbuffer.h` and
//! `arvsystem.h` of aravis 0.8 (stable across 0.8.x); glib's symbols come through
//! libaravis's own dependency on libglib.

use std::ffi::{c_char, c_double, c_int, c_uint, c_void};

use libloading::Library;

/// `GError`.
#[repr(C)]
pub struct GError {
    pub domain: u32,
    pub code: c_int,
    pub message: *const c_char,
}

pub type Err = *mut *mut GError;
/// Opaque GObjects.
pub type Camera = c_void;
pub type Stream = c_void;
pub type Buffer = c_void;

/// `ARV_BUFFER_STATUS_SUCCESS`.
pub const BUFFER_STATUS_SUCCESS: c_int = 0;

/// Library names tried, newest ABI first.
pub const LIBRARY_NAMES: &[&str] = &["libaravis-0.8.so.0", "libaravis-0.8.so"];

macro_rules! symbols {
    ($( $name:ident : fn($($arg:ty),*) $(-> $ret:ty)? ; )*) => {
        /// Function pointers into libaravis (valid while `_library` is loaded).
        #[allow(non_snake_case)]
        pub struct Api {
            $( pub $name: unsafe extern "C" fn($($arg),*) $(-> $ret)?, )*
            _library: Library,
        }

        impl Api {
            /// Load the library and every symbol; the error names what is missing.
            pub fn load() -> Result<Self, String> {
                let mut last = String::new();
                for name in LIBRARY_NAMES {
                    // SAFETY: loading libaravis runs its (glib) initialisers, which are
                    // safe to run in any process.
                    match unsafe { Library::new(name) } {
                        Ok(library) => return Self::bind(library),
                        Err(e) => last = e.to_string(),
                    }
                }
                Err(format!(
                    "libaravis 0.8 is not installed ({last}); on Debian or Ubuntu: apt install libaravis-0.8-0"
                ))
            }

            fn bind(library: Library) -> Result<Self, String> {
                // SAFETY: each symbol is declared with its C signature from aravis 0.8's
                // headers; the pointers live as long as `library`, which Api owns.
                unsafe {
                    Ok(Self {
                        $( $name: *library
                            .get::<unsafe extern "C" fn($($arg),*) $(-> $ret)?>(
                                concat!(stringify!($name), "\0").as_bytes(),
                            )
                            .map_err(|e| format!("libaravis lacks {}: {e}", stringify!($name)))?, )*
                        _library: library,
                    })
                }
            }
        }
    };
}

symbols! {
    arv_get_major_version: fn() -> c_uint;
    arv_get_minor_version: fn() -> c_uint;
    arv_get_micro_version: fn() -> c_uint;
    arv_update_device_list: fn();
    arv_get_n_devices: fn() -> c_uint;
    arv_get_device_id: fn(c_uint) -> *const c_char;
    arv_get_device_address: fn(c_uint) -> *const c_char;
    arv_get_device_vendor: fn(c_uint) -> *const c_char;
    arv_get_device_model: fn(c_uint) -> *const c_char;
    arv_get_device_serial_nbr: fn(c_uint) -> *const c_char;
    arv_get_device_protocol: fn(c_uint) -> *const c_char;

    arv_camera_new: fn(*const c_char, Err) -> *mut Camera;
    arv_camera_get_vendor_name: fn(*mut Camera, Err) -> *const c_char;
    arv_camera_get_model_name: fn(*mut Camera, Err) -> *const c_char;
    arv_camera_get_device_serial_number: fn(*mut Camera, Err) -> *const c_char;
    arv_camera_get_device_id: fn(*mut Camera, Err) -> *const c_char;
    arv_camera_is_gv_device: fn(*mut Camera) -> c_int;
    arv_camera_get_sensor_size: fn(*mut Camera, *mut c_int, *mut c_int, Err);
    arv_camera_set_region: fn(*mut Camera, c_int, c_int, c_int, c_int, Err);
    arv_camera_get_region: fn(*mut Camera, *mut c_int, *mut c_int, *mut c_int, *mut c_int, Err);
    arv_camera_set_binning: fn(*mut Camera, c_int, c_int, Err);
    arv_camera_get_binning: fn(*mut Camera, *mut c_int, *mut c_int, Err);
    arv_camera_set_pixel_format_from_string: fn(*mut Camera, *const c_char, Err);
    arv_camera_get_pixel_format_as_string: fn(*mut Camera, Err) -> *const c_char;
    arv_camera_dup_available_pixel_formats_as_strings: fn(*mut Camera, *mut c_uint, Err) -> *mut *const c_char;
    arv_camera_set_exposure_time: fn(*mut Camera, c_double, Err);
    arv_camera_get_exposure_time: fn(*mut Camera, Err) -> c_double;
    arv_camera_is_gain_available: fn(*mut Camera, Err) -> c_int;
    arv_camera_set_gain: fn(*mut Camera, c_double, Err);
    arv_camera_get_gain: fn(*mut Camera, Err) -> c_double;
    arv_camera_set_trigger: fn(*mut Camera, *const c_char, Err);
    arv_camera_clear_triggers: fn(*mut Camera, Err);
    arv_camera_software_trigger: fn(*mut Camera, Err);
    arv_camera_set_string: fn(*mut Camera, *const c_char, *const c_char, Err);
    arv_camera_get_string: fn(*mut Camera, *const c_char, Err) -> *const c_char;
    arv_camera_get_float: fn(*mut Camera, *const c_char, Err) -> c_double;
    arv_camera_get_boolean: fn(*mut Camera, *const c_char, Err) -> c_int;
    arv_camera_is_feature_available: fn(*mut Camera, *const c_char, Err) -> c_int;
    arv_camera_get_payload: fn(*mut Camera, Err) -> c_uint;
    arv_camera_create_stream: fn(*mut Camera, *mut c_void, *mut c_void, Err) -> *mut Stream;
    arv_camera_start_acquisition: fn(*mut Camera, Err);
    arv_camera_stop_acquisition: fn(*mut Camera, Err);

    arv_stream_push_buffer: fn(*mut Stream, *mut Buffer);
    arv_stream_timeout_pop_buffer: fn(*mut Stream, u64) -> *mut Buffer;
    arv_stream_get_statistics: fn(*mut Stream, *mut u64, *mut u64, *mut u64);
    arv_gv_stream_get_statistics: fn(*mut Stream, *mut u64, *mut u64);

    arv_buffer_new_allocate: fn(usize) -> *mut Buffer;
    arv_buffer_get_status: fn(*mut Buffer) -> c_int;
    arv_buffer_get_data: fn(*mut Buffer, *mut usize) -> *const c_void;
    arv_buffer_get_timestamp: fn(*mut Buffer) -> u64;
    arv_buffer_get_system_timestamp: fn(*mut Buffer) -> u64;
    arv_buffer_get_frame_id: fn(*mut Buffer) -> u64;
    arv_buffer_get_image_width: fn(*mut Buffer) -> c_int;
    arv_buffer_get_image_height: fn(*mut Buffer) -> c_int;
    arv_buffer_get_image_pixel_format: fn(*mut Buffer) -> u32;

    g_object_unref: fn(*mut c_void);
    g_error_free: fn(*mut GError);
    g_free: fn(*mut c_void);
}
