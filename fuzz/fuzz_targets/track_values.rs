//! Any bytes given to the `.tsf` and streamline-weight readers give Ok or Err, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let dir = std::env::temp_dir();
    let (tsf, weights) = (
        dir.join(format!("fascicle-fuzz-{}.tsf", std::process::id())),
        dir.join(format!("fascicle-fuzz-{}.txt", std::process::id())),
    );
    if std::fs::write(&tsf, data).is_ok() {
        let _ = fascicle_core::io::tsf::read(&tsf);
    }
    if std::fs::write(&weights, data).is_ok() {
        let _ = fascicle_core::io::weights::read(&weights);
    }
});
