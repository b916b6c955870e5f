//! The `.mwlod` file: one file per model, little endian, memory-mappable, range-readable.
//!
//! ```text
//! [Header: 256 bytes, CRC-32 over its first 252 bytes]
//! [Node table: node_count × NodeRecord (128 bytes), CRC-32 in the header]
//! [Group table: group_count × GroupRecord (48 bytes), CRC-32 in the header]
//! [Links: u32 node ids referenced by groups (members, then products), CRC-32 in the header]
//! [Patch blobs, in node-table order (locality order: coarse levels first, Morton order
//!  within a level), each with its own CRC-32 in its node record]
//! ```
//! The layout of every record and of a patch blob is documented in `docs/FORMAT.md`, and so
//! are the DAG semantics (system paper §3.2, with Nanite-style groups); `super::build` makes
//! them.

use bytemuck::{Pod, Zeroable};
use memmap2::Mmap;
use std::fs::File;
use std::io::{self, Write};
use std::path::Path;

/// File magic, first 8 bytes.
pub const MAGIC: [u8; 8] = *b"MWLOD\0\r\n";
/// Format version this build writes and reads.
pub const VERSION: u32 = 1;
/// `NodeRecord::producer` / `member_of` value meaning "none".
pub const NO_GROUP: u32 = u32::MAX;

/// Header flags.
pub const HAS_COLORS: u32 = 1;
pub const HAS_NORMALS: u32 = 2;
/// Every patch carries a texture atlas (`docs/FORMAT.md`, patch blob).
pub const HAS_TEXTURE: u32 = 4;
/// Coarse patches carry normal maps (`docs/FORMAT.md`, patch blob).
pub const HAS_NORMAL_MAPS: u32 = 8;
/// Vertex ids number the scan's vertices in the Morton order of their points on the file's
/// grid ([`super::vertex_order`]), not in the scan file's order.
pub const MORTON_VERTEX_ORDER: u32 = 16;

/// Fixed-size file header.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Header {
    pub magic: [u8; 8],
    pub version: u32,
    pub flags: u32,
    pub node_count: u32,
    pub group_count: u32,
    pub link_count: u32,
    pub level_count: u32,
    pub input_vertex_count: u64,
    pub input_triangle_count: u64,
    /// Bounds of the input, world units.
    pub bbox_min: [f32; 3],
    pub bbox_max: [f32; 3],
    /// Quantisation grid: position = origin + step * grid_coordinate (f64 for exactness).
    pub grid_origin: [f64; 3],
    pub grid_step: f64,
    pub max_patch_triangles: u32,
    pub root_count: u32,
    pub nodes_offset: u64,
    pub groups_offset: u64,
    pub links_offset: u64,
    pub blobs_offset: u64,
    pub blobs_len: u64,
    pub nodes_crc: u32,
    pub groups_crc: u32,
    pub links_crc: u32,
    pub _reserved: [u32; 22],
    pub header_crc: u32,
}

const _: () = assert!(std::mem::size_of::<Header>() == 256);

/// Largest patch triangle budget a file may declare (the builder accepts 16 to 2^16).
pub const MAX_PATCH_TRIANGLES: u32 = 1 << 16;

/// One patch of the DAG.
///
/// A node is drawn in a cut iff its own error is acceptable and its group's is not:
/// `proj(lod_error, lod_sphere) <= threshold < proj(parent_error, parent_sphere)`.
/// Siblings share both spheres and errors, so cuts are always crack-free.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct NodeRecord {
    pub blob_offset: u64,
    pub blob_len: u32,
    pub blob_crc: u32,
    pub triangle_count: u32,
    pub vertex_count: u32,
    /// 0 for leaves (full resolution), increasing towards the roots.
    pub level: u32,
    pub _pad: u32,
    /// Tight bounding sphere of the patch (culling): centre xyz, radius.
    pub bounds: [f32; 4],
    /// Normal cone: axis xyz and cutoff (meshoptimizer convention; cutoff 1 = never back-face culled).
    pub cone: [f32; 4],
    /// Sphere and error of the simplification that produced this node (0 for leaves).
    pub lod_sphere: [f32; 4],
    pub lod_error: f32,
    /// Sphere and error of the group this node belongs to (error = +inf for roots).
    pub parent_error: f32,
    pub _pad2: [f32; 2],
    pub parent_sphere: [f32; 4],
    /// Group whose simplification produced this node (`NO_GROUP` for leaves).
    pub producer: u32,
    /// Group this node is a member of (`NO_GROUP` for roots).
    pub member_of: u32,
    pub _pad3: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<NodeRecord>() == 128);

/// A group: neighbouring patches merged, simplified with their outer border locked and split
/// again into its products (system paper §3.2; grouping as in Nanite so that borders locked at
/// one level are interior at the next).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
pub struct GroupRecord {
    /// Bounding sphere of the members' LOD spheres (monotone towards the roots).
    pub sphere: [f32; 4],
    /// Object-space error bound of the products relative to the original surface.
    pub error: f32,
    pub level: u32,
    /// Members: `links[members_first .. members_first + members_count]`.
    pub members_first: u32,
    pub members_count: u32,
    /// Products: `links[products_first .. products_first + products_count]`.
    pub products_first: u32,
    pub products_count: u32,
    pub _pad: [u32; 2],
}

const _: () = assert!(std::mem::size_of::<GroupRecord>() == 48);

/// Problems reading a LOD file.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("cannot read LOD file: {0}")]
    Io(#[from] io::Error),
    #[error("not a meshwiki LOD file")]
    BadMagic,
    #[error("unsupported LOD file version {0} (this build reads {VERSION})")]
    BadVersion(u32),
    #[error("LOD file is corrupt: {0}")]
    Corrupt(String),
    #[error("patch {0} does not exist")]
    NoSuchNode(u32),
    #[error("patch {node} failed its checksum")]
    Checksum { node: u32 },
    #[error("patch {node} cannot be decoded: {reason}")]
    Decode { node: u32, reason: String },
}

/// A memory-mapped LOD file with validated tables.
pub struct LodFile {
    map: Mmap,
    header: Header,
}

impl LodFile {
    /// Maps the file and checks magic, version, table bounds and table checksums.
    pub fn open(path: &Path) -> Result<LodFile, FormatError> {
        let file = File::open(path)?;
        // SAFETY: LOD files are immutable once renamed into place (written under a temporary
        // name); nothing truncates them while mapped.
        let map = unsafe { Mmap::map(&file)? };
        Self::from_map(map)
    }

    fn from_map(map: Mmap) -> Result<LodFile, FormatError> {
        if map.len() < std::mem::size_of::<Header>() {
            return Err(FormatError::BadMagic);
        }
        let header: Header = bytemuck::pod_read_unaligned(&map[..256]);
        if header.magic != MAGIC {
            return Err(FormatError::BadMagic);
        }
        if header.version != VERSION {
            return Err(FormatError::BadVersion(header.version));
        }
        if crc32fast::hash(&map[..252]) != header.header_crc {
            return Err(FormatError::Corrupt("header checksum mismatch".into()));
        }
        let file = LodFile { map, header };
        let nodes = file.table_bytes(header.nodes_offset, header.node_count as u64 * 128)?;
        let groups = file.table_bytes(header.groups_offset, header.group_count as u64 * 48)?;
        let links = file.table_bytes(header.links_offset, header.link_count as u64 * 4)?;
        if crc32fast::hash(nodes) != header.nodes_crc
            || crc32fast::hash(groups) != header.groups_crc
            || crc32fast::hash(links) != header.links_crc
        {
            return Err(FormatError::Corrupt("table checksum mismatch".into()));
        }
        if !header.nodes_offset.is_multiple_of(8)
            || !header.groups_offset.is_multiple_of(8)
            || !header.links_offset.is_multiple_of(4)
        {
            return Err(FormatError::Corrupt("misaligned table".into()));
        }
        if header.max_patch_triangles == 0 || header.max_patch_triangles > MAX_PATCH_TRIANGLES {
            return Err(FormatError::Corrupt(
                "patch triangle budget out of range".into(),
            ));
        }
        file.check_links()?;
        Ok(file)
    }

    fn table_bytes(&self, offset: u64, len: u64) -> Result<&[u8], FormatError> {
        let end = offset
            .checked_add(len)
            .filter(|&e| e <= self.map.len() as u64)
            .ok_or_else(|| FormatError::Corrupt("table out of bounds".into()))?;
        Ok(&self.map[offset as usize..end as usize])
    }

    fn check_links(&self) -> Result<(), FormatError> {
        let n = self.header.node_count;
        let g = self.header.group_count;
        let links = self.links();
        if links.iter().any(|&l| l >= n) {
            return Err(FormatError::Corrupt("link to a missing node".into()));
        }
        for group in self.groups() {
            let ok = |first: u32, count: u32| (first as u64 + count as u64) <= links.len() as u64;
            if !ok(group.members_first, group.members_count)
                || !ok(group.products_first, group.products_count)
            {
                return Err(FormatError::Corrupt("group links out of bounds".into()));
            }
        }
        for node in self.nodes() {
            let group_ok = |x: u32| x == NO_GROUP || x < g;
            let end = node.blob_offset.checked_add(node.blob_len as u64);
            let budget = self.header.max_patch_triangles;
            if !group_ok(node.producer)
                || !group_ok(node.member_of)
                || node.triangle_count > budget
                || node.vertex_count > budget.saturating_mul(3)
                || end.is_none_or(|e| e > self.map.len() as u64)
            {
                return Err(FormatError::Corrupt("node record out of range".into()));
            }
        }
        Ok(())
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// All node records, in file (locality) order; node id = index.
    pub fn nodes(&self) -> &[NodeRecord] {
        let h = &self.header;
        let start = h.nodes_offset as usize;
        bytemuck::cast_slice(&self.map[start..start + h.node_count as usize * 128])
    }

    pub fn groups(&self) -> &[GroupRecord] {
        let h = &self.header;
        let start = h.groups_offset as usize;
        bytemuck::cast_slice(&self.map[start..start + h.group_count as usize * 48])
    }

    pub fn links(&self) -> &[u32] {
        let h = &self.header;
        let start = h.links_offset as usize;
        bytemuck::cast_slice(&self.map[start..start + h.link_count as usize * 4])
    }

    /// Member node ids of a group.
    pub fn members(&self, group: &GroupRecord) -> &[u32] {
        let f = group.members_first as usize;
        &self.links()[f..f + group.members_count as usize]
    }

    /// Product node ids of a group.
    pub fn products(&self, group: &GroupRecord) -> &[u32] {
        let f = group.products_first as usize;
        &self.links()[f..f + group.products_count as usize]
    }

    pub fn node(&self, id: u32) -> Result<&NodeRecord, FormatError> {
        self.nodes()
            .get(id as usize)
            .ok_or(FormatError::NoSuchNode(id))
    }

    /// The raw (compressed) patch blob, checksum verified.
    pub fn blob(&self, id: u32) -> Result<&[u8], FormatError> {
        let node = self.node(id)?;
        let start = node.blob_offset as usize;
        let bytes = &self.map[start..start + node.blob_len as usize];
        if crc32fast::hash(bytes) != node.blob_crc {
            return Err(FormatError::Checksum { node: id });
        }
        Ok(bytes)
    }

    /// Decodes a patch to flat arrays (world-space positions).
    pub fn patch(&self, id: u32) -> Result<super::codec::Patch, FormatError> {
        let blob = self.blob(id)?;
        let max = self.header.max_patch_triangles;
        super::codec::decode_limited(blob, &self.grid(), max).map_err(|reason| {
            FormatError::Decode {
                node: id,
                reason: reason.to_string(),
            }
        })
    }

    /// The quantisation grid shared by every patch.
    pub fn grid(&self) -> super::codec::Grid {
        super::codec::Grid {
            origin: self.header.grid_origin,
            step: self.header.grid_step,
        }
    }

    pub fn has_colors(&self) -> bool {
        self.header.flags & HAS_COLORS != 0
    }

    pub fn has_normals(&self) -> bool {
        self.header.flags & HAS_NORMALS != 0
    }

    /// Whether every patch carries a texture atlas.
    pub fn has_texture(&self) -> bool {
        self.header.flags & HAS_TEXTURE != 0
    }

    /// Whether coarse patches carry normal maps.
    pub fn has_normal_maps(&self) -> bool {
        self.header.flags & HAS_NORMAL_MAPS != 0
    }

    /// How the vertex ids number the scan's vertices.
    pub fn vertex_order(&self) -> super::VertexOrder {
        if self.header.flags & MORTON_VERTEX_ORDER != 0 {
            super::VertexOrder::Morton
        } else {
            super::VertexOrder::Source
        }
    }

    /// The whole file (for serving byte ranges).
    pub fn bytes(&self) -> &[u8] {
        &self.map
    }

    /// Byte range `[start, end)` of the node table (served to clients as-is).
    pub fn node_table_range(&self) -> (u64, u64) {
        let h = &self.header;
        (h.nodes_offset, h.nodes_offset + h.node_count as u64 * 128)
    }
}

/// Writes the tables and blobs as one file, to a temporary name renamed when complete.
pub struct TableWriter<'a> {
    pub header: Header,
    pub nodes: &'a [NodeRecord],
    pub groups: &'a [GroupRecord],
    pub links: &'a [u32],
}

impl TableWriter<'_> {
    /// Fills offsets and checksums, then streams `blobs` (already in node order, with
    /// `nodes[i].blob_offset` relative to the start of the blob section) after the tables.
    /// `copy_blobs` writes exactly `blobs_len` bytes.
    pub fn write(
        mut self,
        path: &Path,
        blobs_len: u64,
        copy_blobs: impl FnOnce(&mut dyn Write) -> io::Result<()>,
    ) -> io::Result<u64> {
        let nodes_offset = 256u64;
        let groups_offset = align(nodes_offset + self.nodes.len() as u64 * 128, 8);
        let links_offset = align(groups_offset + self.groups.len() as u64 * 48, 8);
        let blobs_offset = align(links_offset + self.links.len() as u64 * 4, 16);
        let mut nodes = self.nodes.to_vec();
        for n in &mut nodes {
            n.blob_offset += blobs_offset;
        }
        let h = &mut self.header;
        h.magic = MAGIC;
        h.version = VERSION;
        h.node_count = nodes.len() as u32;
        h.group_count = self.groups.len() as u32;
        h.link_count = self.links.len() as u32;
        h.nodes_offset = nodes_offset;
        h.groups_offset = groups_offset;
        h.links_offset = links_offset;
        h.blobs_offset = blobs_offset;
        h.blobs_len = blobs_len;
        h.nodes_crc = crc32fast::hash(bytemuck::cast_slice(&nodes));
        h.groups_crc = crc32fast::hash(bytemuck::cast_slice(self.groups));
        h.links_crc = crc32fast::hash(bytemuck::cast_slice(self.links));
        h.header_crc = crc32fast::hash(&bytemuck::bytes_of(h)[..252]);

        let tmp = temp_path(path);
        let result = (|| {
            let file = File::create(&tmp)?;
            let mut out = io::BufWriter::with_capacity(1 << 20, file);
            out.write_all(bytemuck::bytes_of(&self.header))?;
            out.write_all(bytemuck::cast_slice(&nodes))?;
            pad_to(
                &mut out,
                nodes_offset + nodes.len() as u64 * 128,
                groups_offset,
            )?;
            out.write_all(bytemuck::cast_slice(self.groups))?;
            pad_to(
                &mut out,
                groups_offset + self.groups.len() as u64 * 48,
                links_offset,
            )?;
            out.write_all(bytemuck::cast_slice(self.links))?;
            pad_to(
                &mut out,
                links_offset + self.links.len() as u64 * 4,
                blobs_offset,
            )?;
            copy_blobs(&mut out)?;
            let file = out.into_inner().map_err(|e| e.into_error())?;
            file.sync_all()?;
            Ok::<u64, io::Error>(blobs_offset + blobs_len)
        })();
        match result {
            Ok(len) => {
                std::fs::rename(&tmp, path)?;
                Ok(len)
            }
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }
}

fn align(x: u64, a: u64) -> u64 {
    x.div_ceil(a) * a
}

fn pad_to(out: &mut dyn Write, at: u64, to: u64) -> io::Result<()> {
    let zeros = [0u8; 16];
    out.write_all(&zeros[..(to - at) as usize])
}

/// `model.mwlod` → `model.mwlod.tmp-<pid>` in the same directory (same filesystem, so the
/// final rename is atomic).
pub fn temp_path(path: &Path) -> std::path::PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}
