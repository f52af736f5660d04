//! # fpm-doctor
//!
//! `fpm doctor`: the machine checked the way a support thread would, one finding per
//! line, each `ok`, `warn` or `fail` with the action to take. The udev rule and the
//! user's access to the board's port and to an RP2040 waiting in BOOTSEL; the board
//! itself, with its firmware and protocol against this host's; the cameras aravis
//! sees; iceoryx2's shared memory (space, and what crashed processes left); free disk
//! where the service keeps its state and jobs write; and whether the service's port is
//! free or already an fpm service's. Nothing here changes the machine but
//! [`Options::clean_shm`], which removes only dead processes' shared memory.

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::time::Duration;

use fpm_acquire::controller::discover::{self, Candidate};
use fpm_acquire::controller::{Controller, ControllerError};
use fpm_protocol::{PROTOCOL_VERSION, USB_PID, USB_VID};
use serde::Serialize;

/// Where udev rules are looked for, separated like `PATH` (default: udev's own).
pub const UDEV_DIRS_ENV: &str = "FPM_UDEV_RULES_DIRS";

/// udev's rule directories, in the order it reads them.
const UDEV_DIRS: [&str; 4] = [
    "/etc/udev/rules.d",
    "/run/udev/rules.d",
    "/usr/lib/udev/rules.d",
    "/lib/udev/rules.d",
];

/// The RP2040's boot ROM on USB (BOOTSEL held, or asked to reboot into it).
const RP2_BOOT: (&str, &str) = ("2e8a", "0003");

/// Less shared memory than this warns: a 20 MP frame of 16 bits is 40 MB, and the frame
/// service keeps several.
const MIN_SHM_BYTES: u64 = 512 << 20;

/// Less free disk than this warns: a 441-frame set of 1024² is 0.9 GB, its
/// reconstruction's outputs as much again.
const MIN_DISK_BYTES: u64 = 5 << 30;

/// How long the board is given to answer each request.
const BOARD_TIMEOUT: Duration = Duration::from_secs(2);

/// What to look at.
#[derive(Debug, Clone)]
pub struct Options {
    /// The board's serial port (None: every USB port with the board's ids, and those
    /// in `FPM_EXTRA_PORTS`).
    pub port: Option<String>,
    /// Where `fpm serve` keeps its state (its runs are under it).
    pub state_dir: PathBuf,
    /// Further directories jobs write to.
    pub out_dirs: Vec<PathBuf>,
    /// Where `fpm serve` listens.
    pub listen: SocketAddr,
    /// Ask this camera only (an address), instead of every camera aravis discovers
    /// (which broadcasts on the local networks).
    pub camera_address: Option<String>,
    /// Remove the shared memory that dead processes left.
    pub clean_shm: bool,
}

/// How a finding stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Nothing to do.
    Ok,
    /// Works, or not needed yet, but worth the action.
    Warn,
    /// In the way of acquiring: the action is needed.
    Fail,
}

/// One thing found.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    /// What was looked at: `udev`, `board`, `boot device`, `cameras`, `shared memory`,
    /// `disk`, `service port`.
    pub check: &'static str,
    /// How it stands.
    pub status: Status,
    /// What was found.
    pub found: String,
    /// What to do (None when nothing is to be done).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub action: Option<String>,
}

impl Finding {
    fn ok(check: &'static str, found: String) -> Self {
        Self {
            check,
            status: Status::Ok,
            found,
            action: None,
        }
    }

    fn with(check: &'static str, status: Status, found: String, action: String) -> Self {
        Self {
            check,
            status,
            found,
            action: Some(action),
        }
    }
}

/// Every check, in the order a person would go through them.
pub fn examine(options: &Options) -> Vec<Finding> {
    let mut out = vec![udev_rule(&udev_dirs())];
    out.extend(boards(options.port.as_deref()));
    out.push(boot_device(Path::new("/sys/bus/usb/devices")));
    out.push(cameras(options.camera_address.as_deref()));
    out.extend(shared_memory(options.clean_shm));
    let mut dirs = vec![options.state_dir.clone(), options.state_dir.join("runs")];
    dirs.extend(options.out_dirs.iter().cloned());
    out.extend(dirs.iter().map(|d| disk(d)));
    out.push(service_port(options.listen));
    out
}

fn udev_dirs() -> Vec<PathBuf> {
    match std::env::var_os(UDEV_DIRS_ENV) {
        Some(dirs) => std::env::split_paths(&dirs).collect(),
        None => UDEV_DIRS.iter().map(PathBuf::from).collect(),
    }
}

/// The board's udev rule (its vendor and product id in a `.rules` file).
fn udev_rule(dirs: &[PathBuf]) -> Finding {
    let (vid, pid) = (format!("{USB_VID:04x}"), format!("{USB_PID:04x}"));
    let rule_for = |(vid, pid): (&str, &str)| {
        dirs.iter()
            .filter_map(|d| std::fs::read_dir(d).ok())
            .flatten()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.extension().is_some_and(|e| e == "rules"))
            .find(|p| {
                std::fs::read_to_string(p).is_ok_and(|text| {
                    text.lines()
                        .filter(|l| !l.trim_start().starts_with('#'))
                        .any(|l| {
                            l.contains(&format!("\"{vid}\"")) && l.contains(&format!("\"{pid}\""))
                        })
                })
            })
    };
    let install = "sudo cp udev/99-fpm.rules /etc/udev/rules.d/ && sudo udevadm control --reload && sudo udevadm trigger (the rule is in the repository; docs/hardware.md)";
    match (rule_for((&vid, &pid)), rule_for(RP2_BOOT)) {
        (Some(path), Some(_)) => Finding::ok(
            "udev",
            format!(
                "the board's rule (USB {vid}:{pid}, and the boot ROM's {}:{}) is installed: {}",
                RP2_BOOT.0,
                RP2_BOOT.1,
                path.display()
            ),
        ),
        (Some(path), None) => Finding::with(
            "udev",
            Status::Warn,
            format!(
                "{} names the board (USB {vid}:{pid}) but not its boot ROM (USB {}:{}): fpm device flash cannot write over PICOBOOT and copies onto the RPI-RP2 drive instead, unchecked",
                path.display(),
                RP2_BOOT.0,
                RP2_BOOT.1
            ),
            install.into(),
        ),
        (None, _) => Finding::with(
            "udev",
            Status::Warn,
            format!(
                "no udev rule names the board (USB {vid}:{pid}) in {}: its serial port is root's only, and has no stable name",
                dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", ")
            ),
            install.into(),
        ),
    }
}

/// Each board found (or the one named), opened and asked its versions.
fn boards(port: Option<&str>) -> Vec<Finding> {
    let candidates = match port {
        Some(p) => vec![Candidate {
            port: p.to_owned(),
            usb: None,
        }],
        None => discover::candidates(),
    };
    if candidates.is_empty() {
        return vec![Finding::with(
            "board",
            Status::Warn,
            format!("no LED controller found (no USB serial port {USB_VID:04x}:{USB_PID:04x})"),
            format!(
                "plug the board in with a data cable; an emulator or an RS-232 adapter is named with --port or {}",
                discover::EXTRA_PORTS_ENV
            ),
        )];
    }
    candidates.iter().map(|c| board(&c.port)).collect()
}

fn board(port: &str) -> Finding {
    use nix::unistd::{access, AccessFlags};
    match access(port, AccessFlags::R_OK | AccessFlags::W_OK) {
        Err(nix::errno::Errno::EACCES) => {
            return Finding::with(
                "board",
                Status::Fail,
                format!("{port}: this user may not open it"),
                "install the udev rule (above), then unplug and replug the board; or join the port's group (sudo usermod -aG dialout $USER, then log in again)".into(),
            )
        }
        Err(e) => {
            return Finding::with(
                "board",
                Status::Fail,
                format!("{port}: {e}"),
                "check the path (fpm device list shows the boards found)".into(),
            )
        }
        Ok(()) => {}
    }
    match Controller::open(port, BOARD_TIMEOUT) {
        Ok(dev) => {
            let info = dev.info();
            Finding::ok(
                "board",
                format!(
                    "{port}: {} (serial {}), firmware {}, protocol {} (this host speaks {PROTOCOL_VERSION})",
                    info.board, info.serial, info.firmware, info.protocol
                ),
            )
        }
        Err(e @ ControllerError::VersionMismatch { .. }) => Finding::with(
            "board",
            Status::Fail,
            e.to_string(),
            "fpm device flash fpm-led-controller.uf2 puts the firmware this host was built with on it (docs/hardware.md), or install the fpm that matches the board".into(),
        ),
        Err(e @ ControllerError::NotFpm { .. }) => Finding::with(
            "board",
            Status::Warn,
            e.to_string(),
            "if it should be an fpm board, flash its firmware (docs/hardware.md); else leave it out of --port and FPM_EXTRA_PORTS".into(),
        ),
        Err(e) => Finding::with(
            "board",
            Status::Fail,
            format!("{port}: {e}"),
            "close what else has the port open (fpm serve, a serial monitor), or unplug and replug the board".into(),
        ),
    }
}

/// An RP2040 in BOOTSEL on USB (under `sysfs`), and whether this user can reach it.
fn boot_device(sysfs: &Path) -> Finding {
    let read = |dir: &Path, name: &str| {
        std::fs::read_to_string(dir.join(name))
            .map(|s| s.trim().to_owned())
            .unwrap_or_default()
    };
    let found = std::fs::read_dir(sysfs)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .find(|d| (read(d, "idVendor").as_str(), read(d, "idProduct").as_str()) == RP2_BOOT);
    let Some(dir) = found else {
        return Finding::ok(
            "boot device",
            "no RP2040 waits in BOOTSEL (one appears only while a board is being flashed)".into(),
        );
    };
    let (bus, dev) = (read(&dir, "busnum"), read(&dir, "devnum"));
    let node = format!(
        "/dev/bus/usb/{:0>3}/{:0>3}",
        bus.parse::<u32>().unwrap_or(0),
        dev.parse::<u32>().unwrap_or(0)
    );
    use nix::unistd::{access, AccessFlags};
    match access(node.as_str(), AccessFlags::R_OK | AccessFlags::W_OK) {
        Ok(()) => Finding::ok(
            "boot device",
            format!("an RP2040 waits in BOOTSEL at {node}, and this user can reach it"),
        ),
        Err(e) => Finding::with(
            "boot device",
            Status::Warn,
            format!("an RP2040 waits in BOOTSEL at {node}, which this user cannot open ({e})"),
            "install the udev rule (udev/99-fpm.rules names the boot ROM too), then unplug and replug the board; meanwhile fpm device flash copies onto its RPI-RP2 drive".into(),
        ),
    }
}

/// The cameras aravis sees (or the one at `address`).
fn cameras(address: Option<&str>) -> Finding {
    let aravis = match fpm_camera::aravis::Aravis::load() {
        Ok(a) => a,
        Err(e) => {
            return Finding::with(
                "cameras",
                Status::Warn,
                format!("aravis, which fpm drives GigE Vision and USB3 Vision cameras with, could not be loaded: {e:#}"),
                "install it (Debian, Ubuntu: sudo apt install libaravis-0.8-0); the virtual rig (fpm demo, fpm serve --virtual) needs none".into(),
            )
        }
    };
    if let Some(address) = address {
        return match aravis.open(address) {
            Ok(camera) => Finding::ok(
                "cameras",
                format!(
                    "{} {} (serial {}) answers at {address}",
                    camera.vendor().unwrap_or_default(),
                    camera.model().unwrap_or_default(),
                    camera.serial().unwrap_or_default()
                ),
            ),
            Err(e) => Finding::with(
                "cameras",
                Status::Warn,
                format!("no camera answers at {address}: {e:#}"),
                "check that the camera is on and reachable at that address (its IP for GigE Vision), or leave --camera-address out to discover cameras".into(),
            ),
        };
    }
    let found = aravis.discover();
    if found.is_empty() {
        return Finding::with(
            "cameras",
            Status::Warn,
            "aravis sees no camera".into(),
            "check the camera's cable and power (GigE: a link on the same subnet), then fpm camera list".into(),
        );
    }
    Finding::ok(
        "cameras",
        found
            .iter()
            .map(|c| {
                format!(
                    "{} {} (serial {}) at {}",
                    c.vendor, c.model, c.serial, c.address
                )
            })
            .collect::<Vec<_>>()
            .join("; "),
    )
}

/// Space in /dev/shm, and what dead processes left in it.
fn shared_memory(clean: bool) -> Vec<Finding> {
    let mut out = vec![];
    match free_bytes(Path::new("/dev/shm")) {
        Some(free) if free < MIN_SHM_BYTES => out.push(Finding::with(
            "shared memory",
            Status::Warn,
            format!("/dev/shm has {} free; large frames need more", gib(free)),
            "give /dev/shm more room (a container: --shm-size=1g; else its tmpfs size in /etc/fstab)".into(),
        )),
        Some(free) => out.push(Finding::ok(
            "shared memory",
            format!("/dev/shm has {} free", gib(free)),
        )),
        None => out.push(Finding::with(
            "shared memory",
            Status::Fail,
            "/dev/shm is not there: iceoryx2, which carries the camera's frames, needs it".into(),
            "mount a tmpfs on /dev/shm".into(),
        )),
    }
    let stale = if clean {
        fpm_frames::cleanup_stale().map(|n| (n, true))
    } else {
        fpm_frames::stale_nodes().map(|n| (n, false))
    };
    out.push(match stale {
        Ok((0, _)) => Finding::ok(
            "shared memory",
            "no crashed process left iceoryx2 resources".into(),
        ),
        Ok((n, true)) => Finding::ok(
            "shared memory",
            format!("removed what {n} crashed process(es) left in iceoryx2"),
        ),
        Ok((n, false)) => Finding::with(
            "shared memory",
            Status::Warn,
            format!("{n} crashed process(es) left iceoryx2 resources behind"),
            "fpm doctor --clean-shm removes them (a live process's are never touched); fpm acquire does so too".into(),
        ),
        Err(e) => Finding::with(
            "shared memory",
            Status::Fail,
            format!("iceoryx2's nodes could not be listed: {e}"),
            "check that /dev/shm and /tmp/iceoryx2 are writable by this user".into(),
        ),
    });
    out
}

/// Free space where `dir` is (or would be created).
fn disk(dir: &Path) -> Finding {
    let existing = dir
        .ancestors()
        .find(|d| d.exists())
        .unwrap_or(Path::new("/"));
    match free_bytes(existing) {
        Some(free) if free < MIN_DISK_BYTES => Finding::with(
            "disk",
            Status::Warn,
            format!("{}: {} free", dir.display(), gib(free)),
            "free some space, or write elsewhere (--out, --state-dir): a 441-frame set of 1024² takes about 2 GB with its reconstruction".into(),
        ),
        Some(free) => Finding::ok("disk", format!("{}: {} free", dir.display(), gib(free))),
        None => Finding::with(
            "disk",
            Status::Warn,
            format!("{}: its free space could not be read", dir.display()),
            "check that the directory is reachable (a network drive mounted?)".into(),
        ),
    }
}

fn free_bytes(path: &Path) -> Option<u64> {
    let s = nix::sys::statvfs::statvfs(path).ok()?;
    Some(s.blocks_available() as u64 * s.fragment_size() as u64)
}

fn gib(bytes: u64) -> String {
    format!("{:.1} GiB", bytes as f64 / (1u64 << 30) as f64)
}

/// Whether `fpm serve` can listen at `address`: free, or an fpm service already.
fn service_port(address: SocketAddr) -> Finding {
    match TcpListener::bind(address) {
        Ok(_) => Finding::ok("service port", format!("{address} is free for fpm serve")),
        Err(e) if e.kind() == std::io::ErrorKind::AddrInUse => match fpm_status(address) {
            Some(status) => Finding::ok(
                "service port",
                format!("an fpm service listens at {address}: {status}"),
            ),
            None => Finding::with(
                "service port",
                Status::Fail,
                format!("{address} is taken by a program that is not fpm serve"),
                "stop that program, or run fpm serve --listen 127.0.0.1:<another port>".into(),
            ),
        },
        Err(e) => Finding::with(
            "service port",
            Status::Fail,
            format!("{address}: {e}"),
            "run fpm serve --listen with an address of this machine".into(),
        ),
    }
}

/// `GET /api/status` at `address`, if an fpm service answers it: its version and rig.
fn fpm_status(address: SocketAddr) -> Option<String> {
    use std::io::{Read, Write};
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(1)).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(2))).ok()?;
    write!(
        stream,
        "GET /api/status HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut reply = String::new();
    stream.take(1 << 20).read_to_string(&mut reply).ok()?;
    let (head, body) = reply.split_once("\r\n\r\n")?;
    if !head.starts_with("HTTP/1.1 200") {
        return None;
    }
    let status: serde_json::Value = serde_json::from_str(body.trim()).ok()?;
    let field = |name: &str| status.get(name)?.as_str().map(str::to_owned);
    Some(format!("version {}, {}", field("version")?, field("rig")?))
}

/// Whether any finding fails.
pub fn any_failed(findings: &[Finding]) -> bool {
    findings.iter().any(|f| f.status == Status::Fail)
}
