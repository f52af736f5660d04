use fpm_protocol::{BoardCalibration, PlacementSigma, StorageError, StoredCalibration};

use super::{CalibrationStore, RamNor};

/// Two sectors of store after one sector of something else, as on the board where the
/// store sits at the end of the flash.
type Nor = RamNor<{ 3 * 4096 }>;
const BASE: u32 = 4096;

fn calibration(i: u32) -> BoardCalibration {
    BoardCalibration {
        dx_mm: 0.1 * i as f32,
        dy_mm: -0.02 * i as f32,
        theta_deg: 1.5,
        height_mm: 90.0 + i as f32 * 1e-3,
        sigma: PlacementSigma {
            dx_mm: 1e-3,
            dy_mm: 2e-3,
            theta_deg: 0.01,
            height_mm: 0.05,
        },
        rms_residual_um: 0.4,
        calibrated_unix_s: 1_796_000_000 + i as u64,
    }
}

fn stored(i: u32) -> StoredCalibration {
    StoredCalibration::Calibrated(calibration(i))
}

#[test]
fn a_new_board_is_not_calibrated_and_keeps_what_it_is_given() {
    let mut store = CalibrationStore::new(Nor::erased(), BASE);
    assert_eq!(store.load(), StoredCalibration::NotCalibrated);
    assert_eq!(store.save(Some(&calibration(1))), Ok(stored(1)));
    assert_eq!(store.load(), stored(1));
    // Read again from the bytes alone, as after a reset.
    let image = *store.flash().image();
    let mut again = CalibrationStore::new(Nor::from_image(&image), BASE);
    assert_eq!(again.load(), stored(1));
    assert_eq!(again.save(None), Ok(StoredCalibration::NotCalibrated));
    assert_eq!(again.load(), StoredCalibration::NotCalibrated);
    // Nothing outside the region was touched.
    assert!(again.flash().image()[..BASE as usize]
        .iter()
        .all(|&b| b == 0xFF));
}

#[test]
fn hundreds_of_writes_rotate_between_the_sectors() {
    let mut store = CalibrationStore::new(Nor::erased(), BASE);
    let mut erases = 0;
    for i in 1..=500 {
        let before = store.flash().ops();
        assert_eq!(
            store.save(Some(&calibration(i))),
            Ok(stored(i)),
            "write {i}"
        );
        // A write either appends (record bytes only) or rotates (one sector erased).
        if store.flash().ops() - before > 4096 {
            erases += 1;
        }
        assert_eq!(store.load(), stored(i));
    }
    // ~50 bytes a record: ~80 records per 4 KiB sector.
    assert!(
        (5..=8).contains(&erases),
        "{erases} sector erases for 500 writes"
    );
}

/// The heart of it: cut the power after every possible number of byte operations of
/// a write (appends, the first write, and rotations with their erase), and the store
/// reads the old record or the new one, and takes the next write.
#[test]
fn a_power_cut_at_any_moment_leaves_the_old_or_the_new_record() {
    // Which writes rotate (erase the other sector) in an uninterrupted history.
    let mut rotating = vec![];
    let mut store = CalibrationStore::new(Nor::erased(), BASE);
    for i in 1..=200u32 {
        let before = store.flash().ops();
        store.save(Some(&calibration(i))).unwrap();
        if i > 1 && store.flash().ops() - before > 4096 {
            rotating.push(i);
        }
    }
    assert!(rotating.len() >= 2, "rotations at {rotating:?}");
    // Histories ending just before: the first write, an append, the first rotation,
    // the first append after it, and the rotation back to the first sector.
    for history in [0u32, 3, rotating[0] - 1, rotating[0], rotating[1] - 1] {
        let mut store = CalibrationStore::new(Nor::erased(), BASE);
        for i in 1..=history {
            store.save(Some(&calibration(i))).unwrap();
        }
        let image = *store.flash().image();
        let old = store.load();
        let new = stored(history + 1);
        // How many byte operations the uninterrupted write takes.
        let total = {
            let mut probe = CalibrationStore::new(Nor::from_image(&image), BASE);
            probe.save(Some(&calibration(history + 1))).unwrap();
            probe.flash().ops()
        };
        assert!(total > 0);
        let mut seen_old = false;
        for cut in 0..total {
            let mut nor = Nor::from_image(&image);
            nor.cut_power_after(cut);
            let mut store = CalibrationStore::new(nor, BASE);
            assert_eq!(
                store.save(Some(&calibration(history + 1))),
                Err(StorageError::Flash),
                "history {history}, cut after {cut} of {total}"
            );
            let mut nor = Nor::from_image(store.flash().image());
            nor.restore_power();
            let mut store = CalibrationStore::new(nor, BASE);
            let read = store.load();
            // Before the first write there is no old record: a torn first write reads
            // as not calibrated or damaged, never as a calibration.
            let acceptable =
                read == old || read == new || (history == 0 && read == StoredCalibration::Damaged);
            assert!(
                acceptable,
                "history {history}, cut after {cut} of {total}: read {read:?}"
            );
            seen_old |= read == old;
            // And the store goes on working.
            assert_eq!(store.save(Some(&calibration(999))), Ok(stored(999)));
            assert_eq!(store.load(), stored(999));
        }
        assert!(seen_old, "history {history}: no cut left the old record");
    }
}

#[test]
fn a_damaged_region_reads_as_damaged_and_recovers_on_the_next_write() {
    let mut image = [0xFFu8; 3 * 4096];
    for (i, b) in image[BASE as usize..].iter_mut().enumerate() {
        *b = (i * 7 + 3) as u8;
    }
    let mut store = CalibrationStore::new(Nor::from_image(&image), BASE);
    assert_eq!(store.load(), StoredCalibration::Damaged);
    assert_eq!(store.save(Some(&calibration(1))), Ok(stored(1)));
    assert_eq!(store.load(), stored(1));
}

#[test]
fn a_flipped_bit_in_the_newest_record_falls_back_to_the_one_before() {
    let mut store = CalibrationStore::new(Nor::erased(), BASE);
    store.save(Some(&calibration(1))).unwrap();
    store.save(Some(&calibration(2))).unwrap();
    let mut image = *store.flash().image();
    // Second record starts where the first ends; flip a bit in its payload.
    let first_len = {
        let mut probe = CalibrationStore::new(Nor::erased(), BASE);
        probe.save(Some(&calibration(1))).unwrap();
        probe.flash().ops()
    };
    image[BASE as usize + first_len + 12] ^= 0x10;
    let mut store = CalibrationStore::new(Nor::from_image(&image), BASE);
    assert_eq!(store.load(), stored(1));
    // The damaged tail is never written over: the next write rotates.
    assert_eq!(store.save(Some(&calibration(3))), Ok(stored(3)));
    assert_eq!(store.load(), stored(3));
}

#[test]
fn unusable_numbers_and_regions_are_refused() {
    let mut store = CalibrationStore::new(Nor::erased(), BASE);
    for bad in [
        BoardCalibration {
            height_mm: 0.0,
            ..calibration(1)
        },
        BoardCalibration {
            dx_mm: f32::NAN,
            ..calibration(1)
        },
        BoardCalibration {
            sigma: PlacementSigma {
                dy_mm: -1.0,
                ..PlacementSigma::default()
            },
            ..calibration(1)
        },
    ] {
        assert_eq!(store.save(Some(&bad)), Err(StorageError::Invalid));
    }
    assert_eq!(store.load(), StoredCalibration::NotCalibrated);
    // Misaligned, or past the end of the chip.
    for base in [100, 2 * 4096] {
        let mut store = CalibrationStore::new(Nor::erased(), base);
        assert_eq!(
            store.save(Some(&calibration(1))),
            Err(StorageError::NoStorage)
        );
        assert_eq!(store.load(), StoredCalibration::NotCalibrated);
    }
}
