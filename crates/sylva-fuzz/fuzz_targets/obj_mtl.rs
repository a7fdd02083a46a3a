#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    sylva_fuzz::obj_mtl(data);
});
