//! Out-of-core GPU patch cache (system paper §3.3: patches are loaded on demand, so a model larger
//! than memory renders with only the patches of the current cut resident).
//!
//! Entries are keyed by (model, node) and hold one buffer per patch (positions, normals,
//! colours, original ids, indices, texture coordinates), drawn from as vertex and index buffer
//! and read by the fragment shaders as storage, plus a CPU copy of the original ids for
//! highlight masks. The
//! budget bounds the resident bytes; least recently used entries not pinned by a render in
//! flight are evicted first. Pinned entries stay alive through their `Arc` until that render
//! ends, so the peak is the budget plus the batches of the renders in flight.

use super::pipeline::{Pipelines, atlas_texture};
use crate::lod::{NodeRecord, Patch, codec};
use crate::mesh::Texture;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

/// Cache key: model id and node id.
pub type Key = (u64, u32);

/// Word offsets (u32 units) of the streams in a patch buffer.
#[derive(Debug, Clone, Copy)]
pub struct PatchLayout {
    pub positions: u32,
    pub normals: u32,
    /// `u32::MAX` when the model has no colours.
    pub colors: u32,
    pub ids: u32,
    pub indices: u32,
    /// Texture coordinates (unorm16 pairs); `u32::MAX` when the patch has no atlas.
    pub uvs: u32,
    pub words: u32,
}

impl PatchLayout {
    pub fn new(vertices: u32, triangles: u32, colors: bool) -> PatchLayout {
        Self::with_uvs(vertices, triangles, colors, false)
    }

    pub fn with_uvs(vertices: u32, triangles: u32, colors: bool, uvs: bool) -> PatchLayout {
        let (v, t) = (vertices as u64, triangles as u64);
        let positions = 0u64;
        let normals = 3 * v;
        let (colors, ids) = if colors {
            (6 * v, 7 * v)
        } else {
            (u32::MAX as u64, 6 * v)
        };
        let indices = ids + v;
        let (uv_at, words) = if uvs {
            (indices + 3 * t, indices + 3 * t + v)
        } else {
            (u32::MAX as u64, indices + 3 * t)
        };
        // Patches hold at most 2^20 elements (codec limit), so these fit in u32.
        let c = |x: u64| x.min(u32::MAX as u64) as u32;
        PatchLayout {
            positions: c(positions),
            normals: c(normals),
            colors: c(colors),
            ids: c(ids),
            indices: c(indices),
            uvs: c(uv_at),
            words: c(words),
        }
    }
}

/// Bytes a node takes in the cache (GPU buffer, CPU ids, fixed overhead).
pub fn node_bytes(node: &NodeRecord, colors: bool) -> u64 {
    let l = PatchLayout::new(node.vertex_count, node.triangle_count, colors);
    l.words as u64 * 4 + node.vertex_count as u64 * 4 + 512
}

/// One resident patch.
pub struct GpuPatch {
    pub node: u32,
    pub vertices: u32,
    pub triangles: u32,
    pub layout: PatchLayout,
    pub bind_group: wgpu::BindGroup,
    /// The patch's streams: a storage buffer (ids, for the fragment shaders) that is also the
    /// vertex and index buffer of its draw.
    pub buffer: wgpu::Buffer,
    /// Whether its colour comes from its atlas.
    pub color_atlas: bool,
    /// Whether it has a normal map.
    pub normal_map: bool,
    _atlas: Option<wgpu::Texture>,
    _normal_map: Option<wgpu::Texture>,
    /// Original vertex ids (CPU copy, for highlight masks).
    pub original_ids: Vec<u32>,
    /// Smallest and largest original id.
    pub id_range: (u32, u32),
    pub bytes: u64,
    live: Arc<AtomicU64>,
}

impl Drop for GpuPatch {
    fn drop(&mut self) {
        self.live.fetch_sub(self.bytes, Ordering::Relaxed);
    }
}

/// Counters of a cache.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct CacheStats {
    pub entries: usize,
    /// Bytes of the entries in the cache.
    pub resident_bytes: u64,
    /// Bytes of all patches alive (resident or pinned by renders in flight).
    pub live_bytes: u64,
    pub budget_bytes: u64,
    pub loads: u64,
    pub hits: u64,
    pub evictions: u64,
}

struct Entry {
    patch: Arc<GpuPatch>,
    tick: u64,
}

#[derive(Default)]
struct Inner {
    map: HashMap<Key, Entry>,
    order: BTreeMap<u64, Key>,
    tick: u64,
    bytes: u64,
}

/// LRU cache of GPU patches with a byte budget, shared by concurrent renders.
pub struct PatchCache {
    inner: Mutex<Inner>,
    budget: u64,
    live: Arc<AtomicU64>,
    loads: AtomicU64,
    hits: AtomicU64,
    evictions: AtomicU64,
}

impl PatchCache {
    pub fn new(budget: u64) -> PatchCache {
        PatchCache {
            inner: Mutex::new(Inner::default()),
            budget,
            live: Arc::new(AtomicU64::new(0)),
            loads: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Resident patches for `keys` (touched as most recently used), `None` for misses.
    pub fn lookup(&self, keys: &[Key]) -> Vec<Option<Arc<GpuPatch>>> {
        let mut inner = self.lock();
        let mut hits = 0;
        let out = keys
            .iter()
            .map(|k| {
                inner.tick += 1;
                let tick = inner.tick;
                let Inner { map, order, .. } = &mut *inner;
                let e = map.get_mut(k)?;
                order.remove(&e.tick);
                order.insert(tick, *k);
                e.tick = tick;
                hits += 1;
                Some(e.patch.clone())
            })
            .collect();
        self.hits.fetch_add(hits, Ordering::Relaxed);
        out
    }

    /// Inserts freshly loaded patches (keeping an entry another render inserted meanwhile) and
    /// evicts down to the budget. Returns the resident patch for each key.
    pub fn insert(&self, loaded: Vec<(Key, GpuPatch)>) -> Vec<Arc<GpuPatch>> {
        let mut inner = self.lock();
        let mut out = Vec::with_capacity(loaded.len());
        for (key, patch) in loaded {
            inner.tick += 1;
            let tick = inner.tick;
            if let Some(e) = inner.map.get(&key) {
                out.push(e.patch.clone());
                continue;
            }
            self.loads.fetch_add(1, Ordering::Relaxed);
            let patch = Arc::new(patch);
            inner.bytes += patch.bytes;
            inner.order.insert(tick, key);
            inner.map.insert(
                key,
                Entry {
                    patch: patch.clone(),
                    tick,
                },
            );
            out.push(patch);
        }
        self.evict(&mut inner);
        out
    }

    /// Evicts unpinned entries, least recently used first, until within the budget.
    fn evict(&self, inner: &mut Inner) {
        if inner.bytes <= self.budget {
            return;
        }
        let mut victims = Vec::new();
        let mut bytes = inner.bytes;
        for (&tick, key) in inner.order.iter() {
            if bytes <= self.budget {
                break;
            }
            if let Some(e) = inner.map.get(key)
                && Arc::strong_count(&e.patch) == 1
            {
                bytes -= e.patch.bytes;
                victims.push((tick, *key));
            }
        }
        for (tick, key) in victims {
            inner.order.remove(&tick);
            if let Some(e) = inner.map.remove(&key) {
                inner.bytes -= e.patch.bytes;
                self.evictions.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Drops every entry of a model (e.g. when the model is deleted).
    pub fn forget_model(&self, model: u64) {
        let mut inner = self.lock();
        let keys: Vec<(u64, Key)> = inner
            .map
            .iter()
            .filter(|(k, _)| k.0 == model)
            .map(|(k, e)| (e.tick, *k))
            .collect();
        for (tick, key) in keys {
            inner.order.remove(&tick);
            if let Some(e) = inner.map.remove(&key) {
                inner.bytes -= e.patch.bytes;
            }
        }
    }

    /// Drops every entry.
    pub fn clear(&self) {
        let mut inner = self.lock();
        inner.map.clear();
        inner.order.clear();
        inner.bytes = 0;
    }

    pub fn stats(&self) -> CacheStats {
        let inner = self.lock();
        CacheStats {
            entries: inner.map.len(),
            resident_bytes: inner.bytes,
            live_bytes: self.live.load(Ordering::Relaxed),
            budget_bytes: self.budget,
            loads: self.loads.load(Ordering::Relaxed),
            hits: self.hits.load(Ordering::Relaxed),
            evictions: self.evictions.load(Ordering::Relaxed),
        }
    }

    /// Uploads a decoded patch (not yet inserted), writing straight into the mapped buffer.
    /// `shared_memory`: the buffer is host-visible (no staging copy).
    /// A patch's atlas image (JPEG) that does not decode is logged and the patch drawn with
    /// its vertex colours.
    #[allow(clippy::too_many_arguments)]
    pub fn upload(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        pipelines: &Pipelines,
        node: u32,
        patch: &Patch,
        has_colors: bool,
        shared_memory: bool,
    ) -> GpuPatch {
        let n = patch.positions.len();
        let t = patch.indices.len() / 3;
        let colors = has_colors && patch.colors.len() == n;
        let decode = |bytes: Option<&[u8]>, what: &str| match bytes {
            Some(bytes) if patch.uvs.len() == n => match Texture::decode(bytes) {
                Ok(img) => Some(img),
                Err(e) => {
                    tracing::warn!(node, error = %e, "patch {what} does not decode");
                    None
                }
            },
            _ => None,
        };
        let image = decode(patch.image.as_deref(), "atlas");
        let normal_image = decode(patch.normal_map.as_deref(), "normal map");
        let uvs = image.is_some() || normal_image.is_some();
        let layout = PatchLayout::with_uvs(n as u32, t as u32, colors, uvs);
        let words_len = (layout.words as usize).max(1);
        let mut usage =
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::INDEX;
        if shared_memory {
            usage |= wgpu::BufferUsages::MAP_WRITE;
        }
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("patch"),
            size: words_len as u64 * 4,
            usage,
            mapped_at_creation: true,
        });
        if let Ok(mut view) = buffer.get_mapped_range_mut(..) {
            let total = view.len();
            let mut at = 0usize;
            let mut scratch: Vec<u32> = Vec::new();
            let mut put = |scratch: &mut Vec<u32>| {
                let bytes: &[u8] = bytemuck::cast_slice(scratch);
                let end = (at + bytes.len()).min(total);
                if end > at {
                    view.slice(at..end).copy_from_slice(&bytes[..end - at]);
                }
                at = end;
                scratch.clear();
            };
            scratch.extend(patch.positions.iter().flatten().map(|f| f.to_bits()));
            put(&mut scratch);
            if patch.normals.len() == n {
                scratch.extend(patch.normals.iter().flatten().map(|f| f.to_bits()));
            } else {
                let computed = codec::computed_normals(&patch.positions, &patch.indices);
                scratch.extend(computed.iter().flatten().map(|f| f.to_bits()));
            }
            put(&mut scratch);
            if colors {
                scratch.extend(patch.colors.iter().map(|c| u32::from_le_bytes(*c)));
                put(&mut scratch);
            }
            scratch.extend_from_slice(&patch.original_ids);
            put(&mut scratch);
            scratch.extend_from_slice(&patch.indices[..t * 3]);
            put(&mut scratch);
            if uvs {
                scratch.extend(patch.uvs.iter().map(|uv| {
                    let q = uv.map(|x| (x.clamp(0.0, 1.0) * 65535.0 + 0.5) as u32);
                    q[0] | (q[1] << 16)
                }));
                put(&mut scratch);
            }
        }
        buffer.unmap();
        let gpu = |img: &Texture| {
            atlas_texture(
                device,
                queue,
                img.width(),
                img.height(),
                bytemuck::cast_slice(img.texels()),
            )
        };
        let atlas = image.as_ref().map(gpu);
        let normal_map = normal_image.as_ref().map(gpu);
        let view = |t: &wgpu::Texture| t.create_view(&Default::default());
        let (atlas_view, normal_view) = (atlas.as_ref().map(view), normal_map.as_ref().map(view));
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("patch"),
            layout: &pipelines.patch_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(
                        atlas_view.as_ref().unwrap_or(&pipelines.no_atlas),
                    ),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&pipelines.atlas_sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(
                        normal_view.as_ref().unwrap_or(&pipelines.no_atlas),
                    ),
                },
            ],
        });
        let id_range = (
            patch.original_ids.iter().copied().min().unwrap_or(0),
            patch.original_ids.iter().copied().max().unwrap_or(0),
        );
        let bytes = words_len as u64 * 4
            + n as u64 * 4
            + 512
            + image.as_ref().map_or(0, |img| img.bytes())
            + normal_image.as_ref().map_or(0, |img| img.bytes());
        self.live.fetch_add(bytes, Ordering::Relaxed);
        GpuPatch {
            node,
            vertices: n as u32,
            triangles: t as u32,
            layout,
            bind_group,
            buffer,
            color_atlas: atlas.is_some(),
            normal_map: normal_map.is_some(),
            _atlas: atlas,
            _normal_map: normal_map,
            original_ids: patch.original_ids.clone(),
            id_range,
            bytes,
            live: self.live.clone(),
        }
    }
}
