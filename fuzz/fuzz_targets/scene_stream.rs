#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| isin_fuzzing::wire::scene_stream(data));
