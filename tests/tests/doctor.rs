//! `fpm doctor` as a user runs it: on a machine in order (an emulated board on a
//! pseudo-terminal, the board's udev rule in place, the service's port free), and with
//! each problem staged that it must name with its action: a board flashed with another
//! protocol version, no udev rule, and the service's port taken by another program.
//! (Shared memory left by a crashed process is not staged here: iceoryx2's nodes are
//! machine-wide, and any `fpm acquire` the suite runs beside it removes dead ones.)

use std::path::Path;
use std::process::Command;

use fpm_protocol::{ProtocolVersion, PROTOCOL_VERSION};
use fpm_tests::{fpm_bin, workspace, Emulator, TempDir};

/// `fpm doctor --json` with `env` and `args`: its exit success and findings. It asks
/// for a camera at 127.0.0.1, GVCP's one address here: it takes its turn with the
/// tests that run the fake GigE camera there (a second client would disturb their
/// stream), and so finds none.
fn doctor(dir: &Path, env: &[(&str, &str)], args: &[&str]) -> (bool, Vec<serde_json::Value>) {
    let _turn = fpm_tests::once::exclusive("fake-gige-camera");
    let out = Command::new(fpm_bin())
        .args(["doctor", "--json", "--camera-address", "127.0.0.1"])
        .arg("--state-dir")
        .arg(dir.join("state"))
        .args(args)
        .env_remove("FPM_PORT")
        .env_remove("FPM_EXTRA_PORTS")
        .envs(env.iter().copied())
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "{e}: {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    assert_eq!(report["ok"], out.status.success(), "{report}");
    (
        out.status.success(),
        report["findings"].as_array().unwrap().clone(),
    )
}

/// The one finding of `check` (panics with all of them when there is not one).
fn finding<'a>(findings: &'a [serde_json::Value], check: &str) -> &'a serde_json::Value {
    let of: Vec<&serde_json::Value> = findings.iter().filter(|f| f["check"] == check).collect();
    assert_eq!(of.len(), 1, "{check}: {findings:#?}");
    of[0]
}

fn text(v: &serde_json::Value, field: &str) -> String {
    v[field].as_str().unwrap_or_default().to_owned()
}

#[test]
fn a_machine_in_order_passes_and_each_staged_problem_is_named_with_its_action() {
    let dir = TempDir::new("doctor");
    let rules = workspace().join("udev").to_string_lossy().into_owned();
    let no_rules = dir.0.join("no-rules");
    std::fs::create_dir_all(&no_rules).unwrap();
    let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let free_port = free.local_addr().unwrap().to_string();
    drop(free);

    // In order: the repository's rule installed, an emulated board, the port free.
    let emulator = Emulator::start_at(&dir.0.join("controller.tty"), &[]);
    let port = emulator.port();
    let (ok, findings) = doctor(
        &dir.0,
        &[("FPM_UDEV_RULES_DIRS", &rules), ("FPM_EXTRA_PORTS", &port)],
        &["--listen", &free_port],
    );
    assert!(ok, "{findings:#?}");
    assert_eq!(finding(&findings, "udev")["status"], "ok", "{findings:#?}");
    let board = finding(&findings, "board");
    assert_eq!(board["status"], "ok", "{board}");
    assert!(
        text(board, "found").contains(&format!(
            "protocol {PROTOCOL_VERSION} (this host speaks {PROTOCOL_VERSION})"
        )),
        "{board}"
    );
    assert_eq!(finding(&findings, "service port")["status"], "ok");
    for f in &findings {
        assert!(
            f["status"] == "ok" || !text(f, "action").is_empty(),
            "a warning without an action: {f}"
        );
    }

    // A board flashed with an older protocol, no udev rule, the port another program's.
    let older = ProtocolVersion {
        major: PROTOCOL_VERSION.major.saturating_sub(1),
        minor: 9,
    };
    let (_device, foreign, _pair) = fpm_tests::foreign_device(Some(older));
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let taken_port = taken.local_addr().unwrap().to_string();
    let answer_garbage = std::thread::spawn(move || {
        if let Ok((mut s, _)) = taken.accept() {
            use std::io::Write;
            let _ = s.write_all(b"SSH-2.0-OpenSSH_9.6\r\n");
        }
    });
    let (ok, findings) = doctor(
        &dir.0,
        &[
            ("FPM_UDEV_RULES_DIRS", no_rules.to_str().unwrap()),
            ("FPM_EXTRA_PORTS", &foreign),
        ],
        &["--listen", &taken_port],
    );
    answer_garbage.join().unwrap();
    assert!(!ok, "{findings:#?}");
    let board = finding(&findings, "board");
    assert_eq!(board["status"], "fail", "{board}");
    assert!(
        text(board, "found").contains(&older.to_string())
            && text(board, "action").contains("flash"),
        "{board}"
    );
    let udev = finding(&findings, "udev");
    assert_eq!(udev["status"], "warn", "{udev}");
    assert!(text(udev, "action").contains("99-fpm.rules"), "{udev}");
    let listen = finding(&findings, "service port");
    assert_eq!(listen["status"], "fail", "{listen}");
    assert!(text(listen, "action").contains("--listen"), "{listen}");
}
