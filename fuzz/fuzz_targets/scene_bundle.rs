#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| isin_fuzzing::files::scene_bundle(data));
