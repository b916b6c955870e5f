//! The render routes' query parser (camera, size, cut, parts, formats) on arbitrary bytes:
//! whatever it accepts is within the server's limits.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| meshwiki::web::fuzzing::render_query(data));
