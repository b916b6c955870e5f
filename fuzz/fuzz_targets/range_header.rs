//! The server's `Range` header parser (RFC 9110 §14.2) on arbitrary bytes: the first 8 bytes
//! are the body length, the rest the header value.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| meshwiki::web::fuzzing::range(data));
