//! The synthesis state over atlas texels, the dense surface it lives on, work
//! patches P(v) and their breadth-first traversal (section III-B, step 2).
//!
//! Both the surface (read from the `.gim` by tiles) and the state (written
//! back compressed to a scratch store beside the output) are paged
//! ([`super::pager`]): `--memory` bounds them however large the atlas.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::path::Path;
use std::sync::Arc;

use super::pager::{Pager, TileGrid, TileSource, TILE_TEXELS};
use super::sample::{dot_f32, Sample};
use crate::artifact::gim::{Gim, ZipperLinks, EMPTY, TILE};
use crate::artifact::quilt::NO_PATCH;
use crate::container::{MemoryBudget, Scratch};
use crate::field::StripePattern;
use crate::Result;

mod patch;
mod surface;
pub(crate) use patch::*;
pub(super) use surface::*;

/// Fewest tiles a pager holds whatever the budget (a work patch spans a
/// few).
const MIN_TILES: usize = 4;

/// Priority buckets of the "most constrained" choice (synthesized-neighbour
/// counts; 15 and more share the last).
const BUCKETS: usize = 16;

/// The synthesis state of one 64×64 tile (struct of arrays; texels outside
/// the atlas are padding).
#[derive(Clone)]
pub(super) struct StateTile {
    pub(super) synthesized: Vec<bool>,
    pub(super) coord: Vec<[f32; 2]>,
    /// Sample-space offset per +x and per +y atlas step (columns of the local
    /// Jacobian), to continue an old patch one texel into its neighbour.
    pub(super) jacobian: Vec<[f32; 4]>,
    pub(super) rotation: Vec<u8>,
    pub(super) patch: Vec<u32>,
    /// Index of the sample each texel draws from ([`Quilt::samples`](crate::quilt::Quilt::samples)):
    /// a texel of another sample than the active one (painting with a new
    /// sample) takes its vector from that sample's `State::foreign` entry.
    pub(super) source: Vec<u8>,
    /// m_σ(p): the sample's foreground mask at each texel's coordinate
    /// (when the sample has a mask).
    pub(super) mask: Vec<f32>,
    /// m0(p): the constraint function (1 on the painted region F, falling
    /// to 0 over the transition zone, 0 elsewhere), when constrained.
    pub(super) target: Vec<f32>,
    /// Synthesized-neighbour counts of unsynthesized texels.
    pub(super) count: Vec<u8>,
}

/// Bytes of a state tile.
const STATE_TILE_BYTES: usize = TILE_TEXELS * (1 + 8 + 16 + 1 + 4 + 1 + 4 + 4 + 1);

impl StateTile {
    fn blank() -> StateTile {
        StateTile {
            synthesized: vec![false; TILE_TEXELS],
            coord: vec![[0.0; 2]; TILE_TEXELS],
            jacobian: vec![[0.0; 4]; TILE_TEXELS],
            rotation: vec![0; TILE_TEXELS],
            patch: vec![NO_PATCH; TILE_TEXELS],
            source: vec![0; TILE_TEXELS],
            mask: vec![0.0; TILE_TEXELS],
            target: vec![0.0; TILE_TEXELS],
            count: vec![0; TILE_TEXELS],
        }
    }

    fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(STATE_TILE_BYTES);
        b.extend(self.synthesized.iter().map(|&s| s as u8));
        b.extend_from_slice(bytemuck::cast_slice(&self.coord));
        b.extend_from_slice(bytemuck::cast_slice(&self.jacobian));
        b.extend_from_slice(&self.rotation);
        b.extend_from_slice(bytemuck::cast_slice(&self.patch));
        b.extend_from_slice(&self.source);
        b.extend_from_slice(bytemuck::cast_slice(&self.mask));
        b.extend_from_slice(bytemuck::cast_slice(&self.target));
        b.extend_from_slice(&self.count);
        b
    }

    fn from_bytes(b: &[u8]) -> StateTile {
        let mut at = 0;
        let mut take = |bytes: usize| {
            at += bytes;
            &b[at - bytes..at]
        };
        let n = TILE_TEXELS;
        StateTile {
            synthesized: take(n).iter().map(|&s| s != 0).collect(),
            coord: bytemuck::pod_collect_to_vec(take(n * 8)),
            jacobian: bytemuck::pod_collect_to_vec(take(n * 16)),
            rotation: take(n).to_vec(),
            patch: bytemuck::pod_collect_to_vec(take(n * 4)),
            source: take(n).to_vec(),
            mask: bytemuck::pod_collect_to_vec(take(n * 4)),
            target: bytemuck::pod_collect_to_vec(take(n * 4)),
            count: take(n).to_vec(),
        }
    }
}

/// State tiles: blank until first evicted, then from the scratch store.
struct StateTiles {
    scratch: Scratch,
    /// The value of m0 on a tile never written (0 when constrained
    /// everywhere, e.g. by a foreground mask).
    target_default: f32,
}

impl TileSource<StateTile> for StateTiles {
    fn load(&mut self, k: usize) -> Result<StateTile> {
        if self.scratch.contains(k) {
            return Ok(StateTile::from_bytes(&self.scratch.get(k, STATE_TILE_BYTES)?));
        }
        let mut t = StateTile::blank();
        t.target.fill(self.target_default);
        Ok(t)
    }

    fn store(&mut self, k: usize, tile: &StateTile) -> Result<()> {
        self.scratch.put(k, &tile.to_bytes())
    }

    fn blank(&self) -> StateTile {
        StateTile::blank()
    }

    fn holds(&self, k: usize) -> bool {
        self.scratch.contains(k)
    }
}

/// Per tile, how many unsynthesized dense vertices each priority bucket
/// holds and the lowest id among them: the "most constrained" choice over
/// the whole atlas without holding its tiles.
struct Frontier {
    count: Vec<[u32; BUCKETS]>,
    first: Vec<[u32; BUCKETS]>,
    total: [u64; BUCKETS],
}

/// A sample a loaded surface draws from besides the active one (painting
/// with a new sample): its unrotated geometry maps and their projection into
/// the active sample's basis. Its texels' vectors are computed when read,
/// not held for the whole surface.
pub(super) struct ForeignSample {
    pub(super) sample: Sample,
    /// C = P_aᵀ P_k, `n × sample.n` row-major ([`basis_projection`](super::sample::basis_projection)).
    pub(super) projection: Vec<f32>,
}

impl ForeignSample {
    /// The vector at sample position `c` in the active basis, g ↦ C g (the
    /// closest vector of the active rank-n space; zero off a sample that
    /// does not tile).
    pub(super) fn features_into(&self, c: [f64; 2], out: &mut [f32]) {
        thread_local! {
            static SCRATCH: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
        }
        let m = self.sample.n;
        SCRATCH.with_borrow_mut(|g| {
            g.clear();
            g.resize(m, 0.0);
            self.sample.lookup(c, g);
            for (a, o) in out.iter_mut().enumerate() {
                *o = dot_f32(&self.projection[a * m..(a + 1) * m], g);
            }
        });
    }
}

/// Per-texel synthesis state (struct of arrays over paged atlas tiles).
pub(super) struct State {
    pub(super) r: usize,
    pub(super) n: usize,
    tiles: Pager<StateTile, StateTiles>,
    /// The sample new patches come from.
    pub(super) active: u8,
    /// The other samples a loaded surface draws from, by index (see
    /// [`Synthesis::load`](super::synthesis::Synthesis::load)); `None` for
    /// the active one and unused ones.
    pub(super) foreign: Arc<Vec<Option<ForeignSample>>>,
    /// Whether m0 is set (constrained synthesis).
    pub(super) constrained: bool,
    /// The id the next accepted patch gets.
    pub(super) next_patch: u32,
    pub(super) remaining: usize,
    frontier: Frontier,
}

impl State {
    /// An empty state over `surface`, its tiles paged within `budget`, their
    /// scratch store beside `output`.
    pub(super) fn new(surface: &Surface, n: usize, output: &Path, budget: MemoryBudget) -> Result<State> {
        let grid = surface.grid();
        let tiles = grid.tiles();
        let source = StateTiles {
            scratch: Scratch::create_beside(output, tiles)?,
            target_default: 0.0,
        };
        let pager = Pager::new(grid.r, source, budget.bytes(), STATE_TILE_BYTES as u64, MIN_TILES);
        let mut frontier = Frontier {
            count: vec![[0; BUCKETS]; tiles],
            first: vec![[u32::MAX; BUCKETS]; tiles],
            total: [0; BUCKETS],
        };
        let mut remaining = 0;
        for k in 0..tiles {
            frontier.count[k][0] = surface.covered[k];
            frontier.first[k][0] = surface.first_covered[k];
            remaining += surface.covered[k] as usize;
        }
        frontier.total[0] = remaining as u64;
        Ok(State {
            r: grid.r,
            n,
            tiles: pager,
            active: 0,
            foreign: Arc::default(),
            constrained: false,
            next_patch: 0,
            remaining,
            frontier,
        })
    }

    /// The state of `tiles` only, for a work patch computed on another
    /// thread ([`Pager::view`]; no frontier).
    pub(super) fn view(&self, tiles: &[usize]) -> State {
        State {
            r: self.r,
            n: self.n,
            tiles: self.tiles.view(tiles),
            active: self.active,
            foreign: Arc::clone(&self.foreign),
            constrained: self.constrained,
            next_patch: self.next_patch,
            remaining: self.remaining,
            frontier: Frontier {
                count: Vec::new(),
                first: Vec::new(),
                total: [0; BUCKETS],
            },
        }
    }

    /// Whether a view was read outside its tiles.
    pub(super) fn missed(&self) -> bool {
        self.tiles.missed()
    }

    /// Sets m0 = `value` everywhere.
    pub(super) fn constrain_everywhere(&mut self, value: f32) {
        // unconstrained, every tile holds the default m0 still
        let unchanged = !self.constrained && self.tiles.with_source(|s| s.target_default) == value;
        self.constrained = true;
        self.tiles.source_mut().target_default = value;
        if unchanged {
            return;
        }
        // tiles already made hold their own m0
        for k in 0..self.tiles.grid.tiles() {
            if self.tiles.made(k) {
                self.tiles.write_tile(k, |s| s.target.fill(value));
            }
        }
    }

    /// Reads texel `t` of its state tile.
    #[inline]
    pub(super) fn texel<R>(&self, t: u32, f: impl FnOnce(&StateTile, usize) -> R) -> R {
        self.tiles.read(t, f)
    }

    /// Changes texel `t` of its state tile.
    #[inline]
    pub(super) fn texel_mut<R>(&mut self, t: u32, f: impl FnOnce(&mut StateTile, usize) -> R) -> R {
        self.tiles.write(t, f)
    }

    /// Changes state tile `k` whole.
    pub(super) fn tile_mut<R>(&mut self, k: usize, f: impl FnOnce(&mut StateTile) -> R) -> R {
        self.tiles.write_tile(k, f)
    }

    /// Reads state tile `k` whole.
    pub(super) fn tile<R>(&self, k: usize, f: impl FnOnce(&StateTile) -> R) -> R {
        self.tiles.read_tile(k, f)
    }

    pub(super) fn synthesized(&self, t: u32) -> bool {
        self.texel(t, |s, i| s.synthesized[i])
    }
    pub(super) fn coord(&self, t: u32) -> [f32; 2] {
        self.texel(t, |s, i| s.coord[i])
    }
    pub(super) fn patch(&self, t: u32) -> u32 {
        self.texel(t, |s, i| s.patch[i])
    }
    /// m0 at `t` when constrained.
    pub(super) fn target(&self, t: u32) -> Option<f32> {
        self.constrained.then(|| self.texel(t, |s, i| s.target[i]))
    }

    /// The first error paging met (checked between steps).
    pub(super) fn take_error(&mut self) -> Result<()> {
        self.tiles.take_error()
    }

    /// How many tiles were read in so far.
    pub(super) fn tiles_read(&self) -> u64 {
        self.tiles.faults()
    }

    /// Compressed bytes evictions wrote so far.
    pub(super) fn scratch_bytes(&self) -> u64 {
        self.tiles.with_source(|s| s.scratch.written())
    }

    /// The most constrained unsynthesized texel (lowest id among equals).
    pub(super) fn most_constrained(&self) -> Option<u32> {
        let f = &self.frontier;
        let b = (0..BUCKETS).rev().find(|&b| f.total[b] > 0)?;
        f.first.iter().map(|first| first[b]).min()
    }

    /// The most constrained unsynthesized texel outside the `blocked`
    /// tiles with at least `min_count` synthesized neighbours (lowest id
    /// among equals).
    pub(super) fn most_constrained_outside(&self, blocked: &[bool], min_count: usize) -> Option<u32> {
        let f = &self.frontier;
        (min_count.min(BUCKETS - 1)..BUCKETS).rev().find_map(|b| {
            if f.total[b] == 0 {
                return None;
            }
            f.count
                .iter()
                .zip(&f.first)
                .zip(blocked)
                .filter(|((count, _), &blocked)| count[b] > 0 && !blocked)
                .map(|((_, first), _)| first[b])
                .min()
        })
    }

    /// Recounts the frontier of the tiles `changed` (sorted, distinct) after
    /// texels in them were synthesized or gained synthesized neighbours.
    pub(super) fn refresh_frontier(&mut self, surface: &Surface, changed: &[usize]) {
        let grid = surface.grid();
        for &k in changed {
            let (x0, y0, w, h) = grid.region(k);
            let chart = surface.chart_tile(k);
            let (mut count, mut first) = ([0u32; BUCKETS], [u32::MAX; BUCKETS]);
            self.tiles.read_tile(k, |s| {
                for y in 0..h {
                    for x in 0..w {
                        let i = y * TILE + x;
                        if chart[i] != EMPTY && !s.synthesized[i] {
                            let b = (s.count[i] as usize).min(BUCKETS - 1);
                            count[b] += 1;
                            first[b] = first[b].min(((y0 + y) * grid.r + x0 + x) as u32);
                        }
                    }
                }
            });
            let f = &mut self.frontier;
            for ((total, &old), &new) in f.total.iter_mut().zip(&f.count[k]).zip(&count) {
                *total = *total - old as u64 + new as u64;
            }
            f.count[k] = count;
            f.first[k] = first;
        }
    }

    /// Texel `t`'s stored sample coordinate and Jacobian (sample offset
    /// per atlas +x, +y).
    pub(super) fn coord_jacobian(&self, t: u32) -> ([f32; 2], [f32; 4]) {
        self.texel(t, |s, i| (s.coord[i], s.jacobian[i]))
    }

    /// The geometry-map vector of synthesized texel `t` in the active
    /// sample's basis, into `out` (`n` values).
    /// The features `t`'s patch would show one atlas step `step` (dx, dy)
    /// further on: its sample coordinate moved by its Jacobian (the old
    /// patch's value across a seam, Kwatra et al. 2003). False where that
    /// falls outside the sample.
    pub(super) fn continued(&self, sample: &Sample, t: u32, step: (f64, f64), out: &mut [f32]) -> bool {
        let (c, j) = self.coord_jacobian(t);
        let moved = [
            c[0] as f64 + j[0] as f64 * step.0 + j[2] as f64 * step.1,
            c[1] as f64 + j[1] as f64 * step.0 + j[3] as f64 * step.1,
        ];
        sample.lookup(moved, out)
    }

    /// Per texel of `texels`: whether it is synthesized, and its features
    /// (`n` per texel, 0 where it is not).
    pub(super) fn features_of(&self, sample: &Sample, texels: &[u32]) -> (Vec<bool>, Vec<f32>) {
        let n = self.n;
        let synthesized: Vec<bool> = texels.iter().map(|&t| self.synthesized(t)).collect();
        let mut features = vec![0f32; texels.len() * n];
        for ((&t, &s), out) in texels
            .iter()
            .zip(&synthesized)
            .zip(features.chunks_exact_mut(n.max(1)))
        {
            if s {
                self.feature_into(sample, t, &mut out[..n]);
            }
        }
        (synthesized, features)
    }

    pub(super) fn feature_into(&self, sample: &Sample, t: u32, out: &mut [f32]) {
        let (source, c) = self.texel(t, |s, i| (s.source[i], s.coord[i]));
        let c = [c[0] as f64, c[1] as f64];
        if let Some(other) = self.foreign.get(source as usize).and_then(Option::as_ref) {
            other.features_into(c, out);
            return;
        }
        if !sample.lookup(c, out) {
            out.fill(0.0);
        }
    }
}
