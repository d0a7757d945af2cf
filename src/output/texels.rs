//! The atlas as the renderer looks it up: tiles of per-texel shading data
//! (the BTF lookup's sample coordinates and frames, or the dilated preview
//! colour), computed from the quilt on demand and held in one
//! [`SharedCache`] the render threads share, so a frame of any atlas size
//! stays within `--memory`. Every tile is a pure function of the quilt: what
//! the cache holds changes the time a frame takes, never its pixels.

use std::sync::{Arc, Mutex};

use crate::artifact::gim::TILE;
use crate::container::{MemoryBudget, SharedCache, Weighed};
use crate::io::imageio::{dilate_with, RgbImage};
use crate::math;
use crate::quilt::{Quilt, NO_PATCH};
use crate::{Error, Result};

/// What a BTF lookup needs of the texels of one atlas tile (row-major over
/// the tile's own extent): sample coordinate, Jacobian, sample index, and
/// whether a patch covers the texel.
pub(crate) struct BtfTile {
    pub coord: Vec<[f32; 2]>,
    pub jacobian: Vec<[f32; 4]>,
    pub sample: Vec<u8>,
    pub covered: Vec<bool>,
}

impl Weighed for BtfTile {
    fn weight(&self) -> u64 {
        (self.coord.len() * 26) as u64
    }
}

/// The dilated preview colour of one atlas tile (RGB, row-major).
pub(crate) struct ColourTile(pub Vec<f32>);

impl Weighed for ColourTile {
    fn weight(&self) -> u64 {
        (self.0.len() * 4) as u64
    }
}

type Loader<T> = Box<dyn Fn(usize, usize, usize, usize) -> Result<T> + Send + Sync>;

/// The atlas in [`TILE`]² tiles of `T`, loaded by `load(x0, y0, w, h)` when
/// first needed. A tile that fails to load reads as empty and its error is
/// kept for [`AtlasTiles::check`].
pub(crate) struct AtlasTiles<T> {
    r: usize,
    per_row: usize,
    cache: SharedCache<usize, T>,
    load: Loader<T>,
    error: Mutex<Option<Error>>,
}

impl<T: Weighed> AtlasTiles<T> {
    pub fn new(r: usize, budget: MemoryBudget, load: Loader<T>) -> AtlasTiles<T> {
        AtlasTiles {
            r,
            per_row: r.div_ceil(TILE),
            cache: SharedCache::new(budget),
            load,
            error: Mutex::new(None),
        }
    }

    /// Tile `k` (row-major over the tile grid), or `None` if it failed to load.
    fn tile(&self, k: usize) -> Option<Arc<T>> {
        let (x0, y0) = (k % self.per_row * TILE, k / self.per_row * TILE);
        let (w, h) = (TILE.min(self.r - x0), TILE.min(self.r - y0));
        match self.cache.get_or_load(k, || (self.load)(x0, y0, w, h)) {
            Ok(t) => Some(t),
            Err(e) => {
                let mut slot = crate::lock(&self.error);
                slot.get_or_insert(e);
                None
            }
        }
    }

    /// Loads the first tile now, so a quilt whose arrays are missing or
    /// malformed is refused before anything is drawn.
    pub fn probe(&self) -> Result<()> {
        self.tile(0);
        self.check()
    }

    /// The first error a tile load met (taken: the next check is clean).
    pub fn check(&self) -> Result<()> {
        match crate::lock(&self.error).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// A view for one thread's lookups.
    pub fn view(&self) -> TileView<'_, T> {
        TileView {
            tiles: self,
            last: None,
        }
    }
}

/// Lookups into [`AtlasTiles`] that keep the last tile used, so the texels
/// around one pixel cost one cache visit.
pub(crate) struct TileView<'a, T> {
    tiles: &'a AtlasTiles<T>,
    last: Option<(usize, Arc<T>)>,
}

impl<T: Weighed> TileView<'_, T> {
    /// `f(tile, index in tile)` for atlas texel `t`; `None` if its tile
    /// failed to load.
    pub fn with<R>(&mut self, t: usize, f: impl FnOnce(&T, usize) -> R) -> Option<R> {
        let r = self.tiles.r;
        let (x, y) = (t % r, t / r);
        let k = y / TILE * self.tiles.per_row + x / TILE;
        if !matches!(&self.last, Some((held, _)) if *held == k) {
            self.last = Some((k, self.tiles.tile(k)?));
        }
        let (_, tile) = self.last.as_ref().expect("just set");
        let w = TILE.min(r - x / TILE * TILE);
        Some(f(tile, (y % TILE) * w + x % TILE))
    }
}

/// The BTF lookup's tiles of `quilt`: a texel's Jacobian is the stored one,
/// or, where it is missing or degenerate, its rotation's (in steps of its
/// own sample's `steps[k]` rotations a turn).
pub(crate) fn btf_tiles(quilt: Arc<Quilt>, steps: Vec<usize>, budget: MemoryBudget) -> AtlasTiles<BtfTile> {
    let r = quilt.resolution;
    let load = move |x0: usize, y0: usize, w: usize, h: usize| -> Result<BtfTile> {
        let coord = quilt.coord_region(x0, y0, w, h)?;
        let patch = quilt.patch_region(x0, y0, w, h)?;
        let rotation = quilt.rotation_region(x0, y0, w, h)?;
        let sample = quilt.sample_region(x0, y0, w, h)?;
        let stored = quilt.jacobian_region(x0, y0, w, h)?;
        let jacobian = (0..w * h)
            .map(|t| match stored.as_ref().map(|s| s[t]) {
                Some(j) if j.iter().all(|v| v.is_finite()) && (j[0] * j[3] - j[1] * j[2]).abs() > 1e-8 => j,
                _ => {
                    let steps = steps[sample[t] as usize].max(1) as f32;
                    let a = rotation[t] as f32 * std::f32::consts::TAU / steps;
                    let (s, c) = math::sin_cos(a);
                    [c, -s, s, c]
                }
            })
            .collect();
        Ok(BtfTile {
            coord,
            jacobian,
            sample,
            covered: patch.iter().map(|&p| p != NO_PATCH).collect(),
        })
    };
    AtlasTiles::new(r, budget, Box::new(load))
}

/// The preview colour's tiles of `quilt`, dilated `passes` rings as the whole
/// atlas would be (each tile computed with `passes` texels of context),
/// with `fill` (the whole atlas's covered mean) where dilation leaves texels
/// empty.
pub(crate) fn colour_tiles(
    quilt: Arc<Quilt>,
    previews: Vec<RgbImage>,
    passes: usize,
    fill: [f32; 3],
    budget: MemoryBudget,
) -> AtlasTiles<ColourTile> {
    let r = quilt.resolution;
    let load = move |x0: usize, y0: usize, w: usize, h: usize| -> Result<ColourTile> {
        let (xa, ya) = (x0.saturating_sub(passes), y0.saturating_sub(passes));
        let (xb, yb) = ((x0 + w + passes).min(r), (y0 + h + passes).min(r));
        let (colour, covered) = super::colour_region(&quilt, &previews, xa, ya, xb - xa, yb - ya)?;
        let mut img = RgbImage {
            width: xb - xa,
            height: yb - ya,
            data: colour,
        };
        dilate_with(&mut img, &covered, passes, fill);
        let mut out = Vec::with_capacity(w * h * 3);
        for y in y0..y0 + h {
            let row = ((y - ya) * img.width + x0 - xa) * 3;
            out.extend_from_slice(&img.data[row..row + w * 3]);
        }
        Ok(ColourTile(out))
    };
    AtlasTiles::new(r, budget, Box::new(load))
}
