//! Computed columns kept for reuse across the workflow's searches and selection steps.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Computed columns kept for reuse, by a key of the caller's (the bits of a period, the
/// model values a replay reads, a column of the force balance): the searches of the workflow
/// evaluate the same grid points, and replay the same chambers, again at every selection
/// step. Shared between threads; a clone starts empty. Holds at most
/// [`ColumnCache::CAPACITY`] entries (beyond, new columns are computed and not kept).
pub struct ColumnCache<K = u64, V = Vec<Vec<f64>>> {
    entries: Mutex<HashMap<K, Arc<V>>>,
}

impl<K, V> Default for ColumnCache<K, V> {
    fn default() -> Self {
        ColumnCache {
            entries: Mutex::new(HashMap::new()),
        }
    }
}

impl<K: Eq + std::hash::Hash, V> ColumnCache<K, V> {
    /// Most entries kept.
    pub const CAPACITY: usize = 1024;

    /// The value under `key`, computed by `make` (outside the lock) if not kept yet.
    pub fn get_or_make(&self, key: K, make: impl FnOnce() -> V) -> Arc<V> {
        let kept = self.entries.lock().ok().and_then(|m| m.get(&key).cloned());
        if let Some(c) = kept {
            return c;
        }
        let made = Arc::new(make());
        if let Ok(mut m) = self.entries.lock() {
            if m.len() < Self::CAPACITY {
                m.entry(key).or_insert_with(|| made.clone());
            }
        }
        made
    }

    /// The value under `key`, if kept.
    pub fn get(&self, key: &K) -> Option<Arc<V>> {
        self.entries.lock().ok().and_then(|m| m.get(key).cloned())
    }
}

impl<K, V> Clone for ColumnCache<K, V> {
    fn clone(&self) -> Self {
        ColumnCache::default()
    }
}

impl<K, V> std::fmt::Debug for ColumnCache<K, V> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self.entries.lock().map_or(0, |m| m.len());
        write!(f, "ColumnCache({n} entries)")
    }
}
