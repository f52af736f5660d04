//! The fuzzer's corpus as a regression test: every input `cargo fuzz run dispatcher`
//! kept (firmware/core/fuzz/corpus/dispatcher, minimised) is replayed through the same
//! script on stable Rust, with the same invariants: no panic, never over the current
//! budget or the board's rating, the next valid request answered.

use std::path::Path;

#[test]
fn every_corpus_input_keeps_the_invariants() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/dispatcher");
    let mut inputs: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| entry.expect("corpus entry").path())
        .collect();
    inputs.sort();
    assert!(
        inputs.len() >= 100,
        "{}: only {} inputs; the corpus is missing",
        dir.display(),
        inputs.len()
    );
    for path in &inputs {
        let script = std::fs::read(path).expect("corpus file");
        if let Err(panic) = std::panic::catch_unwind(|| fpm_firmware::fuzz_script::run(&script)) {
            let message = panic
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| panic.downcast_ref::<&str>().copied())
                .unwrap_or("?");
            panic!("{}: {message}", path.display());
        }
    }
}
