//! Atlas tiles paged in and out: the quilting loop's per-texel data lives in
//! 64×64 tiles ([`TILE`]), at most a budget's worth resident, the least
//! recently used evicted first (written back through their [`TileSource`]
//! when changed). Reads go through `&self` and fault a missing tile in, so
//! every step of the loop sees the whole atlas while only its working set is
//! held; the outcome never depends on which tiles are resident.
//!
//! A [`Pager::view`] shares some resident tiles read-only with a work patch
//! computed on another thread (tiles are reference-counted; a write after
//! the views are gone changes the tile in place).

use std::cell::RefCell;
use std::sync::Arc;

use crate::artifact::gim::TILE;
use crate::{Error, Result};

/// Texels per tile.
pub(super) const TILE_TEXELS: usize = TILE * TILE;

/// A texel id `y · R + x` split into its tile and its place in the tile,
/// with the division by R done by a multiply (Lemire's fastmod).
#[derive(Clone, Copy, Debug)]
pub(super) struct TileGrid {
    pub(super) r: usize,
    /// Tiles per atlas row.
    pub(super) across: usize,
    magic: u64,
}

impl TileGrid {
    pub(super) fn new(r: usize) -> TileGrid {
        TileGrid {
            r,
            across: r.div_ceil(TILE),
            // (for R = 1 every texel is its own row: magic 0 marks it)
            magic: if r > 1 { u64::MAX / r as u64 + 1 } else { 0 },
        }
    }

    /// Number of tiles.
    pub(super) fn tiles(&self) -> usize {
        self.across * self.across
    }

    /// (x, y) of texel `t`.
    #[inline]
    pub(super) fn xy(&self, t: u32) -> (usize, usize) {
        if self.magic == 0 {
            return (0, t as usize);
        }
        let y = ((self.magic as u128 * t as u128) >> 64) as usize;
        (t as usize - y * self.r, y)
    }

    /// Tile and place in the tile of texel `t`.
    #[inline]
    pub(super) fn locate(&self, t: u32) -> (usize, usize) {
        let (x, y) = self.xy(t);
        ((y / TILE) * self.across + x / TILE, (y % TILE) * TILE + x % TILE)
    }

    /// The atlas region of tile `k`: (x0, y0, width, height).
    pub(super) fn region(&self, k: usize) -> (usize, usize, usize, usize) {
        let (x0, y0) = ((k % self.across) * TILE, (k / self.across) * TILE);
        (x0, y0, TILE.min(self.r - x0), TILE.min(self.r - y0))
    }
}

/// Where a pager's tiles come from and go to.
pub(super) trait TileSource<T> {
    /// Tile `k` (from the input, or as last written back).
    fn load(&mut self, k: usize) -> Result<T>;
    /// Stores a changed tile `k` that is being evicted.
    fn store(&mut self, k: usize, tile: &T) -> Result<()>;
    /// A stand-in after a failed load (the error is kept and reported).
    fn blank(&self) -> T;
    /// Whether a tile was stored (not only derivable from the input).
    fn holds(&self, _k: usize) -> bool {
        false
    }
}

struct Inner<T, S> {
    resident: Vec<Option<(Arc<T>, bool)>>,
    used: Vec<u64>,
    tick: u64,
    count: usize,
    capacity: usize,
    /// Where tiles come from; `None` in a view, which holds only what it
    /// was given.
    source: Option<S>,
    /// A view's stand-in for a tile it was not given (`missed` is then set).
    blank: Option<Arc<T>>,
    missed: bool,
    error: Option<Error>,
    faults: u64,
}

/// Tiles of `T` over the atlas, at most `capacity` resident.
pub(super) struct Pager<T, S> {
    pub(super) grid: TileGrid,
    inner: RefCell<Inner<T, S>>,
}

impl<T: Clone, S: TileSource<T>> Pager<T, S> {
    /// A pager over an `r`×`r` atlas holding at most `budget` bytes of
    /// tiles of `tile_bytes` each (at least `min_tiles`).
    pub(super) fn new(r: usize, source: S, budget: u64, tile_bytes: u64, min_tiles: usize) -> Self {
        let grid = TileGrid::new(r);
        let tiles = grid.tiles();
        let capacity = ((budget / tile_bytes.max(1)) as usize)
            .max(min_tiles)
            .min(tiles)
            .max(1);
        Pager {
            grid,
            inner: RefCell::new(Inner {
                resident: (0..tiles).map(|_| None).collect(),
                used: vec![0; tiles],
                tick: 0,
                count: 0,
                capacity,
                source: Some(source),
                blank: None,
                missed: false,
                error: None,
                faults: 0,
            }),
        }
    }

    /// A read-only pager holding only `tiles` (faulted in here first),
    /// shared with this one: a read elsewhere in the view sees a blank tile
    /// and sets [`Pager::missed`]. Write to this pager only once its views
    /// are dropped (a write then changes the tile in place).
    pub(super) fn view(&self, tiles: &[usize]) -> Self {
        let mut inner = self.inner.borrow_mut();
        let mut resident: Vec<Option<(Arc<T>, bool)>> = (0..self.grid.tiles()).map(|_| None).collect();
        for &k in tiles {
            inner.fetch(k);
            let tile = &inner.resident[k].as_ref().expect("fetched").0;
            resident[k] = Some((Arc::clone(tile), false));
        }
        let blank = inner.source.as_ref().map(|s| Arc::new(s.blank()));
        Pager {
            grid: self.grid,
            inner: RefCell::new(Inner {
                count: tiles.len(),
                resident,
                used: Vec::new(),
                tick: 0,
                capacity: usize::MAX,
                source: None,
                blank,
                missed: false,
                error: None,
                faults: 0,
            }),
        }
    }

    /// Whether a view was read outside the tiles it was given.
    pub(super) fn missed(&self) -> bool {
        self.inner.borrow().missed
    }

    /// Reads texel `t` of its tile.
    #[inline]
    pub(super) fn read<R>(&self, t: u32, f: impl FnOnce(&T, usize) -> R) -> R {
        let (k, i) = self.grid.locate(t);
        let mut inner = self.inner.borrow_mut();
        let tile = inner.fetch(k);
        f(tile, i)
    }

    /// Reads tile `k` whole.
    pub(super) fn read_tile<R>(&self, k: usize, f: impl FnOnce(&T) -> R) -> R {
        let mut inner = self.inner.borrow_mut();
        f(inner.fetch(k))
    }

    /// Changes texel `t` of its tile.
    #[inline]
    pub(super) fn write<R>(&mut self, t: u32, f: impl FnOnce(&mut T, usize) -> R) -> R {
        let (k, i) = self.grid.locate(t);
        self.write_tile(k, |tile| f(tile, i))
    }

    /// Changes tile `k` whole.
    pub(super) fn write_tile<R>(&mut self, k: usize, f: impl FnOnce(&mut T) -> R) -> R {
        let inner = self.inner.get_mut();
        inner.fetch(k);
        let (tile, dirty) = inner.resident[k].as_mut().expect("fetched");
        *dirty = true;
        f(Arc::make_mut(tile))
    }

    /// Whether tile `k` is resident or was ever written back (else its
    /// source makes it afresh).
    pub(super) fn made(&self, k: usize) -> bool {
        let inner = self.inner.borrow();
        inner.resident[k].is_some() || inner.source.as_ref().is_some_and(|s| s.holds(k))
    }

    /// The first error a fault met (reads carry on with blank tiles, so
    /// the loop checks this between steps).
    pub(super) fn take_error(&mut self) -> Result<()> {
        match self.inner.get_mut().error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The source (not of a view).
    pub(super) fn source_mut(&mut self) -> &mut S {
        self.inner.get_mut().source.as_mut().expect("not a view")
    }

    /// Reads the source (not of a view).
    pub(super) fn with_source<R>(&self, f: impl FnOnce(&S) -> R) -> R {
        f(self.inner.borrow().source.as_ref().expect("not a view"))
    }

    /// How many tiles were read in so far.
    pub(super) fn faults(&self) -> u64 {
        self.inner.borrow().faults
    }

    /// Tiles resident now.
    #[cfg(test)]
    pub(super) fn resident(&self) -> usize {
        self.inner.borrow().count
    }
}

impl<T, S: TileSource<T>> Inner<T, S> {
    #[inline]
    fn fetch(&mut self, k: usize) -> &T {
        if self.resident[k].is_some() {
            if let Some(u) = self.used.get_mut(k) {
                self.tick += 1;
                *u = self.tick;
            }
        } else {
            self.fault(k);
        }
        &self.resident[k].as_ref().expect("fetched").0
    }

    #[cold]
    fn fault(&mut self, k: usize) {
        let Some(source) = self.source.as_mut() else {
            // a view: only what it was given
            self.missed = true;
            self.resident[k] = self.blank.clone().map(|b| (b, false));
            return;
        };
        self.tick += 1;
        self.used[k] = self.tick;
        self.faults += 1;
        if self.count >= self.capacity {
            let oldest = (0..self.resident.len())
                .filter(|&j| j != k && self.resident[j].is_some())
                .min_by_key(|&j| self.used[j]);
            if let Some(j) = oldest {
                let (tile, dirty) = self.resident[j].take().expect("resident");
                self.count -= 1;
                if dirty {
                    if let Err(e) = source.store(j, &tile) {
                        self.error.get_or_insert(e);
                    }
                }
            }
        }
        let tile = match source.load(k) {
            Ok(t) => t,
            Err(e) => {
                self.error.get_or_insert(e);
                source.blank()
            }
        };
        self.resident[k] = Some((Arc::new(tile), false));
        self.count += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tiles of u32 whose texels start as their own ids; stores count.
    struct Ids {
        r: usize,
        stored: std::collections::HashMap<usize, Vec<u32>>,
    }

    impl TileSource<Vec<u32>> for Ids {
        fn load(&mut self, k: usize) -> Result<Vec<u32>> {
            if let Some(v) = self.stored.get(&k) {
                return Ok(v.clone());
            }
            let g = TileGrid::new(self.r);
            let (x0, y0, w, h) = g.region(k);
            let mut v = vec![u32::MAX; TILE_TEXELS];
            for y in 0..h {
                for x in 0..w {
                    v[y * TILE + x] = ((y0 + y) * self.r + x0 + x) as u32;
                }
            }
            Ok(v)
        }
        fn store(&mut self, k: usize, tile: &Vec<u32>) -> Result<()> {
            self.stored.insert(k, tile.clone());
            Ok(())
        }
        fn blank(&self) -> Vec<u32> {
            vec![0; TILE_TEXELS]
        }
    }

    #[test]
    fn the_grid_splits_every_texel_like_division_does() {
        for r in [1usize, 63, 64, 65, 160, 1000, 4096, 32768] {
            let g = TileGrid::new(r);
            let total = (r * r) as u64;
            let step = (total / 5000).max(1);
            for t in (0..total).step_by(step as usize).chain([total - 1]) {
                let t = t as u32;
                let (x, y) = (t as usize % r, t as usize / r);
                assert_eq!(g.xy(t), (x, y), "r {r} t {t}");
                let (k, i) = g.locate(t);
                let (x0, y0, w, h) = g.region(k);
                assert!(x >= x0 && x < x0 + w && y >= y0 && y < y0 + h);
                assert_eq!(i, (y - y0) * TILE + x - x0);
            }
        }
    }

    #[test]
    fn evicted_changes_come_back_whatever_the_capacity() {
        let r = 300;
        for capacity in [1usize, 2, 7, 100] {
            let mut p = Pager::new(
                r,
                Ids {
                    r,
                    stored: Default::default(),
                },
                capacity as u64,
                1,
                1,
            );
            // every texel read once, then doubled, in an order that hops tiles
            let order: Vec<u32> = (0..(r * r) as u32).map(|i| (i * 7919) % (r * r) as u32).collect();
            for &t in &order {
                assert_eq!(p.read(t, |tile, i| tile[i]), t);
                p.write(t, |tile, i| tile[i] *= 2);
            }
            for t in 0..(r * r) as u32 {
                assert_eq!(p.read(t, |tile, i| tile[i]), 2 * t, "capacity {capacity}");
            }
            assert!(p.resident() <= capacity.max(1));
            p.take_error().unwrap();
        }
    }
}
