//! The app's data cache: what layers read or compute from their sources (images, fitted fields, tractograms),
//! kept by (what, which files at which modification time and size), so that toggling, restyling, reordering or
//! re-slicing a layer never reloads a file or refits a model. A file that changes on disk is read again; a
//! change of parameters is a new key. Least recently used entries go when the cache passes its byte budget.
//!
//! Jobs on other threads share one cache; a value is computed outside the lock, so a long fit never blocks
//! another layer's lookup.

use std::any::Any;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::SystemTime;

use bevy::prelude::Resource;

/// A file as the cache saw it: a changed modification time or size makes the entry stale.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Stamp {
    path: PathBuf,
    modified: Option<SystemTime>,
    len: Option<u64>,
}

impl Stamp {
    fn of(path: &Path) -> Stamp {
        let meta = std::fs::metadata(path).ok();
        Stamp {
            path: path.to_path_buf(),
            modified: meta.as_ref().and_then(|m| m.modified().ok()),
            len: meta.map(|m| m.len()),
        }
    }
}

struct Entry {
    value: Arc<dyn Any + Send + Sync>,
    stamps: Vec<Stamp>,
    bytes: usize,
    used: u64,
}

#[derive(Default)]
struct Inner {
    entries: HashMap<String, Entry>,
    clock: u64,
    stats: CacheStats,
    /// Loads per kind of value (the key up to its first ':').
    loads_by_kind: HashMap<String, u64>,
}

/// What the cache did since it was made: `loads` values computed (a file read, a model fitted), `hits` values
/// reused, `evictions` values dropped for the byte budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Values computed and kept (a file read, a model fitted).
    pub loads: u64,
    /// Lookups answered by a held, unchanged value.
    pub hits: u64,
    /// Values dropped to keep within the byte budget.
    pub evictions: u64,
}

/// Shared by the app and its background jobs (cloning shares it).
#[derive(Resource, Clone)]
pub struct DataCache {
    inner: Arc<Mutex<Inner>>,
    budget: usize,
}

impl Default for DataCache {
    /// A 4 GiB budget: a few large DWIs and their fits.
    fn default() -> Self {
        DataCache::with_budget(4 << 30)
    }
}

impl DataCache {
    /// An empty cache holding at most about `bytes` bytes of values (the most recent one is kept even past it).
    pub fn with_budget(bytes: usize) -> Self {
        DataCache { inner: Arc::default(), budget: bytes }
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // A job that panicked while holding the lock left consistent data (entries are inserted whole).
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// What the cache has done since it was made.
    pub fn stats(&self) -> CacheStats {
        self.lock().stats
    }

    /// Values of one kind computed so far: `nifti` (images read), `sh` and `tensor` (fields read or fitted),
    /// `glyphs` (glyphs placed), `tracts`, ... (the key up to its first ':').
    pub fn loads_of(&self, kind: &str) -> u64 {
        self.lock().loads_by_kind.get(kind).copied().unwrap_or(0)
    }

    /// Number of values held.
    pub fn len(&self) -> usize {
        self.lock().entries.len()
    }

    /// Whether no value is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The value under `key` read from `files`, if held and the files are unchanged; else `load()`'s, kept
    /// (`bytes` its approximate size). Errors are not kept: a fixed file is read again.
    pub fn get_or_load<T: Any + Send + Sync>(
        &self,
        key: &str,
        files: &[&Path],
        bytes: impl FnOnce(&T) -> usize,
        load: impl FnOnce() -> Result<T, String>,
    ) -> Result<Arc<T>, String> {
        // Stamped before the load: a file rewritten meanwhile is read again next time.
        let stamps: Vec<Stamp> = files.iter().map(|p| Stamp::of(p)).collect();
        if let Some(v) = self.peek_stamped(key, &stamps) {
            return Ok(v);
        }
        let value = Arc::new(load()?);
        self.put_stamped(key, stamps, bytes(&value), value.clone());
        Ok(value)
    }

    /// The value under `key`, if held, of type `T` and read from `files` as they are now (a hit).
    pub fn peek<T: Any + Send + Sync>(&self, key: &str, files: &[&Path]) -> Option<Arc<T>> {
        self.peek_stamped(key, &files.iter().map(|p| Stamp::of(p)).collect::<Vec<_>>())
    }

    fn peek_stamped<T: Any + Send + Sync>(&self, key: &str, stamps: &[Stamp]) -> Option<Arc<T>> {
        let mut inner = self.lock();
        inner.clock += 1;
        let now = inner.clock;
        let e = inner.entries.get_mut(key).filter(|e| e.stamps == stamps)?;
        let v = e.value.clone().downcast::<T>().ok()?;
        e.used = now;
        inner.stats.hits += 1;
        Some(v)
    }

    /// Keeps `value` (about `bytes` large) under `key`, read from `files` (a load), replacing what was there;
    /// least recently used values go past the budget.
    pub fn put<T: Any + Send + Sync>(&self, key: &str, files: &[&Path], bytes: usize, value: Arc<T>) {
        self.put_stamped(key, files.iter().map(|p| Stamp::of(p)).collect(), bytes, value);
    }

    fn put_stamped<T: Any + Send + Sync>(&self, key: &str, stamps: Vec<Stamp>, bytes: usize, value: Arc<T>) {
        let mut inner = self.lock();
        inner.stats.loads += 1;
        *inner.loads_by_kind.entry(key.split(':').next().unwrap_or(key).to_string()).or_default() += 1;
        inner.clock += 1;
        let used = inner.clock;
        inner.entries.insert(key.to_string(), Entry { value, stamps, bytes, used });
        while inner.entries.values().map(|e| e.bytes).sum::<usize>() > self.budget && inner.entries.len() > 1 {
            let oldest = inner.entries.iter().filter(|(k, _)| *k != key).min_by_key(|(_, e)| e.used);
            let Some(k) = oldest.map(|(k, _)| k.clone()) else { break };
            inner.entries.remove(&k);
            inner.stats.evictions += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A value is computed once per (key, file state): a second lookup hits; a rewritten file (new size)
    /// loads again; another key loads; errors are not kept; past the budget the least recently used goes.
    #[test]
    fn values_are_kept_per_key_and_file_state() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-cache-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let file = dir.join("a.txt");
        std::fs::write(&file, "one").unwrap();
        let cache = DataCache::with_budget(100);
        let read = |key: &str| {
            cache.get_or_load(
                key,
                &[&file],
                |s: &String| s.len(),
                || std::fs::read_to_string(&file).map_err(|e| e.to_string()),
            )
        };
        assert_eq!(*read("a").unwrap(), "one");
        assert_eq!(*read("a").unwrap(), "one");
        assert_eq!(cache.stats(), CacheStats { loads: 1, hits: 1, evictions: 0 });
        std::fs::write(&file, "three").unwrap();
        assert_eq!(*read("a").unwrap(), "three");
        assert_eq!(cache.stats().loads, 2);
        assert!(cache.get_or_load("bad", &[], |_: &String| 0, || Err("broken".into())).is_err());
        assert_eq!(cache.len(), 1, "an error is not kept");
        // Budget 100 bytes: two 60-byte values cannot both stay; the older one goes.
        let big = |key: &str| cache.get_or_load(key, &[], |v: &Vec<u8>| v.len(), || Ok(vec![0u8; 60]));
        big("x").unwrap();
        big("y").unwrap();
        assert_eq!(cache.stats().evictions, 2, "'a' and then 'x' were evicted");
        big("y").unwrap();
        assert_eq!(cache.stats().hits, 2);
    }
}
