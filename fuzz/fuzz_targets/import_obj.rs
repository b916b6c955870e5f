//! The OBJ importer on arbitrary bytes (one hour of coverage-guided fuzzing per parser).
#![no_main]

#[path = "common/import.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::import("obj", data, &[]));
