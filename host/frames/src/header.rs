//! The frame header, shared byte for byte with camera drivers in other languages.

use iceoryx2::prelude::*;

/// Sent with every frame. Offsets (bytes, little-endian on the machines we run on):
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | u64 | `frame_number` |
/// | 8 | u64 | `timestamp_ns` |
/// | 16 | u32 | `exposure_us` |
/// | 20 | u32 | `width` |
/// | 24 | u32 | `height` |
/// | 28 | u32 | `bit_depth` |
/// | 32 | u64 | `pixel_count` |
/// | 40 | u32 | `camera_id` |
/// | 44 | u32 | `flags` |
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("fpm::FrameHeader/1")]
#[repr(C)]
pub struct FrameHeader {
    /// Consecutive per camera from 0; a gap is a dropped frame.
    pub frame_number: u64,
    /// Start of exposure on the camera's clock, ns.
    pub timestamp_ns: u64,
    /// Exposure time, µs.
    pub exposure_us: u32,
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Significant bits per pixel (1–16), counted from bit 0.
    pub bit_depth: u32,
    /// Pixels in the payload (= width · height). Carried explicitly because the
    /// iceoryx2 Python binding reports a slice's length in bytes (upstream #1533).
    pub pixel_count: u64,
    /// Which camera (0 for a single-camera rig).
    pub camera_id: u32,
    /// Reserved, 0.
    pub flags: u32,
}

impl FrameHeader {
    /// The iceoryx2 type name a publisher in another language must declare.
    pub const TYPE_NAME: &'static str = "fpm::FrameHeader/1";
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{offset_of, size_of};

    #[test]
    fn the_layout_is_the_documented_one() {
        assert_eq!(size_of::<FrameHeader>(), 48);
        assert_eq!(offset_of!(FrameHeader, frame_number), 0);
        assert_eq!(offset_of!(FrameHeader, timestamp_ns), 8);
        assert_eq!(offset_of!(FrameHeader, exposure_us), 16);
        assert_eq!(offset_of!(FrameHeader, width), 20);
        assert_eq!(offset_of!(FrameHeader, height), 24);
        assert_eq!(offset_of!(FrameHeader, bit_depth), 28);
        assert_eq!(offset_of!(FrameHeader, pixel_count), 32);
        assert_eq!(offset_of!(FrameHeader, camera_id), 40);
        assert_eq!(offset_of!(FrameHeader, flags), 44);
    }
}
