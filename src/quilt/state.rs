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
use super::sample::Sample;
use crate::artifact::gim::{Gim, ZipperLinks, EMPTY, TILE};
use crate::artifact::quilt::NO_PATCH;
use crate::container::{MemoryBudget, Scratch};
use crate::Result;

/// No foreign feature vector (a texel of the active sample).
pub(super) const NO_FOREIGN: u32 = u32::MAX;

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
    /// Index of the sample each texel draws from ([`Quilt::samples`](crate::quilt::Quilt::samples)).
    pub(super) source: Vec<u8>,
    /// Texels of other samples than the active one (painting with a new
    /// sample): index into `State::foreign_features` (`NO_FOREIGN` for texels
    /// of the active sample, whose geometry-map vectors are looked up in it
    /// at their coordinate when needed, not stored).
    pub(super) foreign: Vec<u32>,
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
const STATE_TILE_BYTES: usize = TILE_TEXELS * (1 + 8 + 16 + 1 + 4 + 1 + 4 + 4 + 4 + 1);

impl StateTile {
    fn blank() -> StateTile {
        StateTile {
            synthesized: vec![false; TILE_TEXELS],
            coord: vec![[0.0; 2]; TILE_TEXELS],
            jacobian: vec![[0.0; 4]; TILE_TEXELS],
            rotation: vec![0; TILE_TEXELS],
            patch: vec![NO_PATCH; TILE_TEXELS],
            source: vec![0; TILE_TEXELS],
            foreign: vec![NO_FOREIGN; TILE_TEXELS],
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
        b.extend_from_slice(bytemuck::cast_slice(&self.foreign));
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
            foreign: bytemuck::pod_collect_to_vec(take(n * 4)),
            mask: bytemuck::pod_collect_to_vec(take(n * 4)),
            target: bytemuck::pod_collect_to_vec(take(n * 4)),
            count: take(n).to_vec(),
        }
    }
}

/// State tiles: blank until first evicted, then from the scratch store.
pub(super) struct StateTiles {
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

/// Per-texel synthesis state (struct of arrays over paged atlas tiles).
pub(super) struct State {
    pub(super) r: usize,
    pub(super) n: usize,
    tiles: Pager<StateTile, StateTiles>,
    /// The sample new patches come from.
    pub(super) active: u8,
    /// Geometry-map vectors of foreign texels projected into the active
    /// sample's basis (see [`Synthesis::load`](super::synthesis::Synthesis::load)), `n` per entry.
    pub(super) foreign_features: Arc<Vec<f32>>,
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
            foreign_features: Arc::default(),
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
            foreign_features: Arc::clone(&self.foreign_features),
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

    /// The geometry-map vector of synthesized texel `t` in the active
    /// sample's basis, into `out` (`n` values).
    /// The features `t`'s patch would show one atlas step `step` (dx, dy)
    /// further on: its sample coordinate moved by its Jacobian (the old
    /// patch's value across a seam, Kwatra et al. 2003). False where that
    /// falls outside the sample.
    pub(super) fn continued(&self, sample: &Sample, t: u32, step: (f64, f64), out: &mut [f32]) -> bool {
        let (j, c) = self.texel(t, |s, i| (s.jacobian[i], s.coord[i]));
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
        let (f, c) = self.texel(t, |s, i| (s.foreign[i], s.coord[i]));
        if f != NO_FOREIGN {
            let f = f as usize * self.n;
            out.copy_from_slice(&self.foreign_features[f..f + self.n]);
            return;
        }
        if !sample.lookup([c[0] as f64, c[1] as f64], out) {
            out.fill(0.0);
        }
    }
}

/// The per-texel surface of one tile, from the `.gim`.
#[derive(Clone)]
pub(super) struct SurfaceTile {
    pub(super) chart: Vec<u32>,
    pub(super) face: Vec<u32>,
    /// Positions multiplied by the surface's `unit`.
    pub(super) position: Vec<[f32; 3]>,
    pub(super) normal: Vec<[f32; 3]>,
}

/// Bytes of a surface tile.
const SURFACE_TILE_BYTES: usize = TILE_TEXELS * (4 + 4 + 12 + 12);

/// Surface tiles read from the geometry image (never written back).
pub(super) struct GimTiles {
    gim: Gim,
    grid: TileGrid,
    unit: f32,
}

impl TileSource<SurfaceTile> for GimTiles {
    fn load(&mut self, k: usize) -> Result<SurfaceTile> {
        let (x0, y0, w, h) = self.grid.region(k);
        let region = self.gim.texel_region(x0, y0, w, h)?;
        let mut tile = self.blank();
        for y in 0..h {
            for x in 0..w {
                let (i, j) = (y * TILE + x, y * w + x);
                tile.chart[i] = region.chart[j];
                tile.face[i] = region.face[j];
                let p = &region.position[j * 3..j * 3 + 3];
                tile.position[i] = [p[0], p[1], p[2]].map(|c| c * self.unit);
                let q = &region.normal[j * 3..j * 3 + 3];
                tile.normal[i] = [q[0], q[1], q[2]];
            }
        }
        Ok(tile)
    }

    fn store(&mut self, _: usize, _: &SurfaceTile) -> Result<()> {
        Ok(())
    }

    fn blank(&self) -> SurfaceTile {
        SurfaceTile {
            chart: vec![EMPTY; TILE_TEXELS],
            face: vec![0; TILE_TEXELS],
            position: vec![[0.0; 3]; TILE_TEXELS],
            normal: vec![[0.0; 3]; TILE_TEXELS],
        }
    }
}

/// Everything the loop reads of the dense mesh M_d: per texel (paged) the
/// chart, face, position and normal; the zipper links; the field angle per
/// face.
pub(super) struct Surface {
    pub(super) r: usize,
    tiles: Pager<SurfaceTile, GimTiles>,
    zippers: Arc<ZipperLinks>,
    /// Dense positions are multiplied by `unit` (exactly: a power of two, 1
    /// but for a mesh of extreme size, see [`crate::mesh::extreme_scale`]).
    pub(super) unit: f32,
    pub(super) face_angle: Arc<Vec<f64>>,
    /// Per tile, its dense vertices and the lowest id among them.
    covered: Arc<Vec<u32>>,
    first_covered: Arc<Vec<u32>>,
}

impl Surface {
    /// The surface of the geometry image at `path`, its tiles held within
    /// `budget`.
    pub(super) fn open(gim: &Gim, budget: MemoryBudget) -> Result<Surface> {
        let r = gim.resolution;
        let points: Vec<[f32; 3]> = gim.mesh()?.positions;
        let unit = crate::mesh::extreme_scale(&points) as f32;
        // a reader of its own: its chunk cache is the pager's business
        let own = Gim::open(gim.container().path(), MemoryBudget(0))?;
        let grid = TileGrid::new(r);
        // (every tile's indices are checked here, before the loop starts)
        let (mut covered, mut first_covered) = (vec![0; grid.tiles()], vec![u32::MAX; grid.tiles()]);
        for k in 0..grid.tiles() {
            let (x0, y0, w, h) = grid.region(k);
            let (c, _) = gim.chart_face_region(x0, y0, w, h)?;
            for (j, &ch) in c.iter().enumerate() {
                if ch != EMPTY {
                    covered[k] += 1;
                    first_covered[k] = first_covered[k].min(((y0 + j / w) * r + x0 + j % w) as u32);
                }
            }
        }
        let source = GimTiles { gim: own, grid, unit };
        Ok(Surface {
            covered: Arc::new(covered),
            first_covered: Arc::new(first_covered),
            r,
            tiles: Pager::new(r, source, budget.bytes(), SURFACE_TILE_BYTES as u64, MIN_TILES),
            zippers: Arc::new(ZipperLinks::new(&gim.zipper_links()?)),
            unit,
            face_angle: Arc::new(face_angles(gim)?),
        })
    }

    /// The surface of `tiles` only, for a work patch computed on another
    /// thread ([`Pager::view`]).
    pub(super) fn view(&self, tiles: &[usize]) -> Surface {
        Surface {
            r: self.r,
            tiles: self.tiles.view(tiles),
            zippers: Arc::clone(&self.zippers),
            unit: self.unit,
            face_angle: Arc::clone(&self.face_angle),
            covered: Arc::clone(&self.covered),
            first_covered: Arc::clone(&self.first_covered),
        }
    }

    /// Whether a view was read outside its tiles.
    pub(super) fn missed(&self) -> bool {
        self.tiles.missed()
    }

    pub(super) fn grid(&self) -> TileGrid {
        self.tiles.grid
    }

    /// Number of dense vertices.
    pub(super) fn vertices(&self) -> usize {
        self.covered.iter().map(|&c| c as usize).sum()
    }

    /// The `n`-th dense vertex in texel order (row-major), `n` < [`Surface::vertices`].
    pub(super) fn nth_vertex(&self, mut n: usize) -> u32 {
        let grid = self.grid();
        for ty in 0..grid.across {
            let row: usize = (0..grid.across)
                .map(|tx| self.covered[ty * grid.across + tx] as usize)
                .sum();
            if n >= row {
                n -= row;
                continue;
            }
            let (y0, y1) = (ty * TILE, ((ty + 1) * TILE).min(self.r));
            for y in y0..y1 {
                for x in 0..self.r {
                    let t = (y * self.r + x) as u32;
                    if self.covered(t) {
                        if n == 0 {
                            return t;
                        }
                        n -= 1;
                    }
                }
            }
        }
        // (only if a tile failed to load, whose error ends the loop)
        0
    }

    /// The chart plane of tile `k` (64×64, padding [`EMPTY`]).
    pub(super) fn chart_tile(&self, k: usize) -> Vec<u32> {
        self.tiles.read_tile(k, |s| s.chart.clone())
    }

    #[inline]
    pub(super) fn chart(&self, t: u32) -> u32 {
        self.tiles.read(t, |s, i| s.chart[i])
    }

    pub(super) fn covered(&self, t: u32) -> bool {
        self.chart(t) != EMPTY
    }

    /// Position of dense vertex `t`, multiplied by `unit`.
    pub(super) fn position(&self, t: u32) -> [f32; 3] {
        self.tiles.read(t, |s, i| s.position[i])
    }

    pub(super) fn normal(&self, t: u32) -> [f32; 3] {
        self.tiles.read(t, |s, i| s.normal[i])
    }

    pub(super) fn texel_angle(&self, t: u32) -> f64 {
        let face = self.tiles.read(t, |s, i| s.face[i]) as usize;
        // (a tile that failed to load is blank; its error ends the loop)
        self.face_angle.get(face).copied().unwrap_or(0.0)
    }

    /// Calls `f` for every neighbour of texel `t` in M_d (grid neighbours of
    /// its chart, then zipper partners); `f`'s second argument says whether
    /// the edge is a zipper link.
    pub(super) fn for_each_neighbour(&self, t: u32, mut f: impl FnMut(u32, bool)) {
        let r = self.r;
        let (x, y) = self.tiles.grid.xy(t);
        let (lx, ly) = (x % TILE, y % TILE);
        // the chart of t and of its 4 grid neighbours (NONE off the atlas),
        // from one tile when they all lie in it
        const NONE: u32 = EMPTY - 1;
        let charts: [u32; 5] = if lx > 0 && lx + 1 < TILE && ly > 0 && ly + 1 < TILE && x + 1 < r && y + 1 < r
        {
            self.tiles.read(t, |s, i| {
                [
                    s.chart[i],
                    s.chart[i - 1],
                    s.chart[i + 1],
                    s.chart[i - TILE],
                    s.chart[i + TILE],
                ]
            })
        } else {
            let at = |ok: bool, n: u32| if ok { self.chart(n) } else { NONE };
            [
                self.chart(t),
                at(x > 0, t.wrapping_sub(1)),
                at(x + 1 < r, t + 1),
                at(y > 0, t.wrapping_sub(r as u32)),
                at(y + 1 < r, t + r as u32),
            ]
        };
        let c = charts[0];
        if c == EMPTY {
            return;
        }
        let ids = [t.wrapping_sub(1), t + 1, t.wrapping_sub(r as u32), t + r as u32];
        for (k, &n) in ids.iter().enumerate() {
            if charts[k + 1] == c {
                f(n, false);
            }
        }
        self.zippers.for_each(t, |n| f(n, true));
    }

    /// The first error paging met.
    pub(super) fn take_error(&mut self) -> Result<()> {
        self.tiles.take_error()
    }

    /// How many tiles were read in so far.
    pub(super) fn tiles_read(&self) -> u64 {
        self.tiles.faults()
    }
}

/// Per face, the atlas-space angle of its field direction (radians, y down).
pub(super) fn face_angles(gim: &Gim) -> Result<Vec<f64>> {
    let mut mesh = gim.mesh()?;
    // angles do not depend on the scale; f32 products of extreme ones would overflow
    mesh.normalize_extreme_scale();
    let uv = gim.corner_uv()?;
    let field: Vec<f32> = gim.read("face_field")?;
    Ok((0..mesh.triangles.len())
        .map(|f| {
            let v = [
                field[f * 3] as f64,
                field[f * 3 + 1] as f64,
                field[f * 3 + 2] as f64,
            ];
            crate::artifact::gim::atlas_direction(&mesh, &uv, f, v).map_or(0.0, |d| d[1].atan2(d[0]))
        })
        .collect())
}

/// A work patch: its vertices (texels) and their BFS depth.
pub(crate) struct WorkPatch {
    pub(crate) texels: Vec<u32>,
    pub(crate) depth: Vec<u16>,
    /// Whether the traversal crossed a zipper (the patch spans charts).
    pub(super) crosses_charts: bool,
    /// Where in `texels` the first texel reached across a zipper is
    /// (`texels.len()` if none): the patches of smaller radius at the same
    /// seed are prefixes of this traversal ([`Bfs::prefix`]).
    pub(super) first_zipper: usize,
}

impl WorkPatch {
    /// The patch's bounding box in an `r`×`r` atlas: `(x0, y0, width,
    /// height)`.
    pub(super) fn atlas_box(&self, r: usize) -> (usize, usize, usize, usize) {
        let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
        for &t in &self.texels {
            let (x, y) = (t as usize % r, t as usize / r);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        (x0, y0, x1 - x0 + 1, y1 - y0 + 1)
    }
}

/// A multiplicative hash for texel ids (the map's keys are small integers).
#[derive(Default)]
pub(super) struct TexelHasher(u64);

impl Hasher for TexelHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ b as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.0 = (v as u64 ^ 0x5555_5555).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// The last work patch's vertices by texel (sized by the patch, not the
/// atlas): a dense window of the atlas around the seed (a patch of radius
/// r lies within r texels of it inside its chart), a map for the texels
/// of other charts beyond it.
#[derive(Default)]
pub(super) struct Bfs {
    /// Local index per texel of the window (`u32::MAX`: not in the patch).
    window: Vec<u32>,
    /// The window's first column and row and its side.
    x0: i64,
    y0: i64,
    side: usize,
    grid: Option<TileGrid>,
    /// Window slots set by the last patch, to clear.
    set: Vec<u32>,
    index: HashMap<u32, u32, BuildHasherDefault<TexelHasher>>,
}

impl Bfs {
    /// Empties the index and centres its window of `radius` on `v`.
    fn window_around(&mut self, surface: &Surface, v: u32, radius: usize) {
        for &slot in &self.set {
            self.window[slot as usize] = u32::MAX;
        }
        self.set.clear();
        self.index.clear();
        let grid = surface.grid();
        let (x, y) = grid.xy(v);
        self.side = 2 * radius + 1;
        self.x0 = x as i64 - radius as i64;
        self.y0 = y as i64 - radius as i64;
        self.grid = Some(grid);
        if self.window.len() < self.side * self.side {
            self.window = vec![u32::MAX; self.side * self.side];
        }
    }

    /// The work patch of `radius` at `v`: a breadth-first traversal of the
    /// dense mesh, indexed for [`Bfs::contains`].
    pub(super) fn patch(&mut self, surface: &Surface, v: u32, radius: usize) -> WorkPatch {
        self.patch_unless(surface, v, radius, |_| false)
            .expect("never stopped")
    }

    /// [`Bfs::patch`], given up (`None`) at the first texel reached for
    /// which `stop` holds.
    pub(super) fn patch_unless(
        &mut self,
        surface: &Surface,
        v: u32,
        radius: usize,
        stop: impl Fn(u32) -> bool,
    ) -> Option<WorkPatch> {
        self.window_around(surface, v, radius);
        if stop(v) {
            return None;
        }
        let mut texels = vec![v];
        let mut depth = vec![0u16];
        self.insert(v, 0);
        let mut first_zipper = usize::MAX;
        let mut head = 0;
        let mut stopped = false;
        while head < texels.len() && !stopped {
            let (t, d) = (texels[head], depth[head]);
            head += 1;
            if d as usize >= radius {
                continue;
            }
            surface.for_each_neighbour(t, |n, zipper| {
                if self.contains(n).is_none() {
                    if zipper && first_zipper == usize::MAX {
                        first_zipper = texels.len();
                    }
                    self.insert(n, texels.len() as u32);
                    texels.push(n);
                    depth.push(d + 1);
                    stopped |= stop(n);
                }
            });
        }
        (!stopped).then(|| WorkPatch {
            crosses_charts: first_zipper != usize::MAX,
            first_zipper: first_zipper.min(texels.len()),
            texels,
            depth,
        })
    }

    /// [`Bfs::patch`] of `radius` at the seed of `ball`, a traversal of at
    /// least that radius from it, without traversing again: a breadth-first
    /// traversal lists its texels by depth, and those within `radius` come
    /// in the same order as a traversal stopped there.
    pub(super) fn prefix(&mut self, surface: &Surface, ball: &WorkPatch, radius: usize) -> WorkPatch {
        let v = ball.texels[0];
        self.window_around(surface, v, radius);
        let len = ball.depth.partition_point(|&d| d as usize <= radius);
        for (i, &t) in ball.texels[..len].iter().enumerate() {
            self.insert(t, i as u32);
        }
        WorkPatch {
            texels: ball.texels[..len].to_vec(),
            depth: ball.depth[..len].to_vec(),
            crosses_charts: ball.first_zipper < len,
            first_zipper: ball.first_zipper.min(len),
        }
    }

    /// The window slot of texel `t`, if it lies in the window.
    #[inline]
    fn slot(&self, t: u32) -> Option<usize> {
        let (x, y) = self.grid?.xy(t);
        let (dx, dy) = (x as i64 - self.x0, y as i64 - self.y0);
        let side = self.side as i64;
        (dx >= 0 && dy >= 0 && dx < side && dy < side).then(|| (dy * side + dx) as usize)
    }

    fn insert(&mut self, t: u32, i: u32) {
        match self.slot(t) {
            Some(slot) => {
                self.window[slot] = i;
                self.set.push(slot as u32);
            }
            None => {
                self.index.insert(t, i);
            }
        }
    }

    /// The local index of texel `t` in the last patch.
    #[inline]
    pub(super) fn contains(&self, t: u32) -> Option<usize> {
        match self.slot(t) {
            Some(slot) => Some(self.window[slot])
                .filter(|&i| i != u32::MAX)
                .map(|i| i as usize),
            None => self.index.get(&t).map(|&i| i as usize),
        }
    }
}
