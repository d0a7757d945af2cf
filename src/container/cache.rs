//! A chunk cache bounded by a byte budget (`--memory`), least recently used
//! chunks evicted first.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use super::ChunkData;
use crate::{Error, Result};

/// A memory budget in bytes (`--memory`, default 1 GiB).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryBudget(pub u64);

impl Default for MemoryBudget {
    fn default() -> Self {
        MemoryBudget(1 << 30)
    }
}

impl MemoryBudget {
    /// Parses `512MiB`, `1GiB`, `2G`, `800MB`, `65536` (bytes).
    pub fn parse(s: &str) -> Result<MemoryBudget> {
        let t = s.trim();
        let split = t.find(|c: char| c.is_ascii_alphabetic()).unwrap_or(t.len());
        let (num, unit) = t.split_at(split);
        let v: f64 = num
            .trim()
            .parse()
            .map_err(|_| Error::Config(format!("--memory '{s}': expected a size like 512MiB or 2GiB")))?;
        let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
            "" | "b" => 1.0,
            "k" | "kib" => 1024.0,
            "kb" => 1e3,
            "m" | "mib" => 1024.0 * 1024.0,
            "mb" => 1e6,
            "g" | "gib" => 1024.0 * 1024.0 * 1024.0,
            "gb" => 1e9,
            other => return Err(Error::Config(format!("--memory '{s}': unknown unit '{other}'"))),
        };
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::Config(format!("--memory '{s}': must be positive")));
        }
        Ok(MemoryBudget((v * mult) as u64))
    }

    /// The budget in bytes.
    pub fn bytes(self) -> u64 {
        self.0
    }

    /// The budget split into shares in proportion to `weights` (each share
    /// `bytes × weight / Σ weights`, rounded down): how a stage divides
    /// `--memory` among its caches and buffers, e.g. `split([1, 1, 1, 1])`
    /// for quarters.
    pub fn split<const N: usize>(self, weights: [u64; N]) -> [MemoryBudget; N] {
        let total: u128 = weights.iter().map(|&w| w as u128).sum::<u128>().max(1);
        weights.map(|w| MemoryBudget((self.0 as u128 * w as u128 / total) as u64))
    }
}

type Key = (u32, u64);

struct Inner {
    map: HashMap<Key, (Arc<ChunkData>, u64)>,
    by_age: BTreeMap<u64, Key>,
    bytes: u64,
    tick: u64,
}

/// Decoded chunks shared between threads; never holds more than the budget.
pub(crate) struct ChunkCache {
    budget: u64,
    inner: Mutex<Inner>,
}

impl ChunkCache {
    pub(crate) fn new(budget: MemoryBudget) -> Self {
        ChunkCache {
            budget: budget.0,
            inner: Mutex::new(Inner {
                map: HashMap::new(),
                by_age: BTreeMap::new(),
                bytes: 0,
                tick: 0,
            }),
        }
    }

    /// The cached chunk, or `load()`'s result (cached if it fits the budget).
    pub(crate) fn get_or_load(
        &self,
        key: Key,
        load: impl FnOnce() -> Result<ChunkData>,
    ) -> Result<Arc<ChunkData>> {
        {
            let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            let inner = &mut *g;
            inner.tick += 1;
            let tick = inner.tick;
            if let Some((data, age)) = inner.map.get_mut(&key) {
                inner.by_age.remove(age);
                *age = tick;
                inner.by_age.insert(tick, key);
                return Ok(data.clone());
            }
        }
        let data = Arc::new(load()?);
        let size = data.byte_len() as u64;
        if size * 4 > self.budget {
            // Too large to be worth caching under this budget.
            return Ok(data);
        }
        let mut g = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        let inner = &mut *g;
        if inner.map.contains_key(&key) {
            return Ok(data);
        }
        while inner.bytes + size > self.budget {
            let Some((_, old)) = inner.by_age.pop_first() else {
                break;
            };
            if let Some((d, _)) = inner.map.remove(&old) {
                inner.bytes -= d.byte_len() as u64;
            }
        }
        inner.tick += 1;
        let tick = inner.tick;
        inner.by_age.insert(tick, key);
        inner.map.insert(key, (data.clone(), tick));
        inner.bytes += size;
        Ok(data)
    }

    #[cfg(test)]
    pub(crate) fn held_bytes(&self) -> u64 {
        self.inner.lock().unwrap().bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_sizes() {
        assert_eq!(MemoryBudget::parse("512MiB").unwrap().0, 512 << 20);
        assert_eq!(MemoryBudget::parse("1GiB").unwrap().0, 1 << 30);
        assert_eq!(MemoryBudget::parse("2G").unwrap().0, 2 << 30);
        assert_eq!(MemoryBudget::parse("800MB").unwrap().0, 800_000_000);
        assert_eq!(MemoryBudget::parse("4096").unwrap().0, 4096);
        assert!(MemoryBudget::parse("lots").is_err());
        assert!(MemoryBudget::parse("5 parsecs").is_err());
        assert!(MemoryBudget::parse("-1G").is_err());
    }

    #[test]
    fn split_shares_in_proportion_and_never_exceeds_the_whole() {
        let b = MemoryBudget(1000);
        assert_eq!(b.split([1, 1, 1, 1]), [MemoryBudget(250); 4]);
        assert_eq!(b.split([1, 2]), [MemoryBudget(333), MemoryBudget(666)]);
        let big = MemoryBudget(u64::MAX);
        let [a, c] = big.split([1, 1]);
        assert_eq!(a.0, u64::MAX / 2);
        assert!(a.0 as u128 + c.0 as u128 <= u64::MAX as u128);
        for bytes in [0u64, 1, 7, 1 << 30, 12345678901] {
            let [q, ..] = MemoryBudget(bytes).split([1, 1, 1, 1]);
            assert_eq!(q.0, bytes / 4, "a quarter of {bytes}");
        }
    }

    #[test]
    fn cache_stays_within_budget_and_evicts_oldest() {
        let cache = ChunkCache::new(MemoryBudget(4000));
        let mut loads = 0;
        for k in 0..20u64 {
            cache
                .get_or_load((0, k), || {
                    loads += 1;
                    Ok(ChunkData::U8(vec![0; 900]))
                })
                .unwrap();
            assert!(cache.held_bytes() <= 4000);
        }
        assert_eq!(loads, 20);
        // the four most recent are cached, the oldest is not
        cache
            .get_or_load((0, 19), || panic!("19 should be cached"))
            .unwrap();
        let mut reloaded = false;
        cache
            .get_or_load((0, 0), || {
                reloaded = true;
                Ok(ChunkData::U8(vec![0; 900]))
            })
            .unwrap();
        assert!(reloaded);
    }
}
