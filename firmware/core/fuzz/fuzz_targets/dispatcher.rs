//! The controller's byte input under libFuzzer: every byte sequence a host (or line
//! noise) can send, as a script of raw bytes, framed requests on every key with
//! arbitrary or valid-but-fuzzed bodies, camera edges and time
//! (`fpm_firmware::fuzz_script`). Invariants: no panic, never over the current budget
//! or the board's rating, and the next valid request is answered.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|script: &[u8]| {
    fpm_firmware::fuzz_script::run(script);
});
