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

/// `fpm device --port PORT --json flash ARGS…` with the boot ROM's PICOBOOT interface
/// at `socket`: success, stdout, stderr.
fn flash_over(port: &Path, socket: &Path, args: &[&str]) -> (bool, String, String) {
    let socket = socket.to_string_lossy().into_owned();
    flash(port, &[args, &["--boot-rom-socket", &socket]].concat())
}

/// The board the boot ROM restarts: the chip started (in rp2040js, at `link`) from what
/// `rom`'s flash holds, written as a UF2 into `dir`.
fn start_from_flash(rom: &fpm_rig::boot_rom::BootRom, dir: &Path, link: &Path) -> Emulator {
    let from_flash = dir.join("flash.uf2");
    std::fs::write(&from_flash, rom.flash_as_uf2()).unwrap();
    Emulator::start_at(
        link,
        &["--firmware", &from_flash.to_string_lossy(), "--no-camera"],
    )
}

/// The image's flash pages, as the boot ROM holds them once written.
fn pages(uf2: &Path) -> Vec<fpm_flash::picoboot::Page> {
    fpm_flash::check_image(uf2).unwrap().pages
}

/// A board in the rig runs the 2-lane image; `fpm device flash`, given the 1-lane
/// image's ELF, restarts it in BOOTSEL and writes that image over PICOBOOT to the
/// emulated boot ROM, which held the 2-lane image. Every page is read back, the boot loader's last; the ROM restarts;
/// the board comes back from what its flash now holds, answering as the 1-lane image.
#[test]
fn a_board_in_the_rig_is_flashed_over_picoboot_and_comes_back_from_its_flash() {
    let dir = TempDir::new("picoboot");
    let link = dir.0.join("ctl.tty");
    let socket = dir.0.join("picoboot.sock");
    let (old, new) = (
        fpm_tests::firmware_uf2_with_lanes(2),
        fpm_tests::firmware_uf2_with_lanes(1),
    );
    let board = Emulator::start_at(
        &link,
        &["--firmware", &old.to_string_lossy(), "--no-camera"],
    );
    let flashing = {
        // The ELF beside its UF2, as the firmware's build leaves it.
        let (link, socket, elf) = (link.clone(), socket.clone(), new.with_extension(""));
        std::thread::spawn(move || {
            flash_over(&link, &socket, &[&elf.to_string_lossy(), "--wait-s", "60"])
        })
    };
    // The board leaves its port for BOOTSEL; its boot ROM appears with the old image.
    let mut board = board;
    let left = board.exited_within(Duration::from_secs(60));
    assert!(left.is_some_and(|s| s.success()), "{}", board.log_text());
    drop(board);
    let rom = fpm_rig::boot_rom::BootRom::with_pages(&pages(old), Default::default());
    assert!(rom.would_boot(), "the old image boots");
    let deadline = Instant::now() + Duration::from_secs(120);
    let rom = fpm_rig::boot_rom::serve(&socket, rom, &|| Instant::now() > deadline).unwrap();
    assert!(rom.rebooted, "the flasher did not restart the boot ROM");
    assert_eq!(rom.exclusive, 2, "exclusive access, the drive ejected");
    assert!(
        rom.holds(&pages(new)),
        "the flash is not exactly the new image"
    );
    assert!(rom.would_boot());
    let back = start_from_flash(&rom, &dir.0, &link);
    let (ok, out, err) = flashing.join().unwrap();
    assert!(ok, "{err}\n{}", back.log_text());
    for step in 1..=5 {
        assert!(err.contains(&format!("[{step}/5]")), "{err}");
    }
    let done: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(done["via"], "picoboot", "{done}");
    assert_eq!(
        done["verified_pages"].as_u64(),
        Some(pages(new).len() as u64),
        "{done}"
    );
    assert_eq!(done["after"][1], PROTOCOL_VERSION.to_string(), "{done}");
    let dev = fpm_acquire::Controller::open(&link.to_string_lossy(), Duration::from_secs(5))
        .expect("the flashed board answers");
    assert_eq!(dev.info().geometry.lanes, 1, "the board runs the new image");
}

/// A board in BOOTSEL with a bootable image, and a write that goes wrong each way: a
/// page the ROM refuses, a page that reads back wrong (the boot loader's own too), the
/// device gone half-way through a page. Each ends with the step and the way out, and
/// leaves a flash the ROM does not boot: never half of each image.
#[test]
fn a_picoboot_write_that_fails_leaves_no_image_the_boot_rom_would_start() {
    use fpm_rig::boot_rom::{serve, BootRom, Faults};
    let dir = TempDir::new("picoboot-faults");
    let socket = dir.0.join("picoboot.sock");
    let no_board = dir.0.join("no-board.tty");
    let (old, new) = (
        pages(fpm_tests::firmware_uf2_with_lanes(2)),
        fpm_tests::firmware_uf2_with_lanes(1),
    );
    let middle = pages(new)[pages(new).len() / 2].0;
    let boot_page = fpm_flash::picoboot::FLASH.start;
    let cases = [
        (
            Faults {
                refuse_write_at: Some(middle),
                ..Faults::default()
            },
            format!("refused writing 256 bytes at {middle:#010x} (UnknownError)"),
        ),
        (
            Faults {
                corrupt_at: Some(middle + 17),
                ..Faults::default()
            },
            format!("reading back {middle:#010x}: byte 17 of the page"),
        ),
        (
            Faults {
                corrupt_at: Some(boot_page + 3),
                ..Faults::default()
            },
            format!("reading back {boot_page:#010x}: byte 3 of the page"),
        ),
        (
            Faults {
                vanish_in_write: Some(9),
                ..Faults::default()
            },
            "the device is gone".to_owned(),
        ),
    ];
    for (faults, says) in cases {
        let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let rom = {
            let (socket, old, done) = (socket.clone(), old.clone(), done.clone());
            std::thread::spawn(move || {
                let stop = || done.load(std::sync::atomic::Ordering::SeqCst);
                serve(&socket, BootRom::with_pages(&old, faults), &stop).unwrap()
            })
        };
        let listening = Instant::now() + Duration::from_secs(10);
        while !socket.exists() {
            assert!(Instant::now() < listening, "the boot ROM never listened");
            std::thread::sleep(Duration::from_millis(10));
        }
        let (ok, _, err) = flash_over(
            &no_board,
            &socket,
            &[&new.to_string_lossy(), "--wait-s", "10"],
        );
        done.store(true, std::sync::atomic::Ordering::SeqCst);
        let rom = rom.join().unwrap();
        assert!(!ok, "{faults:?}: flashed");
        assert!(err.contains(&says), "{faults:?}: {err}");
        assert!(
            err.contains("[3/5]") && err.contains("stays in BOOTSEL"),
            "{faults:?}: {err}"
        );
        assert!(!rom.would_boot(), "{faults:?}: the ROM would start the mix");
        assert!(!rom.rebooted, "{faults:?}");
    }
}

/// The emulated boot ROM keeps the real one's rules, so that the flasher is judged by
/// them: sector-aligned erases and page-aligned writes inside the flash, a refused
/// command stalling until the interface is reset with its status readable, and NOR
/// flash (a page written twice without its erase reads back wrong).
#[test]
fn the_emulated_boot_rom_keeps_the_roms_rules() {
    use fpm_flash::picoboot::{Picoboot, PicobootError, StatusCode, FLASH};
    let rom = fpm_rig::boot_rom::BootRom::with_pages(&[], Default::default());
    let mut boot = Picoboot::new(rom).unwrap();
    let refused = |r: Result<(), PicobootError>| match r {
        Err(PicobootError::Refused { code, .. }) => code,
        other => panic!("not refused: {other:?}"),
    };
    assert_eq!(
        refused(boot.erase(FLASH.start + 256, 4096)),
        StatusCode::BadAlignment
    );
    assert_eq!(
        refused(boot.erase(FLASH.end, 4096)),
        StatusCode::InvalidAddress
    );
    assert_eq!(
        refused(boot.write(FLASH.start + 8, &[0; 256])),
        StatusCode::BadAlignment
    );
    assert_eq!(
        refused(boot.write(FLASH.start, &[0; 100])),
        StatusCode::BadAlignment
    );
    // After each refusal the next command goes through.
    boot.erase(FLASH.start, 4096).unwrap();
    let page: Vec<u8> = (0..=255).collect();
    boot.write(FLASH.start, &page).unwrap();
    assert_eq!(boot.read(FLASH.start, 256).unwrap(), page);
    let other: Vec<u8> = (0..=255).rev().collect();
    boot.write(FLASH.start, &other).unwrap();
    let read = boot.read(FLASH.start, 256).unwrap();
    assert!(
        read != other
            && read
                .iter()
                .zip(&page)
                .zip(&other)
                .all(|((r, a), b)| *r == a & b),
        "NOR flash: a second write only clears bits"
    );
    boot.reboot(0).unwrap();
    assert!(matches!(
        boot.read(FLASH.start, 4),
        Err(PicobootError::Transport { .. })
    ));
}

/// A new Pico (its flash erased, in BOOTSEL) flashed with no image given: the firmware
/// of the checkout `fpm` was built from is built (cargo finds it up to date after the
/// suite's own build) for one data lane, no board answering to say otherwise, and
/// written over PICOBOOT; the board then starts from its flash.
#[test]
fn a_new_pico_is_flashed_with_the_firmware_of_this_checkout() {
    let dir = TempDir::new("picoboot-new");
    let link = dir.0.join("ctl.tty");
    let socket = dir.0.join("picoboot.sock");
    let built = pages(firmware_uf2());
    let flashing = {
        let (link, socket) = (link.clone(), socket.clone());
        std::thread::spawn(move || flash_over(&link, &socket, &["--wait-s", "120"]))
    };
    let deadline = Instant::now() + Duration::from_secs(300);
    let rom = fpm_rig::boot_rom::serve(
        &socket,
        fpm_rig::boot_rom::BootRom::with_pages(&[], Default::default()),
        &|| Instant::now() > deadline,
    )
    .unwrap();
    assert!(rom.rebooted, "the flasher did not restart the boot ROM");
    assert!(rom.holds(&built), "the flash is not this checkout's image");
    let back = start_from_flash(&rom, &dir.0, &link);
    let (ok, out, err) = flashing.join().unwrap();
    assert!(ok, "{err}\n{}", back.log_text());
    assert!(
        err.contains("building the firmware of")
            && err.contains("1 data lane(s) (no board answers"),
        "{err}"
    );
    let done: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(done["before"].is_null(), "{done}");
    assert!(
        done["image"]["path"]
            .as_str()
            .is_some_and(|p| p.ends_with("/fpm-led-controller.uf2")),
        "{done}"
    );
    assert_eq!(done["after"][1], PROTOCOL_VERSION.to_string(), "{done}");
}
