//! The surface: the per-texel data of the geometry image (chart, face,
//! position, normal) paged in tiles, and its dense graph with zipper links.

use super::*;
use crate::math;

/// The per-texel surface of one tile, from the `.gim`.
#[derive(Clone)]
pub(in crate::quilt) struct SurfaceTile {
    pub(in crate::quilt) chart: Vec<u32>,
    pub(in crate::quilt) face: Vec<u32>,
    /// Positions multiplied by the surface's `unit`.
    pub(in crate::quilt) position: Vec<[f32; 3]>,
    pub(in crate::quilt) normal: Vec<[f32; 3]>,
    /// The course phase of the stripe pattern per texel (radians), with
    /// locked courses: computed the first time a texel of the tile asks
    /// for it ([`Surface::course_phase`]), so a stroke that loads the whole
    /// surface computes it only around its region.
    pub(in crate::quilt) phase: std::sync::OnceLock<Vec<f32>>,
}

/// Bytes of a surface tile, and what its course phase adds.
const SURFACE_TILE_BYTES: usize = TILE_TEXELS * (4 + 4 + 12 + 12);
const PHASE_TILE_BYTES: usize = TILE_TEXELS * 4;

/// Locked courses (`--courses locked`): the stripe pattern whose phase the
/// surface tiles carry, its period and orientation.
pub(in crate::quilt) struct CourseLock {
    pub(in crate::quilt) pattern: StripePattern,
    /// The course period in texels (the resampled sample's).
    pub(in crate::quilt) period: f64,
}

/// Surface tiles read from the geometry image (never written back).
pub(in crate::quilt) struct GimTiles {
    gim: Gim,
    grid: TileGrid,
    pub(super) unit: f32,
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
            phase: std::sync::OnceLock::new(),
        }
    }
}

/// Everything the loop reads of the dense mesh M_d: per texel (paged) the
/// chart, face, position and normal; the zipper links; the field angle per
/// face.
pub(in crate::quilt) struct Surface {
    pub(in crate::quilt) r: usize,
    pub(super) tiles: Pager<SurfaceTile, GimTiles>,
    zippers: Arc<ZipperLinks>,
    /// Dense positions are multiplied by `unit` (exactly: a power of two, 1
    /// but for a mesh of extreme size, see [`crate::mesh::extreme_scale`]).
    pub(in crate::quilt) unit: f32,
    pub(in crate::quilt) face_angle: Arc<Vec<f64>>,
    /// Per tile, its dense vertices and the lowest id among them.
    pub(super) covered: Arc<Vec<u32>>,
    pub(super) first_covered: Arc<Vec<u32>>,
    /// Locked courses: the pattern (whose phase the tiles carry) and the
    /// course period.
    pub(in crate::quilt) lock: Option<Arc<CourseLock>>,
}

impl Surface {
    /// The surface of the geometry image at `path`, its tiles held within
    /// `budget`.
    /// With `lock`, each tile also carries the stripe pattern's course
    /// phase.
    pub(in crate::quilt) fn open(
        gim: &Gim,
        budget: MemoryBudget,
        lock: Option<CourseLock>,
    ) -> Result<Surface> {
        let lock = lock.map(Arc::new);
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
        let tile_bytes = SURFACE_TILE_BYTES + if lock.is_some() { PHASE_TILE_BYTES } else { 0 };
        Ok(Surface {
            covered: Arc::new(covered),
            first_covered: Arc::new(first_covered),
            r,
            tiles: Pager::new(r, source, budget.bytes(), tile_bytes as u64, MIN_TILES),
            zippers: Arc::new(ZipperLinks::new(&gim.zipper_links()?)),
            unit,
            face_angle: Arc::new(face_angles(gim)?),
            lock,
        })
    }

    /// The surface of `tiles` only, for a work patch computed on another
    /// thread ([`Pager::view`]).
    pub(in crate::quilt) fn view(&self, tiles: &[usize]) -> Surface {
        Surface {
            r: self.r,
            tiles: self.tiles.view(tiles),
            zippers: Arc::clone(&self.zippers),
            unit: self.unit,
            face_angle: Arc::clone(&self.face_angle),
            covered: Arc::clone(&self.covered),
            first_covered: Arc::clone(&self.first_covered),
            lock: self.lock.clone(),
        }
    }

    /// Whether a view was read outside its tiles.
    pub(in crate::quilt) fn missed(&self) -> bool {
        self.tiles.missed()
    }

    pub(in crate::quilt) fn grid(&self) -> TileGrid {
        self.tiles.grid
    }

    /// Number of dense vertices.
    pub(in crate::quilt) fn vertices(&self) -> usize {
        self.covered.iter().map(|&c| c as usize).sum()
    }

    /// The `n`-th dense vertex in texel order (row-major), `n` < [`Surface::vertices`].
    pub(in crate::quilt) fn nth_vertex(&self, mut n: usize) -> u32 {
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
    pub(in crate::quilt) fn chart_tile(&self, k: usize) -> Vec<u32> {
        self.tiles.read_tile(k, |s| s.chart.clone())
    }

    #[inline]
    pub(in crate::quilt) fn chart(&self, t: u32) -> u32 {
        self.tiles.read(t, |s, i| s.chart[i])
    }

    pub(in crate::quilt) fn covered(&self, t: u32) -> bool {
        self.chart(t) != EMPTY
    }

    /// Position of dense vertex `t`, multiplied by `unit`.
    pub(in crate::quilt) fn position(&self, t: u32) -> [f32; 3] {
        self.tiles.read(t, |s, i| s.position[i])
    }

    pub(in crate::quilt) fn normal(&self, t: u32) -> [f32; 3] {
        self.tiles.read(t, |s, i| s.normal[i])
    }

    /// The stripe pattern's course phase at texel `t` (radians), with
    /// locked courses.
    pub(in crate::quilt) fn course_phase(&self, t: u32) -> f64 {
        let Some(lock) = &self.lock else {
            return 0.0;
        };
        let unit = self.unit;
        self.tiles.read(t, |s, i| {
            s.phase.get_or_init(|| {
                // the pattern's phase at each covered texel's own position
                // (the tile holds it times `unit`, a power of two: exact)
                (0..TILE_TEXELS)
                    .map(|j| match s.chart[j] {
                        EMPTY => 0.0,
                        _ => lock
                            .pattern
                            .phase(s.face[j] as usize, s.position[j].map(|c| f64::from(c / unit)))
                            as f32,
                    })
                    .collect()
            })[i]
        }) as f64
    }

    pub(in crate::quilt) fn texel_angle(&self, t: u32) -> f64 {
        let face = self.tiles.read(t, |s, i| s.face[i]) as usize;
        // (a tile that failed to load is blank; its error ends the loop)
        self.face_angle.get(face).copied().unwrap_or(0.0)
    }

    /// Calls `f` for every neighbour of texel `t` in M_d (grid neighbours of
    /// its chart, then zipper partners); `f`'s second argument says whether
    /// the edge is a zipper link.
    pub(in crate::quilt) fn for_each_neighbour(&self, t: u32, mut f: impl FnMut(u32, bool)) {
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
    pub(in crate::quilt) fn take_error(&mut self) -> Result<()> {
        self.tiles.take_error()
    }

    /// How many tiles were read in so far.
    pub(in crate::quilt) fn tiles_read(&self) -> u64 {
        self.tiles.faults()
    }
}

/// Per face, the atlas-space angle of its field direction (radians, y down).
pub(in crate::quilt) fn face_angles(gim: &Gim) -> Result<Vec<f64>> {
    let mut mesh = gim.mesh()?;
    // angles do not depend on the scale; f32 products of extreme ones would overflow
    mesh.normalize_extreme_scale();
    let uv = gim.corner_uv()?;
    let field = gim.face_field()?;
    Ok((0..mesh.triangles.len())
        .map(|f| {
            let v = field[f].map(f64::from);
            crate::artifact::gim::atlas_direction(&mesh, &uv, f, v).map_or(0.0, |d| math::atan2(d[1], d[0]))
        })
        .collect())
}
