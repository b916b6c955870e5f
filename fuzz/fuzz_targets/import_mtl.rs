//! The OBJ importer's MTL reader on arbitrary bytes: a fixed textured OBJ refers to the
//! fuzzed `case.mtl` (materials, colours, texture map names resolved in the scan's folder).
#![no_main]

#[path = "common/import.rs"]
mod common;

const OBJ: &[u8] = b"mtllib case.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 2/2 4/1 3/3\n";

libfuzzer_sys::fuzz_target!(|data: &[u8]| common::import("obj", OBJ, &[("case.mtl", data)]));
