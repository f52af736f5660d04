//! `fpm device flash` end to end, on the real firmware image in an emulated RP2040 and
//! a stand-in for the RP2040 boot ROM's drive: a directory laid out as RPI-RP2
//! (INFO_UF2.TXT, INDEX.HTM) that appears when the board leaves its serial port for
//! BOOTSEL, takes a UF2 copied onto it as the boot ROM does (checked block by block)
//! and starts the board again from that image.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use fpm_protocol::PROTOCOL_VERSION;
use fpm_tests::{firmware_uf2, fpm_bin, Emulator, TempDir};

/// What the RP2040's boot ROM (B1) writes in INFO_UF2.TXT.
const INFO_UF2: &str = "UF2 Bootloader v3.0\nModel: Raspberry Pi RP2\nBoard-ID: RPI-RP2\n";

/// `fpm device --port PORT --json flash ARGS…`: success, stdout, stderr.
fn flash(port: &Path, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(fpm_bin())
        .args(["device", "--port"])
        .arg(port)
        .args(["--json", "flash"])
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The boot drive's side: once `board` has left its port, the drive appears at
/// `drive`; the first whole UF2 written onto it is checked as the boot ROM checks it,
/// the drive goes (the ROM restarts the chip), and the board starts from the image.
fn boot_rom(mut board: Emulator, link: PathBuf, drive: PathBuf) -> (Emulator, PathBuf) {
    let left = board.exited_within(Duration::from_secs(60));
    assert!(
        left.is_some_and(|s| s.success()),
        "the board did not leave for BOOTSEL ({left:?}):\n{}",
        board.log_text()
    );
    // Gone with its link, before the board comes back on the same path.
    drop(board);
    std::fs::create_dir_all(&drive).unwrap();
    std::fs::write(drive.join("INFO_UF2.TXT"), INFO_UF2).unwrap();
    std::fs::write(
        drive.join("INDEX.HTM"),
        "<html><head><meta http-equiv=\"refresh\" content=\"0;URL='https://raspberrypi.com/device/RP2?version=E0C9125B0D9B'\"/></head><body>Redirecting to <a href='https://raspberrypi.com/device/RP2?version=E0C9125B0D9B'>raspberrypi.com</a></body></html>",
    )
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    let image = loop {
        let written = std::fs::read_dir(&drive)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .find(|p| p.extension().is_some_and(|e| e == "uf2"));
        if let Some(p) = written.filter(|p| fpm_flash::check_image(p).is_ok()) {
            break p;
        }
        assert!(
            Instant::now() < deadline,
            "no whole UF2 was copied onto the drive"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    // The ROM has written it to flash and restarts: the drive goes, the board comes
    // back from the image.
    let flashed = drive.with_extension("flashed.uf2");
    std::fs::rename(&image, &flashed).unwrap();
    std::fs::remove_dir_all(&drive).unwrap();
    let flashed_arg = flashed.to_string_lossy().into_owned();
    let back = Emulator::start_at(&link, &["--firmware", &flashed_arg, "--no-camera"]);
    (back, flashed)
}

#[test]
fn a_board_in_the_rig_is_flashed_in_place_and_a_wrong_image_never_darkens_it() {
    let dir = TempDir::new("flash");
    let link = dir.0.join("ctl.tty");
    let uf2 = firmware_uf2().to_string_lossy().into_owned();
    let board = Emulator::start_at(&link, &["--firmware", &uf2, "--no-camera"]);

    // An image for another chip is refused before the board is touched.
    let mut other = std::fs::read(&uf2).unwrap();
    for block in other.chunks_exact_mut(512) {
        block[28..32].copy_from_slice(&0xADA5_2840u32.to_le_bytes()); // the nRF52840's family
    }
    let wrong = dir.0.join("nrf52840.uf2");
    std::fs::write(&wrong, &other).unwrap();
    let (ok, _, err) = flash(&link, &[wrong.to_str().unwrap(), "--wait-s", "5"]);
    assert!(!ok);
    assert!(
        err.contains("block 0 (byte 0)") && err.contains("another chip"),
        "{err}"
    );
    let dev = fpm_acquire::Controller::open(&link.to_string_lossy(), Duration::from_secs(2))
        .expect("the board still answers after a refused image");
    drop(dev);

    // The real image: restarted in BOOTSEL, copied onto the drive, back in this
    // host's protocol.
    let drive = dir.0.join("RPI-RP2");
    // `fpm device flash` on a thread of its own; the boot drive's side on this one (the
    // board it starts again is stopped when the thread that started it ends).
    let flashing = {
        let (link, uf2, drive) = (link.clone(), uf2.clone(), drive.clone());
        std::thread::spawn(move || {
            flash(
                &link,
                &[&uf2, "--drive", drive.to_str().unwrap(), "--wait-s", "60"],
            )
        })
    };
    let (back, flashed) = boot_rom(board, link.clone(), drive.clone());
    let (ok, out, err) = flashing.join().unwrap();
    assert!(ok, "{err}\n{}", back.log_text());
    for step in 1..=5 {
        assert!(err.contains(&format!("[{step}/5]")), "{err}");
    }
    let done: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(done["after"][1], PROTOCOL_VERSION.to_string(), "{done}");
    assert_eq!(done["before"][0], done["after"][0], "{done}");
    assert_eq!(
        done["image"]["blocks"].as_u64().unwrap() * 512,
        std::fs::metadata(&flashed).unwrap().len(),
        "{done}"
    );
    // The drive got the image byte for byte, and the board runs it.
    assert_eq!(
        std::fs::read(&flashed).unwrap(),
        std::fs::read(&uf2).unwrap()
    );
    assert!(
        back.log_text()
            .contains(&flashed.to_string_lossy().into_owned()),
        "{}",
        back.log_text()
    );
}
