//! Any bytes given to the TRX reader give Ok or Err, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = fascicle_core::io::trx::read_bytes(data, std::path::Path::new("fuzz.trx"));
});
