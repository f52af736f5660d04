//! Work the tests share (building `fpm`, the firmware images, a Python environment),
//! done once however the suite is run. `cargo test` runs each binary's tests as
//! threads of one process; cargo-nextest runs every test in a process of its own, so
//! in-process `OnceLock`s no longer share anything and two processes may build the same
//! file at once. A file lock under `target/test-locks/` serialises the work across
//! processes, and under nextest a stamp with the run's id (`NEXTEST_RUN_ID`) lets the
//! first process of a run do it and the others read its result.

use std::fs::File;
use std::path::{Path, PathBuf};

use nix::fcntl::{Flock, FlockArg};

fn lock_dir() -> PathBuf {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../target/test-locks"));
    std::fs::create_dir_all(dir).expect("creating target/test-locks");
    dir.to_path_buf()
}

/// Hold an exclusive lock named `name` (one file under `target/test-locks/`) until the
/// returned guard drops: other test processes asking for it wait.
pub fn exclusive(name: &str) -> Flock<File> {
    let path = lock_dir().join(format!("{name}.lock"));
    let file = File::create(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Flock::lock(file, FlockArg::LockExclusive)
        .unwrap_or_else(|(_, e)| panic!("locking {}: {e}", path.display()))
}

/// `make`'s result (a line of text, such as a path), computed once per nextest run
/// under the lock `name`; outside nextest, computed under the lock on every call
/// (callers keep it in a `OnceLock`, so once per test binary). A `make` that panics
/// leaves no stamp: the next test tries again and fails with the same message.
pub fn once_per_run(name: &str, make: impl FnOnce() -> String) -> String {
    let _lock = exclusive(name);
    let Ok(run) = std::env::var("NEXTEST_RUN_ID") else {
        return make();
    };
    let stamp = lock_dir().join(format!("{name}.done"));
    if let Ok(text) = std::fs::read_to_string(&stamp) {
        if let Some((id, value)) = text.split_once('\n') {
            if id == run {
                return value.to_string();
            }
        }
    }
    let value = make();
    std::fs::write(&stamp, format!("{run}\n{value}"))
        .unwrap_or_else(|e| panic!("{}: {e}", stamp.display()));
    value
}
