//! Growable flat arrays that live in memory up to a budget and in a memory-mapped scratch file
//! beyond it. The builder calls [`SpillVec::release`] between work units so resident memory
//! stays bounded while the page cache (not counted against the process) keeps the data warm.

use bytemuck::Pod;
use memmap2::MmapMut;
use std::fs::File;
use std::io;
use std::marker::PhantomData;
use std::path::PathBuf;

enum Storage<T: Pod> {
    Memory(Vec<T>),
    Mapped {
        file: File,
        map: MmapMut,
        capacity: usize,
    },
}

/// A `Vec<T>` that moves to a file once it would exceed `memory_limit` bytes.
pub struct SpillVec<T: Pod> {
    storage: Storage<T>,
    len: usize,
    memory_limit: usize,
    path: PathBuf,
    _t: PhantomData<T>,
}

impl<T: Pod> SpillVec<T> {
    /// An empty array that spills to `path` beyond `memory_limit` bytes.
    pub fn new(path: PathBuf, memory_limit: usize) -> Self {
        SpillVec {
            storage: Storage::Memory(Vec::new()),
            len: 0,
            memory_limit,
            path,
            _t: PhantomData,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Whether the data lives in a file mapping.
    pub fn is_spilled(&self) -> bool {
        matches!(self.storage, Storage::Mapped { .. })
    }

    pub fn extend_from_slice(&mut self, items: &[T]) -> io::Result<()> {
        let new_len = self.len + items.len();
        self.reserve_total(new_len)?;
        match &mut self.storage {
            Storage::Memory(v) => v.extend_from_slice(items),
            Storage::Mapped { map, .. } => {
                let size = std::mem::size_of::<T>();
                map[self.len * size..new_len * size].copy_from_slice(bytemuck::cast_slice(items));
            }
        }
        self.len = new_len;
        Ok(())
    }

    /// Grows to `len` elements, filling with `value`.
    pub fn resize(&mut self, len: usize, value: T) -> io::Result<()> {
        if len <= self.len {
            self.len = len;
            if let Storage::Memory(v) = &mut self.storage {
                v.truncate(len);
            }
            return Ok(());
        }
        let fill = vec![value; (len - self.len).min(1 << 16)];
        while self.len < len {
            let n = (len - self.len).min(fill.len());
            self.extend_from_slice(&fill[..n])?;
        }
        Ok(())
    }

    fn reserve_total(&mut self, total: usize) -> io::Result<()> {
        let size = std::mem::size_of::<T>().max(1);
        match &mut self.storage {
            Storage::Memory(v) => {
                if total * size <= self.memory_limit {
                    v.reserve(total.saturating_sub(v.len()));
                    return Ok(());
                }
                // Move to a file mapping with room to grow.
                let capacity = (total * 2).max(1 << 16);
                let file = File::options()
                    .create(true)
                    .truncate(true)
                    .read(true)
                    .write(true)
                    .open(&self.path)?;
                file.set_len((capacity * size) as u64)?;
                // SAFETY: the scratch file is private to this build and never truncated while mapped.
                let mut map = unsafe { MmapMut::map_mut(&file)? };
                map[..v.len() * size].copy_from_slice(bytemuck::cast_slice(v));
                self.storage = Storage::Mapped {
                    file,
                    map,
                    capacity,
                };
                Ok(())
            }
            Storage::Mapped {
                file,
                map,
                capacity,
            } => {
                if total <= *capacity {
                    return Ok(());
                }
                let new_capacity = (total * 2).max(*capacity * 2);
                map.flush_async()?;
                file.set_len((new_capacity * size) as u64)?;
                // SAFETY: as above; the old mapping is replaced before anyone reads it again.
                *map = unsafe { MmapMut::map_mut(&*file)? };
                *capacity = new_capacity;
                Ok(())
            }
        }
    }

    pub fn as_slice(&self) -> &[T] {
        match &self.storage {
            Storage::Memory(v) => &v[..self.len],
            Storage::Mapped { map, .. } => {
                bytemuck::cast_slice(&map[..self.len * std::mem::size_of::<T>()])
            }
        }
    }

    pub fn as_mut_slice(&mut self) -> &mut [T] {
        let len = self.len;
        match &mut self.storage {
            Storage::Memory(v) => &mut v[..len],
            Storage::Mapped { map, .. } => {
                bytemuck::cast_slice_mut(&mut map[..len * std::mem::size_of::<T>()])
            }
        }
    }

    /// Drops resident pages of a spilled array (the data stays in the file / page cache).
    pub fn release(&self) {
        #[cfg(unix)]
        if let Storage::Mapped { map, .. } = &self.storage {
            // SAFETY: a shared file mapping keeps its contents after MADV_DONTNEED; only the
            // process's page-table entries go, to be refaulted from the page cache.
            let _ = unsafe { map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
    }
}

impl<T: Pod> Drop for SpillVec<T> {
    fn drop(&mut self) {
        if self.is_spilled() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spills_transparently() {
        let dir = std::env::temp_dir().join(format!("mw-spill-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let mut v: SpillVec<[f32; 3]> = SpillVec::new(dir.join("a.bin"), 1000);
        for i in 0..10_000 {
            v.extend_from_slice(&[[i as f32, 0.0, 1.0]]).expect("grow");
        }
        assert!(v.is_spilled());
        v.release();
        assert_eq!(v.len(), 10_000);
        assert_eq!(v.as_slice()[9_999], [9_999.0, 0.0, 1.0]);
        v.as_mut_slice()[5][1] = 2.0;
        assert_eq!(v.as_slice()[5], [5.0, 2.0, 1.0]);
        drop(v);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
