//! The `.mwlod` reader on arbitrary files whose checksums are re-sealed first, so that the
//! table checks and the patch decoder see the damage (the `mwlod` target mostly stops at a
//! checksum, as a file damaged on disk does).
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshwiki_engine::lod::format::Header;
use meshwiki_engine::lod::{self, LodFile, NodeRecord};

fn reseal(b: &mut [u8]) {
    if b.len() < 256 {
        return;
    }
    let h: Header = bytemuck::pod_read_unaligned(&b[..256]);
    let size = b.len() as u64;
    let table = |off: u64, len: u64| -> Option<std::ops::Range<usize>> {
        let end = off.checked_add(len)?;
        (end <= size).then_some(off as usize..end as usize)
    };
    let mut h2 = h;
    if let Some(r) = table(h.nodes_offset, h.node_count as u64 * 128) {
        for k in 0..h.node_count as usize {
            let at = r.start + k * 128;
            let mut node: NodeRecord = bytemuck::pod_read_unaligned(&b[at..at + 128]);
            if let Some(blob) = table(node.blob_offset, node.blob_len as u64) {
                node.blob_crc = crc32fast::hash(&b[blob]);
                b[at..at + 128].copy_from_slice(bytemuck::bytes_of(&node));
            }
        }
        h2.nodes_crc = crc32fast::hash(&b[r]);
    }
    if let Some(r) = table(h.groups_offset, h.group_count as u64 * 48) {
        h2.groups_crc = crc32fast::hash(&b[r]);
    }
    if let Some(r) = table(h.links_offset, h.link_count as u64 * 4) {
        h2.links_crc = crc32fast::hash(&b[r]);
    }
    b[..256].copy_from_slice(bytemuck::bytes_of(&h2));
    let crc = crc32fast::hash(&b[..252]);
    b[252..256].copy_from_slice(&crc.to_le_bytes());
}

fuzz_target!(|data: &[u8]| {
    let mut bytes = data.to_vec();
    reseal(&mut bytes);
    let dir = std::env::temp_dir().join(format!("meshwiki-fuzz-sealed-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("case.mwlod");
    if std::fs::write(&path, &bytes).is_err() {
        return;
    }
    let Ok(file) = LodFile::open(&path) else {
        return;
    };
    for node in 0..file.nodes().len() as u32 {
        if let Ok(p) = file.patch(node) {
            let n = p.positions.len() as u32;
            assert!(p.indices.iter().all(|&i| i < n));
        }
    }
    for e in [0.0f32, 1e-3, f32::INFINITY] {
        let cut = lod::cut_uniform(file.nodes(), e);
        let _ = lod::export_cut(&file, &cut);
    }
});
