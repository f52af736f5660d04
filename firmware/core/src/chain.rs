//! Mapping the LED grid onto the WS2812 data chain, and what a chain update costs.

use fpm_protocol::{BoardGeometry, ChainMajor, ChainStart, LedIndex};

/// Most data lanes the firmware drives (one PIO state machine each on the RP2040).
pub const MAX_LANES: usize = 4;

/// Mirror grid coordinates so that the chain's first LED is at (0, 0). Mirroring is
/// its own inverse, so the same function maps back.
fn from_chain_corner(g: &BoardGeometry, row: u16, col: u16) -> (u16, u16) {
    let (rows, cols) = (g.rows as u16, g.cols as u16);
    let flip_cols = matches!(
        g.chain.start,
        ChainStart::TopRight | ChainStart::BottomRight
    );
    let flip_rows = matches!(
        g.chain.start,
        ChainStart::BottomLeft | ChainStart::BottomRight
    );
    (
        if flip_rows { rows - 1 - row } else { row },
        if flip_cols { cols - 1 - col } else { col },
    )
}

/// Length of one run of the chain (a row or a column).
fn run_len(g: &BoardGeometry) -> u16 {
    match g.chain.major {
        ChainMajor::Rows => g.cols as u16,
        ChainMajor::Columns => g.rows as u16,
    }
}

/// Position of `led` along the data chain, or `None` if it is not on the board.
pub fn chain_index(g: &BoardGeometry, led: LedIndex) -> Option<u16> {
    if !g.contains(led) {
        return None;
    }
    let (r, c) = from_chain_corner(g, led.row as u16, led.col as u16);
    let (run, pos) = match g.chain.major {
        ChainMajor::Rows => (r, c),
        ChainMajor::Columns => (c, r),
    };
    let len = run_len(g);
    let pos = if g.chain.serpentine && run % 2 == 1 {
        len - 1 - pos
    } else {
        pos
    };
    Some(run * len + pos)
}

/// The LED at chain position `index` (inverse of [`chain_index`]).
pub fn led_at(g: &BoardGeometry, index: u16) -> Option<LedIndex> {
    if index >= g.led_count() {
        return None;
    }
    let len = run_len(g);
    let run = index / len;
    let mut pos = index % len;
    if g.chain.serpentine && run % 2 == 1 {
        pos = len - 1 - pos;
    }
    let (r, c) = match g.chain.major {
        ChainMajor::Rows => (run, pos),
        ChainMajor::Columns => (pos, run),
    };
    let (r, c) = from_chain_corner(g, r, c);
    Some(LedIndex::new(r as u8, c as u8))
}

/// LEDs per lane: the chain is cut into `lanes` consecutive runs of this length (the
/// last one may be shorter).
pub fn lane_len(g: &BoardGeometry) -> usize {
    let lanes = (g.lanes as usize).clamp(1, MAX_LANES);
    (g.led_count() as usize).div_ceil(lanes)
}

/// How far each lane must shift so that every LED whose value differs between `old`
/// and `new` is updated: up to and including the last changed LED of the lane.
pub fn shift_lengths(
    g: &BoardGeometry,
    old: &[fpm_protocol::Rgb],
    new: &[fpm_protocol::Rgb],
) -> [u16; MAX_LANES] {
    let mut shift = [0u16; MAX_LANES];
    let per_lane = lane_len(g).max(1);
    let n = (g.led_count() as usize).min(old.len()).min(new.len());
    for (i, (a, b)) in old.iter().zip(new.iter()).take(n).enumerate() {
        if a != b {
            let lane = i / per_lane;
            if let Some(s) = shift.get_mut(lane) {
                *s = (i - lane * per_lane + 1) as u16;
            }
        }
    }
    shift
}

/// Time to shift `shift` LEDs per lane and latch them, µs (0 if nothing shifts). Lanes
/// shift in parallel, so the longest one sets the time.
pub fn update_time_us(shift: &[u16], led_shift_ns: u32, latch_us: u32) -> u64 {
    let longest = shift.iter().copied().max().unwrap_or(0) as u64;
    if longest == 0 {
        return 0;
    }
    (longest * led_shift_ns as u64).div_ceil(1000) + latch_us as u64
}

/// One LED's data word as a WS2812 expects it: green, red, blue, most significant bit
/// first, left-aligned in 32 bits for a 24-bit PIO autopull.
pub const fn grb_word(c: smart_leds::RGB8) -> u32 {
    ((c.g as u32) << 24) | ((c.r as u32) << 16) | ((c.b as u32) << 8)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BoardConfig;
    use fpm_protocol::{ChainOrder, Rgb};

    fn geometry(
        rows: u8,
        cols: u8,
        start: ChainStart,
        major: ChainMajor,
        serp: bool,
    ) -> BoardGeometry {
        let mut g = BoardConfig::PICO_21X21.geometry;
        g.rows = rows;
        g.cols = cols;
        g.center = LedIndex::new(rows / 2, cols / 2);
        g.chain = ChainOrder {
            start,
            major,
            serpentine: serp,
        };
        g
    }

    const STARTS: [ChainStart; 4] = [
        ChainStart::TopLeft,
        ChainStart::TopRight,
        ChainStart::BottomLeft,
        ChainStart::BottomRight,
    ];

    #[test]
    fn every_wiring_is_a_bijection_with_an_inverse() {
        for start in STARTS {
            for major in [ChainMajor::Rows, ChainMajor::Columns] {
                for serp in [false, true] {
                    let g = geometry(5, 7, start, major, serp);
                    let mut seen = [false; 35];
                    for r in 0..5 {
                        for c in 0..7 {
                            let led = LedIndex::new(r, c);
                            let i = chain_index(&g, led).unwrap();
                            assert!(!seen[i as usize], "{start:?} {major:?} {serp}: {i} twice");
                            seen[i as usize] = true;
                            assert_eq!(led_at(&g, i), Some(led));
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn chain_starts_in_its_corner_and_neighbours_are_adjacent() {
        for start in STARTS {
            for major in [ChainMajor::Rows, ChainMajor::Columns] {
                let g = geometry(4, 6, start, major, true);
                let first = led_at(&g, 0).unwrap();
                let corner_row = if matches!(start, ChainStart::TopLeft | ChainStart::TopRight) {
                    0
                } else {
                    3
                };
                let corner_col = if matches!(start, ChainStart::TopLeft | ChainStart::BottomLeft) {
                    0
                } else {
                    5
                };
                assert_eq!(first, LedIndex::new(corner_row, corner_col));
                // Serpentine wiring: consecutive chain LEDs are grid neighbours.
                for i in 1..24 {
                    let a = led_at(&g, i - 1).unwrap();
                    let b = led_at(&g, i).unwrap();
                    let d =
                        (a.row as i32 - b.row as i32).abs() + (a.col as i32 - b.col as i32).abs();
                    assert_eq!(d, 1, "{start:?} {major:?}: chain {i} jumps");
                }
            }
        }
    }

    #[test]
    fn row_major_serpentine_reverses_odd_rows() {
        let g = geometry(21, 21, ChainStart::TopLeft, ChainMajor::Rows, true);
        assert_eq!(chain_index(&g, LedIndex::new(0, 20)), Some(20));
        assert_eq!(chain_index(&g, LedIndex::new(1, 20)), Some(21));
        assert_eq!(chain_index(&g, LedIndex::new(1, 0)), Some(41));
        assert_eq!(chain_index(&g, LedIndex::new(21, 0)), None);
        assert_eq!(led_at(&g, 441), None);
    }

    #[test]
    fn partial_update_shifts_only_to_the_last_change() {
        let g = geometry(21, 21, ChainStart::TopLeft, ChainMajor::Rows, true);
        let old = [Rgb::OFF; 441];
        let mut new = old;
        assert_eq!(shift_lengths(&g, &old, &new), [0; MAX_LANES]);
        new[3] = Rgb::WHITE;
        new[100] = Rgb::WHITE;
        let s = shift_lengths(&g, &old, &new);
        assert_eq!(s[0], 101);
        // 101 LEDs × 30 µs + 280 µs latch
        assert_eq!(update_time_us(&s, 30_000, 280), 3030 + 280);
        // the whole chain: 441 × 30 µs = 13.23 ms + latch
        new[440] = Rgb::WHITE;
        let s = shift_lengths(&g, &old, &new);
        assert_eq!(update_time_us(&s, 30_000, 280), 13_230 + 280);
        assert_eq!(update_time_us(&[0, 0], 30_000, 280), 0);
    }

    #[test]
    fn data_words_are_green_red_blue_from_the_top_bit() {
        use smart_leds::RGB8;
        assert_eq!(grb_word(RGB8::new(0x12, 0x34, 0x56)), 0x3412_5600);
        assert_eq!(
            grb_word(RGB8::new(0, 0x80, 0)) >> 31,
            1,
            "green's MSB goes out first"
        );
    }

    #[test]
    fn lanes_split_the_chain_and_divide_the_time() {
        let mut g = geometry(21, 21, ChainStart::TopLeft, ChainMajor::Rows, true);
        g.lanes = 3;
        assert_eq!(lane_len(&g), 147);
        let old = [Rgb::OFF; 441];
        let mut new = old;
        new[440] = Rgb::WHITE; // last LED of lane 2
        new[146] = Rgb::WHITE; // last LED of lane 0
        new[150] = Rgb::WHITE; // 4th LED of lane 1
        let s = shift_lengths(&g, &old, &new);
        assert_eq!(&s[..3], &[147, 4, 147]);
        assert_eq!(update_time_us(&s, 30_000, 280), 147 * 30 + 280);
    }
}
