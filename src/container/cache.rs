//! A chunk cache bounded by a byte budget (`--memory`), least recently used
//! chunks evicted first.

use std::collections::{BTreeMap, HashMap};
use std::hash::Hash;
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

    /// The budget less `held` bytes (what a stage holds besides the caches
    /// and buffers it budgets: the program itself, data it keeps whole),
    /// never less than half of it: what those caches and buffers share.
    pub fn less(self, held: u64) -> MemoryBudget {
        MemoryBudget(self.0 - held.min(self.0 / 2))
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

/// Whether a cache's value is also held outside the cache: its memory
/// lives on when the cache lets it go ([`BoundedCache`] counts it until it
/// is dropped).
pub trait Held {
    fn held_elsewhere(&self) -> bool;
}

impl<T: ?Sized> Held for Arc<T> {
    fn held_elsewhere(&self) -> bool {
        Arc::strong_count(self) > 1
    }
}

impl<T> Held for Vec<T> {
    fn held_elsewhere(&self) -> bool {
        false
    }
}

impl<T: ?Sized> Held for &T {
    fn held_elsewhere(&self) -> bool {
        false
    }
}

/// A map bounded by a byte budget, least recently used entries evicted
/// first: the one cache type behind every cache (decoded chunks, the rotated
/// copies of a sample, the matcher's sample spectra). The newest entry is
/// always kept, even when it alone exceeds the budget, unless it was put in
/// with [`BoundedCache::insert_if_fits`] or [`BoundedCache::reserve`]d.
///
/// An entry a user still holds ([`Held`]) frees nothing when evicted, so it
/// is not: entries in use stay, and count against the budget until their
/// users drop them, as do those [`clear`](BoundedCache::clear)ed while held
/// and the room [`reserve`](BoundedCache::reserve)d for entries being made.
pub struct BoundedCache<K, V> {
    budget: u64,
    map: HashMap<K, (V, u64, u64)>,
    by_age: BTreeMap<u64, K>,
    bytes: u64,
    tick: u64,
    /// Room promised to entries being made ([`BoundedCache::reserve`]).
    reserved: u64,
    /// Entries cleared or replaced while held elsewhere, until their
    /// users drop them.
    out: Vec<(V, u64)>,
}

impl<K: Hash + Eq + Clone, V: Held> BoundedCache<K, V> {
    /// An empty cache of at most `budget` bytes.
    pub fn new(budget: MemoryBudget) -> Self {
        BoundedCache {
            budget: budget.0,
            map: HashMap::new(),
            by_age: BTreeMap::new(),
            bytes: 0,
            tick: 0,
            reserved: 0,
            out: Vec::new(),
        }
    }

    /// The budget in bytes.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Bytes held (as given to [`insert`](Self::insert)).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// Whether `key` is cached (does not count as a use).
    pub fn contains(&self, key: &K) -> bool {
        self.map.contains_key(key)
    }

    /// The entry for `key` without counting it as a use.
    pub fn peek(&self, key: &K) -> Option<&V> {
        self.map.get(key).map(|(v, _, _)| v)
    }

    /// The entry for `key`, now the most recently used.
    pub fn get(&mut self, key: &K) -> Option<&V> {
        self.tick += 1;
        let tick = self.tick;
        let (v, _, age) = self.map.get_mut(key)?;
        self.by_age.remove(age);
        *age = tick;
        self.by_age.insert(tick, key.clone());
        Some(v)
    }

    /// Inserts (or replaces) `key` holding `bytes`, first evicting the least
    /// recently used entries not in use until it fits (or none is left).
    pub fn insert(&mut self, key: K, value: V, bytes: u64) {
        if let Some((old, b, age)) = self.map.remove(&key) {
            self.by_age.remove(&age);
            self.bytes -= b;
            self.let_go(old, b);
        }
        self.reap();
        while self.bytes + self.pinned_out() + bytes > self.budget && self.evict_oldest() {}
        self.tick += 1;
        self.by_age.insert(self.tick, key.clone());
        self.map.insert(key, (value, bytes, self.tick));
        self.bytes += bytes;
    }

    /// Bytes that evicting entries cannot free: entries in use, entries let
    /// go while in use, and the room reserved.
    pub fn pinned(&mut self) -> u64 {
        self.reap();
        let in_use: u64 = self
            .map
            .values()
            .filter(|(v, _, _)| v.held_elsewhere())
            .map(|&(_, b, _)| b)
            .sum();
        in_use + self.pinned_out()
    }

    /// Whether [`insert_if_fits`](Self::insert_if_fits) keeps an entry of
    /// `bytes` now: it fits the budget beside the [`pinned`](Self::pinned)
    /// bytes.
    pub fn fits(&mut self, bytes: u64) -> bool {
        bytes.saturating_add(self.pinned()) <= self.budget
    }

    /// [`insert`](Self::insert), unless the entry does not [`fit`](Self::fits):
    /// it is then not kept and evicts nothing (for values made again when
    /// needed, so that one too large does not empty the cache of the small
    /// ones). Whether it was kept.
    pub fn insert_if_fits(&mut self, key: K, value: V, bytes: u64) -> bool {
        let fits = self.fits(bytes);
        if fits {
            self.insert(key, value, bytes);
        }
        fits
    }

    /// Reserves room for an entry of `bytes` about to be made, if it
    /// [`fits`](Self::fits): the room counts as in use until the entry is
    /// put in with [`insert_reserved`](Self::insert_reserved) or the room
    /// given back with [`unreserve`](Self::unreserve), so that users making
    /// entries at once do not each count on the same room. Whether it was
    /// reserved.
    pub fn reserve(&mut self, bytes: u64) -> bool {
        let fits = self.fits(bytes);
        if fits {
            self.reserved += bytes;
        }
        fits
    }

    /// Gives back room [`reserve`](Self::reserve)d for `bytes`.
    pub fn unreserve(&mut self, bytes: u64) {
        self.reserved -= bytes.min(self.reserved);
    }

    /// Puts in an entry of `bytes` made in the room reserved for `reserved`
    /// bytes ([`reserve`](Self::reserve)), as
    /// [`insert_if_fits`](Self::insert_if_fits) does (it fits unless the
    /// budget shrank meanwhile). Whether it was kept.
    pub fn insert_reserved(&mut self, key: K, value: V, reserved: u64, bytes: u64) -> bool {
        self.unreserve(reserved);
        self.insert_if_fits(key, value, bytes)
    }

    /// Sets the budget, evicting the least recently used entries not in use
    /// until the rest fit (the newest kept whatever its size).
    pub fn set_budget(&mut self, budget: MemoryBudget) {
        self.budget = budget.0;
        self.reap();
        while self.bytes + self.pinned_out() > self.budget && self.map.len() > 1 && self.evict_oldest() {}
    }

    /// Evicts the least recently used entry not in use; `false` when there
    /// was none.
    fn evict_oldest(&mut self) -> bool {
        let Some((&age, _)) = self
            .by_age
            .iter()
            .find(|(_, k)| self.map.get(*k).is_some_and(|(v, _, _)| !v.held_elsewhere()))
        else {
            return false;
        };
        let key = self.by_age.remove(&age).expect("found above");
        if let Some((_, b, _)) = self.map.remove(&key) {
            self.bytes -= b;
        }
        true
    }

    /// Keeps counting `value` while its users hold it.
    fn let_go(&mut self, value: V, bytes: u64) {
        if value.held_elsewhere() {
            self.out.push((value, bytes));
        }
    }

    /// Drops the entries let go whose users have dropped them.
    fn reap(&mut self) {
        self.out.retain(|(v, _)| v.held_elsewhere());
    }

    /// Bytes of the entries let go but still held, and the room reserved.
    fn pinned_out(&self) -> u64 {
        self.out.iter().map(|&(_, b)| b).sum::<u64>() + self.reserved
    }

    /// Drops every entry (those still in use count until their users drop
    /// them).
    pub fn clear(&mut self) {
        self.by_age.clear();
        let map = std::mem::take(&mut self.map);
        for (_, (v, b, _)) in map {
            self.let_go(v, b);
        }
        self.bytes = 0;
        self.reap();
    }
}

type Key = (u32, u64);

/// What a [`SharedCache`] value costs in bytes.
pub trait Weighed {
    fn weight(&self) -> u64;
}

impl Weighed for Vec<f32> {
    fn weight(&self) -> u64 {
        self.len() as u64 * 4
    }
}

impl Weighed for ChunkData {
    fn weight(&self) -> u64 {
        self.byte_len() as u64
    }
}

/// A [`BoundedCache`] shared between threads: values behind `Arc`, loaded
/// outside the lock (two threads may load the same key; both get equal
/// values), never holding more than the budget.
pub struct SharedCache<K, V> {
    inner: Mutex<BoundedCache<K, Arc<V>>>,
}

/// Decoded chunks of a container.
pub(crate) type ChunkCache = SharedCache<Key, ChunkData>;

impl<K: Hash + Eq + Clone, V: Weighed> SharedCache<K, V> {
    pub fn new(budget: MemoryBudget) -> Self {
        SharedCache {
            inner: Mutex::new(BoundedCache::new(budget)),
        }
    }

    /// The cached value, or `load()`'s result (cached if it fits the budget).
    pub fn get_or_load(&self, key: K, load: impl FnOnce() -> Result<V>) -> Result<Arc<V>> {
        if let Some(data) = crate::lock(&self.inner).get(&key) {
            return Ok(data.clone());
        }
        let data = Arc::new(load()?);
        let size = data.weight();
        let mut cache = crate::lock(&self.inner);
        // too large to be worth caching under this budget
        if size * 4 > cache.budget() || cache.contains(&key) {
            return Ok(data);
        }
        cache.insert(key, data.clone(), size);
        Ok(data)
    }

    #[cfg(test)]
    pub(crate) fn held_bytes(&self) -> u64 {
        self.inner.lock().unwrap().bytes()
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
    fn bounded_cache_evicts_least_recently_used_and_keeps_the_newest() {
        let mut c: BoundedCache<u32, &str> = BoundedCache::new(MemoryBudget(30));
        c.insert(1, "a", 10);
        c.insert(2, "b", 10);
        c.insert(3, "c", 10);
        assert_eq!(c.get(&1), Some(&"a")); // 1 is now the most recent
        c.insert(4, "d", 10); // evicts 2, the least recently used
        assert!(!c.contains(&2) && c.contains(&1) && c.contains(&3) && c.contains(&4));
        assert_eq!(c.bytes(), 30);
        c.insert(5, "e", 100); // larger than the budget: kept alone
        assert_eq!((c.len(), c.bytes()), (1, 100));
        assert_eq!(c.peek(&5), Some(&"e"));
        c.insert(5, "f", 5); // replacing updates the bytes held
        assert_eq!((c.len(), c.bytes()), (1, 5));
        c.insert(6, "g", 10);
        c.insert(7, "h", 10);
        assert_eq!(c.get(&5), Some(&"f")); // 6 is now the least recently used
        c.set_budget(MemoryBudget(16)); // shrinking evicts down to the budget
        assert!(!c.contains(&6) && c.contains(&7) && c.contains(&5));
        assert_eq!((c.len(), c.bytes(), c.budget()), (2, 15, 16));
        c.insert(8, "i", 10); // and the new budget holds from then on
        assert!(!c.contains(&7) && c.contains(&5) && c.contains(&8) && c.bytes() == 15);
        c.set_budget(MemoryBudget(1)); // the newest stays, whatever its size
        assert_eq!((c.len(), c.bytes()), (1, 10));
        assert!(c.contains(&8));
        c.set_budget(MemoryBudget(100)); // growing evicts nothing
        assert_eq!(c.len(), 1);
        c.clear();
        assert!(c.is_empty() && c.bytes() == 0);
    }

    #[test]
    fn an_entry_larger_than_the_budget_put_in_if_it_fits_is_dropped_and_evicts_nothing() {
        let mut c = BoundedCache::new(MemoryBudget(30));
        assert!(c.insert_if_fits(1, "a", 10));
        assert!(c.insert_if_fits(2, "b", 10));
        assert!(!c.insert_if_fits(3, "c", 31));
        assert!(c.contains(&1) && c.contains(&2) && !c.contains(&3));
        assert_eq!(c.bytes(), 20);
        // one that fits evicts the least recently used as `insert` does
        c.get(&1);
        assert!(c.insert_if_fits(4, "d", 15));
        assert!(c.contains(&1) && !c.contains(&2) && c.contains(&4));
        assert_eq!(c.bytes(), 25);
    }

    #[test]
    fn entries_in_use_stay_and_count_until_their_users_drop_them() {
        let mut c = BoundedCache::new(MemoryBudget(30));
        c.insert(1, Arc::new("a"), 10);
        c.insert(2, Arc::new("b"), 10);
        let held = Arc::clone(c.get(&1).unwrap()); // 1 in use, and the newest
        c.get(&2);
        // evicting must free room: 2, not the older 1 in use, goes
        assert_eq!(c.pinned(), 10);
        assert!(c.fits(20) && !c.fits(21));
        assert!(c.insert_if_fits(3, Arc::new("c"), 20));
        assert!(c.contains(&1) && !c.contains(&2) && c.contains(&3));
        assert!(!c.insert_if_fits(4, Arc::new("d"), 21));
        // a cleared entry in use counts until dropped
        c.clear();
        assert!(c.is_empty() && c.bytes() == 0);
        assert_eq!(c.pinned(), 10);
        assert!(!c.fits(21));
        drop(held);
        assert_eq!(c.pinned(), 0);
        assert!(c.fits(30));
        // as does one replaced while in use, and a shrunk budget keeps it
        c.insert(5, Arc::new("a"), 10);
        let held = Arc::clone(c.get(&5).unwrap());
        c.insert(5, Arc::new("e"), 5);
        assert_eq!((c.bytes(), c.pinned()), (5, 10));
        c.insert(6, Arc::new("f"), 10);
        c.set_budget(MemoryBudget(20));
        assert!(!c.contains(&5) && c.contains(&6), "the oldest not in use goes");
        drop(held);
        assert_eq!(c.pinned(), 0);
    }

    #[test]
    fn reserved_room_counts_until_filled_or_given_back() {
        let mut c = BoundedCache::new(MemoryBudget(30));
        assert!(c.reserve(20));
        assert!(!c.reserve(11), "two users cannot count on the same room");
        assert!(c.reserve(10));
        assert_eq!(c.pinned(), 30);
        c.unreserve(10);
        assert!(c.insert_reserved(1, Arc::new("a"), 20, 18));
        assert_eq!((c.bytes(), c.pinned()), (18, 0));
        // an unused entry gives way to a reservation
        assert!(c.reserve(25));
        assert!(c.insert_reserved(2, Arc::new("b"), 25, 25));
        assert!(!c.contains(&1) && c.contains(&2));
        // a budget shrunk meanwhile keeps what no longer fits out
        assert!(c.reserve(30));
        c.set_budget(MemoryBudget(20));
        assert!(!c.insert_reserved(3, Arc::new("c"), 30, 30));
        assert!(!c.contains(&3) && c.pinned() == 0);
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
