//! Any bytes given to the nifti reader give Ok or Err, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = std::env::temp_dir().join(format!("fascicle-fuzz-{}.nii", std::process::id()));
    if std::fs::write(&p, data).is_ok() {
        let _ = fascicle_core::io::nifti::read::<f32>(&p);
    }
});
