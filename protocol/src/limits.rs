//! Hard limits of the wire contract. A device may advertise smaller ones in
//! [`crate::Limits`]; it never accepts larger ones.

/// Largest message (header + body, before COBS) either side sends or accepts.
/// Longer frames are dropped by the receiver and counted in [`crate::LinkStats`].
pub const MAX_FRAME_LEN: usize = 512;

/// Largest COBS-encoded frame including its terminating zero.
pub const MAX_ENCODED_FRAME_LEN: usize = MAX_FRAME_LEN + MAX_FRAME_LEN / 254 + 2;

/// Most LEDs named in one [`crate::SetLeds`] request.
pub const MAX_LEDS_PER_LIST: usize = 64;

/// Most steps carried by one [`crate::StepChunk`].
pub const MAX_STEPS_PER_CHUNK: usize = 24;

/// Most steps a capture sequence may hold (a 21×21 array plus dark and reference frames
/// fits with room to spare).
pub const MAX_SEQUENCE_STEPS: usize = 1024;

/// Most LEDs on a board the protocol can address (rows and columns are `u8`, and the
/// firmware's frame buffer is sized for this).
pub const MAX_LEDS: usize = 1024;

/// Longest board name in [`crate::DeviceInfo`].
pub const MAX_NAME_LEN: usize = 32;

/// Most LED sets the table holds ([`crate::LedSetDefine`]).
pub const MAX_LED_SETS: usize = 256;

/// Most LEDs the LED sets hold together (each LED of a 1024-LED board in one set).
pub const MAX_LED_SET_LEDS: usize = MAX_LEDS;
