//! `tile`: graphcut quilting on the dense mesh (Zhou et al., section III-B;
//! Kwatra et al. 2003), for colour samples and BTFs alike (both enter as a
//! `.svd`: patch costs use the n-term geometry-map vectors).
//!
//! The loop (the paper's Fig. 4):
//! 1. pick the most constrained unsynthesized dense vertex v (most
//!    synthesized neighbours; the first one from the seed);
//! 2. work patch P(v): breadth-first traversal of M_d from v to depth r_w;
//! 3. work image I(v): inside one chart, the chart's sub-image (no
//!    resampling); across charts, P(v) flattened — the charts' own LSCM
//!    layouts aligned over the zipper links and their seams closed by a
//!    membrane (area distortion ≤ T_d, else the rigid field-based
//!    unfolding) — and resampled at one texel per pixel, a pixel known where
//!    its triangle's three vertices are synthesized;
//! 4. entire-patch matching of the sample rotated to the work image's mean
//!    field direction (one of the 72 rotated copies) by FFT; a seeded choice
//!    among near-minimal placements;
//! 5. patch fitting: a graphcut over P(v)'s vertices between the old values A
//!    and the new B, edge weight ‖A(s)−B(s)‖ + ‖A(t)−B(t)‖, with a seam node on
//!    every old seam so later patches can remove earlier seams;
//! 6. accept if the mean seam cost is below T_c (relative to the sample's own
//!    neighbour differences), else shrink r_w by 0.8 and retry, down to 4;
//! 7. record for each vertex taken: sample coordinate, rotation, patch id.
//!
//! State is struct-of-arrays over atlas texels. The loop is sequential, so the
//! result depends only on the inputs and the seed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::container::{ArraySpec, Container, ContainerWriter, DType, MemoryBudget, Param};
use crate::factorize::{self, FactorizeConfig, SvdArtifact};
use crate::gim::{Gim, EMPTY, TILE};
use crate::matching::{self, Image, MatchConfig, Matcher};
use crate::maxflow::{Graph, Segment};
use crate::progress::Progress;
use crate::{Error, Result};

/// The artifact kind of a decorated surface.
pub const KIND: &str = "quilt";
/// Patch id of an unsynthesized texel.
pub const NO_PATCH: u32 = u32::MAX;

/// Options of [`tile`].
#[derive(Clone, Debug)]
pub struct TileConfig {
    /// Work-patch radius r_w in BFS hops; `None` = 32 per 512 texels of
    /// atlas, at most a quarter of the sample's smaller side.
    pub patch_radius: Option<usize>,
    /// Smallest radius of the hierarchical search.
    pub min_radius: usize,
    /// Accept a fitting if its mean seam cost ≤ this × the sample's mean
    /// neighbour difference (T_c). A seam edge's cost sums two differences
    /// (‖A(s)−B(s)‖ + ‖A(t)−B(t)‖), so 2 is a seam as strong as the
    /// sample's own edges; 3 (the default) keeps patches large, which on
    /// Spot gave fewer broken structures than 2, whose many small patches
    /// multiply the seams (and is 5–7× faster).
    pub seam_threshold: f64,
    /// Near-minimal placements: cost ≤ (1 + tolerance) × best.
    pub tolerance: f64,
    /// Maximum area distortion of a flattened work patch (T_d).
    pub max_distortion: f64,
    pub seed: u64,
    pub memory: MemoryBudget,
    pub level: i32,
    /// The sample's foreground mask m_P (a PNG the sample's size): with it,
    /// tiling keeps the foreground out (m0 = 0 everywhere, §IV).
    pub sample_mask: Option<PathBuf>,
    /// Weight of the constraint: the data term |m_σ(p) − m0(p)| costs this
    /// many sample neighbour differences per texel in the graphcut, and the
    /// matching adds (this × neighbour difference)² · |m0 − m_P|². It must
    /// outweigh the feature difference between the old background and the
    /// foreground that replaces it (on a flat square with a brick sample,
    /// 2 filled 17 % of F, 4 filled 62 %, 8 filled 79 %, 16 at least 95 %).
    pub constraint_weight: f64,
    /// Seam refinement after the surface is covered ([`Synthesis::refine`]):
    /// seams whose step exceeds this × the sample's neighbour difference
    /// get one more work patch of radius r_w each; `None` turns it off. The
    /// default 2: on Spot at 1024² with the 192² brick crop it took the seam
    /// ratio from 0.91 to 0.80 (50 refinements kept) in 3 s more.
    pub refine: Option<f64>,
    /// Seam refinement fits this many distinct good placements per seam
    /// (graphcut each, the cheapest cut kept). Default 1, the cheapest
    /// match: on Spot at 1024² with the brick wall, back to back, seam ratio
    /// 0.684 (1 placement), 0.667 (2), 0.658 (4); each extra placement costs
    /// a graphcut per refined seam (there 2-3 s more per placement).
    pub refine_placements: usize,
}

impl Default for TileConfig {
    fn default() -> Self {
        TileConfig {
            patch_radius: None,
            min_radius: 4,
            seam_threshold: 3.0,
            tolerance: 0.1,
            max_distortion: 4.0,
            seed: 1,
            memory: MemoryBudget::default(),
            level: crate::container::DEFAULT_ZSTD_LEVEL,
            sample_mask: None,
            constraint_weight: 16.0,
            refine: Some(2.0),
            refine_placements: REFINE_PLACEMENTS,
        }
    }
}

impl TileConfig {
    /// Checks the numbers a user gives (each must be finite and in range),
    /// naming the command-line flag and the value.
    pub fn validate(&self) -> Result<()> {
        let check = |flag: &str, v: f64, ok: bool, want: &str| {
            if v.is_finite() && ok {
                Ok(())
            } else {
                Err(Error::Config(format!("{flag} {v}: must be {want}")))
            }
        };
        check(
            "--seam-threshold",
            self.seam_threshold,
            self.seam_threshold > 0.0,
            "a finite number > 0 (a mean seam cost in sample neighbour differences)",
        )?;
        check(
            "--constraint-weight",
            self.constraint_weight,
            self.constraint_weight >= 0.0,
            "a finite number ≥ 0 (sample neighbour differences per texel)",
        )?;
        if let Some(r) = self.refine {
            check(
                "--refine",
                r,
                r > 0.0,
                "a finite number > 0 (a seam step in sample neighbour differences), or 0 for none",
            )?;
        }
        if self.refine_placements == 0 {
            return Err(Error::Config("--refine-placements must be at least 1".into()));
        }
        Ok(())
    }
}

/// What [`tile`] did.
#[derive(Clone, Debug, Default)]
pub struct TileReport {
    pub patches: usize,
    pub cross_chart_patches: usize,
    /// Accepted cross-chart patches whose work image is the rigid unfolding
    /// (the flattening exceeded T_d).
    pub unfolded_patches: usize,
    pub shrinks: usize,
    /// Seam refinements kept ([`TileConfig::refine`]).
    pub refined: usize,
    pub texels: usize,
    pub mean_seam_cost: f64,
    pub seconds: f64,
    pub matching_seconds: f64,
    pub graphcut_seconds: f64,
}

impl std::fmt::Display for TileReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} texels in {} patches ({} across charts, {} of them unfolded, {} shrinks, {} seams refined), mean seam cost {:.4}, {:.1} s (matching {:.1} s, graphcut {:.1} s)",
            self.texels,
            self.patches,
            self.cross_chart_patches,
            self.unfolded_patches,
            self.shrinks,
            self.refined,
            self.mean_seam_cost,
            self.seconds,
            self.matching_seconds,
            self.graphcut_seconds
        )
    }
}

/// The sample: unrotated geometry maps, and rotated copies on demand.
struct Sample {
    svd: SvdArtifact,
    width: usize,
    height: usize,
    n: usize,
    maps: Vec<f32>,
    tileable: bool,
    /// Rotated copies as f32 (maps, validity), loaded lazily and dropped
    /// least recently used first beyond `rotated_budget` bytes.
    rotated: Vec<Option<(Vec<f32>, Vec<f32>)>>,
    /// When each rotated copy was last asked for.
    rotated_used: Vec<u64>,
    rotated_clock: u64,
    rotated_budget: usize,
    /// The foreground mask m_P (`[y][x]`, 0..1), if painting or keeping the
    /// foreground out.
    mask: Option<Vec<f32>>,
    /// Rotated copies of the mask, made lazily like the maps'.
    rotated_mask: Vec<Option<Vec<f32>>>,
}

impl Sample {
    /// Reads the unrotated geometry maps; rotated copies and the mask come
    /// later, on demand.
    fn from_svd(svd: SvdArtifact) -> Result<Sample> {
        let tileable = svd.tileable();
        let rotations = if svd.rotations > 0 {
            svd.rotations
        } else {
            factorize::DEFAULT_ROTATIONS
        };
        Ok(Sample {
            width: svd.width,
            height: svd.height,
            n: svd.terms,
            maps: svd.geometry_maps()?,
            tileable,
            rotated: vec![None; rotations],
            rotated_used: vec![0; rotations],
            rotated_clock: 0,
            rotated_budget: usize::MAX,
            mask: None,
            rotated_mask: vec![None; rotations],
            svd,
        })
    }

    fn rotation(&mut self, r: usize) -> Result<&(Vec<f32>, Vec<f32>)> {
        self.rotated_clock += 1;
        self.rotated_used[r] = self.rotated_clock;
        if self.rotated[r].is_none() {
            // room first: drop the least recently used copies (never the
            // one asked for; at least one copy always stays)
            let copy_bytes = self.width * self.height * (self.n + 1) * 4;
            let mut held = self.rotated.iter().flatten().count() * copy_bytes;
            while held + copy_bytes > self.rotated_budget && held > 0 {
                let oldest = (0..self.rotated.len())
                    .filter(|&k| self.rotated[k].is_some())
                    .min_by_key(|&k| self.rotated_used[k])
                    .expect("held > 0");
                self.rotated[oldest] = None;
                held -= copy_bytes;
            }
            let (maps, valid) = self.svd.rotated(r)?;
            let mut m = vec![0f32; maps.len()];
            half::slice::HalfFloatSliceExt::convert_to_f32_slice(&maps[..], &mut m);
            self.rotated[r] = Some((m, valid.iter().map(|&v| v as f32).collect()));
        }
        Ok(self.rotated[r].as_ref().expect("just loaded"))
    }

    /// Rotated copy `r` of the foreground mask (turned like the maps).
    fn rotation_mask(&mut self, r: usize) -> Option<&[f32]> {
        let mask = self.mask.as_ref()?;
        if self.rotated_mask[r].is_none() {
            let degrees = r as f64 * 360.0 / self.rotated.len() as f64;
            let (m, _) = factorize::rotate_maps(mask, self.width, self.height, 1, degrees, self.tileable);
            self.rotated_mask[r] = Some(m);
        }
        self.rotated_mask[r].as_deref()
    }

    /// Bilinear foreground mask at unrotated sample coordinates (0 where
    /// there is no mask or outside the sample).
    fn mask_at(&self, c: [f64; 2]) -> f32 {
        let Some(mask) = &self.mask else { return 0.0 };
        crate::imageio::mask_bilinear(mask, self.width, self.height, c, self.tileable)
    }

    /// Bilinear geometry-map vector at unrotated sample coordinates (pixel
    /// indices); `None` outside the sample (unless tileable).
    fn lookup(&self, c: [f64; 2], out: &mut [f32]) -> bool {
        let (w, h) = (self.width as f64, self.height as f64);
        let (mut x, mut y) = (c[0], c[1]);
        if self.tileable {
            x = x.rem_euclid(w);
            y = y.rem_euclid(h);
        } else if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
            return false;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let wrap = |v: usize, n: usize| if self.tileable { v % n } else { v.min(n - 1) };
        let (x0, y0) = (wrap(x0, self.width), wrap(y0, self.height));
        let (x1, y1) = (wrap(x0 + 1, self.width), wrap(y0 + 1, self.height));
        let n = self.n;
        let at = |x: usize, y: usize| (y * self.width + x) * n;
        let (a, b, cc, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        for i in 0..n {
            let top = self.maps[a + i] + (self.maps[b + i] - self.maps[a + i]) * fx;
            let bottom = self.maps[cc + i] + (self.maps[d + i] - self.maps[cc + i]) * fx;
            out[i] = top + (bottom - top) * fy;
        }
        true
    }

    /// Mean ‖g(x) − g(x + 1)‖ over horizontal and vertical neighbours: the
    /// sample's own seam scale, the unit of T_c.
    fn neighbour_difference(&self) -> f64 {
        let (w, h, n) = (self.width, self.height, self.n);
        let (mut s, mut c) = (0f64, 0usize);
        for y in 0..h {
            for x in 0..w {
                let a = (y * w + x) * n;
                for (dx, dy) in [(1, 0), (0, 1)] {
                    if x + dx < w && y + dy < h {
                        let b = ((y + dy) * w + x + dx) * n;
                        s += dist(&self.maps[a..a + n], &self.maps[b..b + n]);
                        c += 1;
                    }
                }
            }
        }
        (s / c.max(1) as f64).max(1e-12)
    }
}

/// Whether two paths name the same file (textually equal when either is
/// missing).
pub(crate) fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// C = P_aᵀ P_k (`n_a × n_k`, row-major) for appearance functions stored
/// `[pair][rgb][i]` over the same direction pairs: it takes sample k's
/// geometry-map vectors into sample a's basis.
fn basis_projection(pa: &[f32], na: usize, pk: &[f32], nk: usize) -> Vec<f32> {
    let rows = pa.len() / na.max(1);
    let mut c = vec![0f64; na * nk];
    for row in 0..rows {
        let (ra, rk) = (&pa[row * na..(row + 1) * na], &pk[row * nk..(row + 1) * nk]);
        for (a, &x) in ra.iter().enumerate() {
            for (k, &y) in rk.iter().enumerate() {
                c[a * nk + k] += x as f64 * y as f64;
            }
        }
    }
    c.into_iter().map(|v| v as f32).collect()
}

fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// No foreign feature vector (a texel of the active sample).
const NO_FOREIGN: u32 = u32::MAX;

/// Per-texel synthesis state (struct of arrays over the atlas).
struct State {
    r: usize,
    n: usize,
    chart: Vec<u32>,
    synthesized: Vec<bool>,
    coord: Vec<[f32; 2]>,
    /// Sample-space offset per +x and per +y atlas step (columns of the local
    /// Jacobian), to continue an old patch one texel into its neighbour.
    jacobian: Vec<[f32; 4]>,
    rotation: Vec<u8>,
    patch: Vec<u32>,
    /// Index of the sample each texel draws from ([`Quilt::samples`]).
    source: Vec<u8>,
    /// The sample new patches come from.
    active: u8,
    /// Texels of other samples than the active one (painting with a new
    /// sample): index into `foreign_features` (`NO_FOREIGN` for texels of
    /// the active sample, whose geometry-map vectors are looked up in it
    /// at their coordinate when needed, not stored).
    foreign: Vec<u32>,
    /// Their geometry-map vectors projected into the active sample's basis
    /// (see [`Synthesis::load`]), `n` per entry.
    foreign_features: Vec<f32>,
    /// m_σ(p): the sample's foreground mask at each texel's coordinate
    /// (when the sample has a mask).
    mask: Vec<f32>,
    /// m0(p): the constraint function (1 on the painted region F, falling
    /// to 0 over the transition zone, 0 elsewhere), when constrained.
    target: Option<Vec<f32>>,
    /// The id the next accepted patch gets.
    next_patch: u32,
    /// Synthesized-neighbour counts of unsynthesized texels (the
    /// "most constrained" priority), bucketed.
    count: Vec<u8>,
    buckets: Vec<std::collections::BTreeSet<u32>>,
    remaining: usize,
}

impl State {
    fn new(chart: Vec<u32>, n: usize, r: usize) -> State {
        let texels = chart.len();
        let mut buckets = vec![std::collections::BTreeSet::new(); 16];
        let mut remaining = 0;
        for (t, &c) in chart.iter().enumerate() {
            if c != EMPTY {
                buckets[0].insert(t as u32);
                remaining += 1;
            }
        }
        State {
            r,
            n,
            synthesized: vec![false; texels],
            coord: vec![[0.0; 2]; texels],
            jacobian: vec![[0.0; 4]; texels],
            rotation: vec![0; texels],
            patch: vec![NO_PATCH; texels],
            source: vec![0; texels],
            active: 0,
            foreign: vec![NO_FOREIGN; texels],
            foreign_features: Vec::new(),
            mask: vec![0.0; texels],
            target: None,
            next_patch: 0,
            count: vec![0; texels],
            buckets,
            remaining,
            chart,
        }
    }

    /// The most constrained unsynthesized texel (lowest id among equals).
    fn most_constrained(&self) -> Option<u32> {
        self.buckets.iter().rev().find_map(|b| b.first().copied())
    }

    /// The geometry-map vector of synthesized texel `t` in the active
    /// sample's basis, into `out` (`n` values).
    fn feature_into(&self, sample: &Sample, t: u32, out: &mut [f32]) {
        let f = self.foreign[t as usize];
        if f != NO_FOREIGN {
            let f = f as usize * self.n;
            out.copy_from_slice(&self.foreign_features[f..f + self.n]);
            return;
        }
        let c = self.coord[t as usize];
        if !sample.lookup([c[0] as f64, c[1] as f64], out) {
            out.fill(0.0);
        }
    }
}

/// A work patch: its vertices (texels) and their BFS depth.
pub(crate) struct WorkPatch {
    pub(crate) texels: Vec<u32>,
    pub(crate) depth: Vec<u16>,
    /// Whether the traversal crossed a zipper (the patch spans charts).
    crosses_charts: bool,
}

impl WorkPatch {
    /// The patch's bounding box in an `r`×`r` atlas: `(x0, y0, width,
    /// height)`.
    fn atlas_box(&self, r: usize) -> (usize, usize, usize, usize) {
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

/// Reusable BFS buffers.
struct Bfs {
    stamp: Vec<u32>,
    index: Vec<u32>,
    epoch: u32,
}

impl Bfs {
    fn patch(&mut self, graph: &crate::gim::DenseGraph, v: u32, radius: usize) -> WorkPatch {
        self.epoch += 1;
        let mut texels = vec![v];
        let mut depth = vec![0u16];
        self.stamp[v as usize] = self.epoch;
        self.index[v as usize] = 0;
        let mut crosses = false;
        let mut head = 0;
        while head < texels.len() {
            let (t, d) = (texels[head], depth[head]);
            head += 1;
            if d as usize >= radius {
                continue;
            }
            graph.for_each_neighbour(t, |n, zipper| {
                if self.stamp[n as usize] != self.epoch {
                    self.stamp[n as usize] = self.epoch;
                    self.index[n as usize] = texels.len() as u32;
                    texels.push(n);
                    depth.push(d + 1);
                    crosses |= zipper;
                }
            });
        }
        WorkPatch {
            texels,
            depth,
            crosses_charts: crosses,
        }
    }

    fn contains(&self, t: u32) -> Option<usize> {
        (self.stamp[t as usize] == self.epoch).then(|| self.index[t as usize] as usize)
    }
}

/// The work image of a patch and where each patch vertex sits in it.
struct WorkImage {
    width: usize,
    height: usize,
    features: Vec<f32>,
    known: Vec<f32>,
    /// Work-image coordinates of each patch vertex (pixel indices, continuous).
    coords: Vec<[f64; 2]>,
    /// Mean field direction in the work image (radians, y down).
    angle: f64,
    /// Local linear map from atlas steps (+x, +y) to work-image offsets, for
    /// in-chart work images (identity) — used for the Jacobian.
    atlas_to_work: Option<[f64; 4]>,
    /// m0 per work pixel (empty when unconstrained).
    constraint: Vec<f32>,
}

impl WorkImage {
    /// A `width`×`height` work image with nothing known yet: `n` feature
    /// channels, and an m0 channel when the synthesis is constrained.
    fn blank(width: usize, height: usize, state: &State, coords: Vec<[f64; 2]>, angle: f64) -> WorkImage {
        WorkImage {
            width,
            height,
            features: vec![0f32; width * height * state.n],
            known: vec![0f32; width * height],
            coords,
            angle,
            atlas_to_work: None,
            constraint: vec![0f32; if state.target.is_some() { width * height } else { 0 }],
        }
    }
}

/// Per face, the atlas-space angle of its field direction (radians, y down).
fn face_angles(gim: &Gim) -> Result<Vec<f64>> {
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
            crate::gim::atlas_direction(&mesh, &uv, f, v).map_or(0.0, |d| d[1].atan2(d[0]))
        })
        .collect())
}

/// Everything the loop reads.
struct Surface {
    r: usize,
    graph: crate::gim::DenseGraph,
    face: Vec<u32>,
    /// Dense positions multiplied by `unit` (exactly: a power of two, 1 but
    /// for a mesh of extreme size, see [`crate::mesh::extreme_scale`]).
    position: Vec<f32>,
    unit: f32,
    normal: Vec<f32>,
    face_angle: Vec<f64>,
}

impl Surface {
    fn texel_angle(&self, t: u32) -> f64 {
        self.face_angle[self.face[t as usize] as usize]
    }
}

fn mean_angle(angles: impl Iterator<Item = f64>) -> f64 {
    let (mut c, mut s) = (0.0, 0.0);
    for a in angles {
        c += a.cos();
        s += a.sin();
    }
    s.atan2(c)
}

/// In-chart work image: the chart's sub-image around the patch.
fn chart_work_image(surface: &Surface, sample: &Sample, state: &State, patch: &WorkPatch) -> WorkImage {
    let r = surface.r;
    let chart = state.chart[patch.texels[0] as usize];
    let (x0, y0, w, h) = patch.atlas_box(r);
    let n = state.n;
    let coords = patch
        .texels
        .iter()
        .map(|&t| [(t as usize % r - x0) as f64, (t as usize / r - y0) as f64])
        .collect();
    let angle = mean_angle(patch.texels.iter().map(|&t| surface.texel_angle(t)));
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    work.atlas_to_work = Some([1.0, 0.0, 0.0, 1.0]);
    for y in 0..h {
        for x in 0..w {
            let (t, p) = ((y0 + y) * r + x0 + x, y * w + x);
            if state.chart[t] == chart && state.synthesized[t] {
                work.known[p] = 1.0;
                state.feature_into(sample, t as u32, &mut work.features[p * n..(p + 1) * n]);
            }
            if let Some(m0) = &state.target {
                work.constraint[p] = m0[t];
            }
        }
    }
    work
}

/// The patch's triangles (local indices): grid blocks inside charts, then
/// zipper triangles, all wound like the surface; and how many are grid ones.
fn patch_triangles(
    surface: &Surface,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
) -> (Vec<[u32; 3]>, Vec<[f32; 3]>, usize) {
    let r = surface.r;
    let local = |t: u32| bfs.contains(t);
    // triangles: grid blocks inside charts, plus zipper triangles, all in P
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for &t in &patch.texels {
        let (x, y) = (t as usize % r, t as usize / r);
        if x + 1 < r && y + 1 < r {
            for tri in crate::gim::block_triangles(&state.chart, r, x, y) {
                if let (Some(a), Some(b), Some(c)) = (local(tri[0]), local(tri[1]), local(tri[2])) {
                    tris.push([a as u32, b as u32, c as u32]);
                }
            }
        }
    }
    let grid_count = tris.len();
    for z in zipper_triangles {
        if let (Some(a), Some(b), Some(c)) = (local(z[0]), local(z[1]), local(z[2])) {
            tris.push([a as u32, b as u32, c as u32]);
        }
    }
    let positions: Vec<[f32; 3]> = patch
        .texels
        .iter()
        .map(|&t| {
            let p = &surface.position[t as usize * 3..t as usize * 3 + 3];
            [p[0], p[1], p[2]]
        })
        .collect();
    // wind every triangle like the surface (its 3D normal along the texels'
    // normals): zipper triangles are stored unoriented, and the distortion
    // check reads flips from the orientation
    for tri in &mut tris {
        let p = tri.map(|i| positions[i as usize]);
        let n = crate::mesh::cross(crate::mesh::sub(p[1], p[0]), crate::mesh::sub(p[2], p[0]));
        let mut avg = [0f32; 3];
        for &i in tri.iter() {
            let t = patch.texels[i as usize] as usize;
            for k in 0..3 {
                avg[k] += surface.normal[t * 3 + k];
            }
        }
        if crate::mesh::dot(n, avg) < 0.0 {
            tri.swap(1, 2);
        }
    }
    (tris, positions, grid_count)
}

/// Weight of the prior that keeps a chart piece's alignment near the field-
/// based unfolding (texels² per unit of similarity change): a link's
/// residual counts as much as a change of the piece's rotation seen at
/// this distance.
const ALIGN_PRIOR: f64 = 4.0;

type C64 = [f64; 2];

fn cmul(a: C64, b: C64) -> C64 {
    [a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0]]
}

fn conj(a: C64) -> C64 {
    [a[0], -a[1]]
}

/// Solves the small dense complex system `a x = b` (Gaussian elimination
/// with partial pivoting); `None` if singular.
fn solve_complex(mut a: Vec<C64>, mut b: Vec<C64>) -> Option<Vec<C64>> {
    let n = b.len();
    let norm = |z: C64| z[0] * z[0] + z[1] * z[1];
    for k in 0..n {
        let p = (k..n).max_by(|&i, &j| norm(a[i * n + k]).total_cmp(&norm(a[j * n + k])))?;
        if !(norm(a[p * n + k]) > 1e-300) {
            return None;
        }
        if p != k {
            for j in 0..n {
                a.swap(p * n + j, k * n + j);
            }
            b.swap(p, k);
        }
        let d = norm(a[k * n + k]);
        let inv = [a[k * n + k][0] / d, -a[k * n + k][1] / d];
        for i in k + 1..n {
            let f = cmul(a[i * n + k], inv);
            if f == [0.0, 0.0] {
                continue;
            }
            for j in k..n {
                let v = cmul(f, a[k * n + j]);
                a[i * n + j][0] -= v[0];
                a[i * n + j][1] -= v[1];
            }
            let v = cmul(f, b[k]);
            b[i][0] -= v[0];
            b[i][1] -= v[1];
        }
    }
    let mut x = vec![[0.0; 2]; n];
    for k in (0..n).rev() {
        let mut s = b[k];
        for j in k + 1..n {
            let v = cmul(a[k * n + j], x[j]);
            s[0] -= v[0];
            s[1] -= v[1];
        }
        let d = a[k * n + k];
        let dn = d[0] * d[0] + d[1] * d[1];
        x[k] = cmul(s, [d[0] / dn, -d[1] / dn]);
    }
    Some(x)
}

/// Cross-chart flattening by aligning chart pieces. Inside a chart the atlas
/// already is a flattening of the surface with near-unit stretch (the paper
/// uses the chart image directly there), so each chart's part of the work
/// patch keeps its atlas layout up to a similarity w = γ_c u + δ_c applied
/// to the field-based [`unfold`]; the similarities are the least-squares
/// solution that closes the zipper links between the pieces (the links join
/// texels ≈ 0.4 texel apart on the surface), with a weak prior towards the
/// unfolding and the seed's chart fixed. Returns work coordinates per patch
/// vertex.
fn aligned_unfolding(surface: &Surface, state: &State, patch: &WorkPatch, bfs: &Bfs) -> Vec<[f64; 2]> {
    let (u, _) = unfold(surface, state, patch, bfs);
    let mut charts: Vec<u32> = patch.texels.iter().map(|&t| state.chart[t as usize]).collect();
    charts.sort_unstable();
    charts.dedup();
    let piece = |t: u32| {
        charts
            .binary_search(&state.chart[t as usize])
            .expect("patch chart")
    };
    let seed = piece(patch.texels[0]);
    // unknowns: (γ, δ) of every piece but the seed's
    let unknown = |p: usize| if p < seed { p } else { p - 1 };
    let n = 2 * (charts.len() - 1);
    if n == 0 {
        return u;
    }
    let mut a = vec![[0.0f64; 2]; n * n];
    let mut b = vec![[0.0f64; 2]; n];
    // adds the weighted row Σ coeff·x = c to the normal equations
    let mut add_row = |coeffs: &[(usize, C64)], c: C64, w: f64| {
        for &(i, ci) in coeffs {
            let ci_h = conj(ci);
            for &(j, cj) in coeffs {
                let v = cmul(ci_h, cj);
                a[i * n + j][0] += w * v[0];
                a[i * n + j][1] += w * v[1];
            }
            let v = cmul(ci_h, c);
            b[i][0] += w * v[0];
            b[i][1] += w * v[1];
        }
    };
    let mut row: Vec<(usize, C64)> = Vec::with_capacity(4);
    for (i, &t) in patch.texels.iter().enumerate() {
        let p = piece(t);
        surface.graph.for_each_neighbour(t, |nb, zipper| {
            if !zipper {
                return;
            }
            let Some(j) = bfs.contains(nb) else { return };
            let q = piece(nb);
            if j <= i || q == p {
                return;
            }
            // γ_p u_i + δ_p − γ_q u_j − δ_q = 0
            row.clear();
            let mut c = [0.0, 0.0];
            for (piece_k, coord, sign) in [(p, u[i], 1.0), (q, u[j], -1.0)] {
                if piece_k == seed {
                    c[0] -= sign * coord[0];
                    c[1] -= sign * coord[1];
                } else {
                    let k = unknown(piece_k);
                    row.push((2 * k, [sign * coord[0], sign * coord[1]]));
                    row.push((2 * k + 1, [sign, 0.0]));
                }
            }
            add_row(&row, c, 1.0);
        });
    }
    for p in (0..charts.len()).filter(|&p| p != seed) {
        let k = unknown(p);
        add_row(&[(2 * k, [1.0, 0.0])], [1.0, 0.0], ALIGN_PRIOR);
        add_row(&[(2 * k + 1, [1.0, 0.0])], [0.0, 0.0], 1e-6);
    }
    let Some(x) = solve_complex(a, b) else { return u };
    patch
        .texels
        .iter()
        .zip(&u)
        .map(|(&t, &ui)| {
            let p = piece(t);
            if p == seed {
                ui
            } else {
                let k = unknown(p);
                let w = cmul(x[2 * k], ui);
                [w[0] + x[2 * k + 1][0], w[1] + x[2 * k + 1][1]]
            }
        })
        .collect()
}

/// Root-mean-square distance in the work frame across the patch's zipper
/// links (texels).
fn zipper_gap(surface: &Surface, patch: &WorkPatch, bfs: &Bfs, coords: &[[f64; 2]]) -> f64 {
    let (mut gap, mut links) = (0.0, 0usize);
    for (i, &t) in patch.texels.iter().enumerate() {
        surface.graph.for_each_neighbour(t, |nb, zipper| {
            if let (true, Some(j)) = (zipper, bfs.contains(nb)) {
                gap += (coords[i][0] - coords[j][0]).powi(2) + (coords[i][1] - coords[j][1]).powi(2);
                links += 1;
            }
        });
    }
    (gap / links.max(1) as f64).sqrt()
}

/// How much more a zipper link weighs than a grid edge when the gaps are
/// closed.
const LINK_WEIGHT: f64 = 4.0;

/// Closes the gaps an [`aligned_unfolding`] leaves across zipper links (the
/// charts' own flattenings disagree along a seam on a curved surface) by
/// the smoothest displacement field d: minimises Σ_grid |d_i − d_j|² +
/// μ Σ_links |x_i + d_i − x_j − d_j|² (+ a tiny ε|d|²), a membrane that
/// spreads the misfit over the patch like the distortion LSCM would
/// distribute. Solved per coordinate by Jacobi-preconditioned conjugate
/// gradients (at most `iterations`).
fn close_gaps(surface: &Surface, patch: &WorkPatch, bfs: &Bfs, coords: &mut [[f64; 2]], iterations: usize) {
    let m = patch.texels.len();
    let mut start = Vec::with_capacity(m + 1);
    let mut nbr: Vec<(u32, f64)> = Vec::with_capacity(m * 4);
    let mut rhs = vec![[0.0f64; 2]; m];
    let mut any_link = false;
    start.push(0);
    for (i, &t) in patch.texels.iter().enumerate() {
        surface.graph.for_each_neighbour(t, |nb, zipper| {
            if let Some(j) = bfs.contains(nb) {
                let w = if zipper { LINK_WEIGHT } else { 1.0 };
                nbr.push((j as u32, w));
                if zipper {
                    any_link = true;
                    rhs[i][0] += w * (coords[j][0] - coords[i][0]);
                    rhs[i][1] += w * (coords[j][1] - coords[i][1]);
                }
            }
        });
        start.push(nbr.len());
    }
    if !any_link {
        return;
    }
    const EPS: f64 = 1e-4;
    let diag: Vec<f64> = (0..m)
        .map(|i| EPS + nbr[start[i]..start[i + 1]].iter().map(|e| e.1).sum::<f64>())
        .collect();
    let apply = |x: &[f64], out: &mut [f64]| {
        for i in 0..m {
            let mut v = diag[i] * x[i];
            for &(j, w) in &nbr[start[i]..start[i + 1]] {
                v -= w * x[j as usize];
            }
            out[i] = v;
        }
    };
    for c in 0..2 {
        let b: Vec<f64> = rhs.iter().map(|r| r[c]).collect();
        let bnorm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
        if bnorm == 0.0 {
            continue;
        }
        let mut x = vec![0.0f64; m];
        let mut r = b.clone();
        let mut z: Vec<f64> = r.iter().zip(&diag).map(|(r, d)| r / d).collect();
        let mut p = z.clone();
        let mut ap = vec![0.0f64; m];
        let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        for _ in 0..iterations {
            apply(&p, &mut ap);
            let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
            if !(pap > 0.0) {
                break;
            }
            let alpha = rz / pap;
            for k in 0..m {
                x[k] += alpha * p[k];
                r[k] -= alpha * ap[k];
            }
            if r.iter().map(|v| v * v).sum::<f64>().sqrt() < 1e-3 * bnorm {
                break;
            }
            for k in 0..m {
                z[k] = r[k] / diag[k];
            }
            let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..m {
                p[k] = z[k] + beta * p[k];
            }
        }
        for k in 0..m {
            coords[k][c] += x[k];
        }
    }
}

/// The patch flattened across charts (the paper flattens such patches with
/// LSCM; here the charts' own LSCM layouts are aligned by
/// [`aligned_unfolding`] and their seams closed by [`close_gaps`], which
/// never fails on the thin zipper strips a global LSCM solve broke down
/// on), scaled so grid edges average one pixel, and the mean field
/// direction in that frame. `None` if a grid triangle's area changed by
/// more than T_d (or flipped) against its atlas area — the charts are
/// near-isometric, so that is the area distortion against the surface — or
/// if gaps of more than a texel remain across the zippers (a patch around a
/// cone point).
fn flatten(
    surface: &Surface,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    grid_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<(Vec<[f64; 2]>, f64)> {
    let r = surface.r;
    let local = |t: u32| bfs.contains(t);
    let mut uv = aligned_unfolding(surface, state, patch, bfs);
    close_gaps(surface, patch, bfs, &mut uv, 300);
    let gap = zipper_gap(surface, patch, bfs, &uv);
    // grid triangles have atlas area ½; those touching a chart border are
    // left out (conservative coverage overlaps the charts there by up to a
    // texel, which closing the gaps squeezes out)
    let border = |i: u32| {
        let t = patch.texels[i as usize];
        let mut on = false;
        surface.graph.for_each_neighbour(t, |_, zipper| on |= zipper);
        on
    };
    let area = |p: [[f64; 2]; 3]| {
        0.5 * ((p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]))
    };
    let atlas = |i: u32| {
        let t = patch.texels[i as usize] as usize;
        [(t % r) as f64, (t / r) as f64]
    };
    let mut ratios: Vec<f64> = grid_triangles
        .iter()
        .filter(|t| !t.iter().any(|&i| border(i)))
        .map(|t| {
            // against the triangle's atlas area (±½, signed like the atlas)
            let a = area(t.map(|i| uv[i as usize])) / area(t.map(atlas));
            if a > 0.0 {
                a.max(1.0 / a)
            } else {
                f64::INFINITY
            }
        })
        .collect();
    // T_d on the 98th percentile: a few triangles squeezed or folded where
    // a seam closes do not spoil a work image, a patch that cannot lie
    // flat does
    let distortion = if ratios.is_empty() {
        1.0
    } else {
        let k = (ratios.len() * 98 / 100).min(ratios.len() - 1);
        *ratios.select_nth_unstable_by(k, f64::total_cmp).1
    };
    if std::env::var_os("BTFQUILT_TRACE").is_some() {
        eprintln!("flattening distortion {distortion} gap {gap}");
    }
    if !(gap <= 1.0 && distortion <= max_distortion) {
        return None;
    }
    // scale so grid edges average one pixel; measure the frame's rotation
    // against the atlas on grid edges
    let (mut len, mut cnt, mut rc, mut rs) = (0.0, 0usize, 0.0, 0.0);
    for (i, &t) in patch.texels.iter().enumerate() {
        if (t as usize % r) + 1 < r && state.chart[t as usize + 1] == state.chart[t as usize] {
            if let Some(j) = local(t + 1) {
                let d = [uv[j][0] - uv[i][0], uv[j][1] - uv[i][1]];
                len += (d[0] * d[0] + d[1] * d[1]).sqrt();
                cnt += 1;
                // the atlas +x direction maps to angle atan2(d): field angle
                // in the work frame = atlas angle + this rotation
                let a = d[1].atan2(d[0]);
                let fa = surface.texel_angle(t) + a;
                rc += fa.cos();
                rs += fa.sin();
            }
        }
    }
    if cnt == 0 || len <= 0.0 {
        return None;
    }
    let scale = cnt as f64 / len;
    let (mut minu, mut minv) = (f64::INFINITY, f64::INFINITY);
    for p in &uv {
        minu = minu.min(p[0] * scale);
        minv = minv.min(p[1] * scale);
    }
    let coords: Vec<[f64; 2]> = uv
        .iter()
        .map(|p| [p[0] * scale - minu, p[1] * scale - minv])
        .collect();
    Some((coords, rs.atan2(rc)))
}

/// Shifts work-image coordinates so they start at 0; the pixel size of the
/// image that holds them.
fn shift_to_origin(coords: &mut [[f64; 2]]) -> (usize, usize) {
    let minx = coords.iter().map(|c| c[0]).fold(f64::INFINITY, f64::min);
    let miny = coords.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min);
    for c in coords.iter_mut() {
        c[0] -= minx;
        c[1] -= miny;
    }
    let w = coords.iter().map(|c| c[0]).fold(0.0, f64::max).ceil() as usize + 1;
    let h = coords.iter().map(|c| c[1]).fold(0.0, f64::max).ceil() as usize + 1;
    (w, h)
}

/// The work image of a flattened patch: coordinates shifted to start at 0,
/// a pixel known where a triangle of three synthesized vertices covers it
/// (features interpolated). `None` if the patch flattened implausibly large.
fn raster_work_image(
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    tris: &[[u32; 3]],
    mut coords: Vec<[f64; 2]>,
    angle: f64,
    r: usize,
) -> Option<WorkImage> {
    let (w, h) = shift_to_origin(&mut coords);
    if w > 4 * r || h > 4 * r {
        return None;
    }
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    let mut corner = vec![0f32; 3 * n];
    for tri in tris {
        let ids = [
            patch.texels[tri[0] as usize],
            patch.texels[tri[1] as usize],
            patch.texels[tri[2] as usize],
        ];
        if !ids.iter().all(|&t| state.synthesized[t as usize]) {
            continue;
        }
        for (k, &t) in ids.iter().enumerate() {
            state.feature_into(sample, t, &mut corner[k * n..(k + 1) * n]);
        }
        let p = [
            work.coords[tri[0] as usize],
            work.coords[tri[1] as usize],
            work.coords[tri[2] as usize],
        ];
        let d = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if d.abs() < 1e-12 {
            continue;
        }
        let lo = |k: usize| {
            p.iter()
                .map(|q| q[k])
                .fold(f64::INFINITY, f64::min)
                .floor()
                .max(0.0) as usize
        };
        let hi = |k: usize, m: usize| (p.iter().map(|q| q[k]).fold(0.0, f64::max).ceil() as usize).min(m - 1);
        for y in lo(1)..=hi(1, h) {
            for x in lo(0)..=hi(0, w) {
                let q = [x as f64, y as f64];
                let l1 =
                    ((q[0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (q[1] - p[0][1])) / d;
                let l2 =
                    ((p[1][0] - p[0][0]) * (q[1] - p[0][1]) - (q[0] - p[0][0]) * (p[1][1] - p[0][1])) / d;
                let l0 = 1.0 - l1 - l2;
                if l0 < -1e-9 || l1 < -1e-9 || l2 < -1e-9 {
                    continue;
                }
                let i = y * w + x;
                work.known[i] = 1.0;
                if let Some(m0) = &state.target {
                    work.constraint[i] = (l0 as f32) * m0[ids[0] as usize]
                        + (l1 as f32) * m0[ids[1] as usize]
                        + (l2 as f32) * m0[ids[2] as usize];
                }
                for c in 0..n {
                    work.features[i * n + c] = (l0 as f32) * corner[c]
                        + (l1 as f32) * corner[n + c]
                        + (l2 as f32) * corner[2 * n + c];
                }
            }
        }
    }
    Some(work)
}

/// Cross-chart work image: the patch flattened by [`flatten`] and resampled.
/// `None` if it cannot be flattened within the distortion bound.
#[allow(clippy::too_many_arguments)]
fn flattened_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<(WorkImage, Vec<[f64; 2]>)> {
    let (tris, _, grid_count) = patch_triangles(surface, state, patch, bfs, zipper_triangles);
    let (coords, angle) = flatten(surface, state, patch, bfs, &tris[..grid_count], max_distortion)?;
    let work = raster_work_image(sample, state, patch, &tris, coords.clone(), angle, surface.r)?;
    Some((work, coords))
}

/// A seed's flattening, reused when its patch shrinks: a smaller BFS
/// ball from the same seed is part of the larger one.
struct Flattening {
    /// (texel, coordinate), sorted by texel.
    coords: Vec<(u32, [f64; 2])>,
    angle: f64,
}

impl Flattening {
    /// The work image of a smaller patch from the cached coordinates.
    fn work_image(
        &self,
        surface: &Surface,
        sample: &Sample,
        state: &State,
        patch: &WorkPatch,
        bfs: &Bfs,
        zipper_triangles: &[[u32; 3]],
    ) -> Option<WorkImage> {
        let coords: Vec<[f64; 2]> = patch
            .texels
            .iter()
            .map(|t| {
                self.coords
                    .binary_search_by_key(t, |e| e.0)
                    .ok()
                    .map(|k| self.coords[k].1)
            })
            .collect::<Option<_>>()?;
        let (tris, _, _) = patch_triangles(surface, state, patch, bfs, zipper_triangles);
        raster_work_image(sample, state, patch, &tris, coords, self.angle, surface.r)
    }
}

/// Cross-chart work image without flattening: each chart's part of the patch keeps
/// its atlas layout (no resampling inside a chart) and is turned rigidly so
/// that the vector field agrees across the zipper it was entered through.
/// Used when the patch's triangulation cannot be flattened within T_d.
fn unfolded_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
) -> WorkImage {
    let (mut coords, angle) = unfold(surface, state, patch, bfs);
    let (w, h) = shift_to_origin(&mut coords);
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    for (i, &t) in patch.texels.iter().enumerate() {
        if state.synthesized[t as usize] {
            let c = work.coords[i];
            let (x, y) = (c[0].round() as usize, c[1].round() as usize);
            let p = (y.min(h - 1)) * w + x.min(w - 1);
            if work.known[p] == 0.0 {
                work.known[p] = 1.0;
                state.feature_into(sample, t, &mut work.features[p * n..(p + 1) * n]);
                if let Some(m0) = &state.target {
                    work.constraint[p] = m0[t as usize];
                }
            }
        }
    }
    work
}

/// The rigid unfolding of a patch: each chart's part keeps its atlas layout,
/// turned so the vector field agrees across the zipper it was entered
/// through. Work coordinates per patch vertex and the mean field angle.
fn unfold(surface: &Surface, state: &State, patch: &WorkPatch, bfs: &Bfs) -> (Vec<[f64; 2]>, f64) {
    let r = surface.r;
    let m = patch.texels.len();
    let atlas = |t: u32| [(t as usize % r) as f64, (t as usize / r) as f64];
    // per chart: (rotation φ, work origin, atlas origin)
    let mut frames: std::collections::BTreeMap<u32, (f64, [f64; 2], [f64; 2])> = Default::default();
    let v = patch.texels[0];
    frames.insert(state.chart[v as usize], (0.0, [0.0, 0.0], atlas(v)));
    let mut coords = vec![[0f64; 2]; m];
    for i in 0..m {
        let t = patch.texels[i];
        let c = state.chart[t as usize];
        if !frames.contains_key(&c) {
            // entered through a zipper from an earlier texel of a known chart
            let mut entry = None;
            surface.graph.for_each_neighbour(t, |nb, zipper| {
                if entry.is_none() && zipper {
                    if let Some(k) = bfs.contains(nb) {
                        if k < i && frames.contains_key(&state.chart[nb as usize]) {
                            entry = Some((nb, k));
                        }
                    }
                }
            });
            let (phi, origin) = match entry {
                Some((p, k)) => {
                    let pf = frames[&state.chart[p as usize]].0;
                    (pf + surface.texel_angle(p) - surface.texel_angle(t), coords[k])
                }
                None => (0.0, [0.0, 0.0]),
            };
            frames.insert(c, (phi, origin, atlas(t)));
        }
        let (phi, wo, ao) = frames[&c];
        let (s, co) = phi.sin_cos();
        let a = atlas(t);
        let d = [a[0] - ao[0], a[1] - ao[1]];
        coords[i] = [wo[0] + co * d[0] - s * d[1], wo[1] + s * d[0] + co * d[1]];
    }
    let angle = mean_angle(
        patch
            .texels
            .iter()
            .map(|&t| surface.texel_angle(t) + frames[&state.chart[t as usize]].0),
    );
    (coords, angle)
}

/// Rotation index (5° steps for 72 copies) closest to an angle.
fn rotation_index(angle: f64, rotations: usize) -> usize {
    let step = std::f64::consts::TAU / rotations as f64;
    ((angle.rem_euclid(std::f64::consts::TAU) / step).round() as usize) % rotations
}

/// The sample's `.svd`: the file itself, or a colour image factorized into a
/// temporary directory (kept alive by the returned guard), with the rotated
/// copies only if `matching` needs them (they are most of the cost).
pub(crate) fn sample_svd(
    sample_path: &Path,
    matching: bool,
    progress: &dyn Progress,
) -> Result<(PathBuf, Option<tempfile::TempDir>)> {
    if factorize::is_image_path(sample_path) {
        let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
        let p = dir.path().join("sample.svd");
        let cfg = FactorizeConfig {
            rotations: if matching { factorize::DEFAULT_ROTATIONS } else { 0 },
            ..FactorizeConfig::default()
        };
        factorize::factorize(sample_path, &p, &cfg, progress)?;
        Ok((p, Some(dir)))
    } else {
        Ok((sample_path.to_path_buf(), None))
    }
}

/// The quilting loop's working set: the surface, the sample, the synthesis
/// state and the reusable buffers. [`tile`] runs it from an empty surface;
/// painting (`crate::paint`) from a decorated one with a constraint.
pub(crate) struct Synthesis {
    cfg: TileConfig,
    sample_path: PathBuf,
    /// Every sample the surface draws from ([`Quilt::samples`]); the active
    /// one is `sample_paths[state.active]`.
    sample_paths: Vec<PathBuf>,
    /// The preview colours of the other samples a loaded surface draws
    /// from (by index; `None` for the active one and unused ones).
    other_previews: Vec<Option<crate::imageio::RgbImage>>,
    surface: Surface,
    zipper_triangles: Vec<[u32; 3]>,
    sample: Sample,
    state: State,
    bfs: Bfs,
    matcher: Matcher,
    /// The sample's mean neighbour difference, the unit of T_c.
    reference: f64,
    pub(crate) report: TileReport,
    /// Painting (§IV): one min-cut per fitting, no T_c shrinking, and a
    /// fitting may keep every old value.
    pub(crate) painting: bool,
    seam_sum: f64,
    seam_cnt: usize,
}

impl Synthesis {
    /// Opens the geometry image and the sample's `.svd`, with an empty state.
    /// Without `matching` (verbatim copy) the rotated copies are not needed:
    /// rotations are then quantized to the default 72 steps.
    pub(crate) fn open(
        gim: &Gim,
        sample_path: &Path,
        svd_path: &Path,
        cfg: &TileConfig,
        matching: bool,
    ) -> Result<Self> {
        // --memory is shared by the three caches of the loop: decoded tiles
        // of the .svd, the rotated copies as f32, and the sample spectra of
        // the matcher (a quarter each; the per-texel state comes on top)
        let quarter = (cfg.memory.0 / 4).max(1 << 20);
        let svd = SvdArtifact::open(svd_path, crate::container::MemoryBudget(quarter))?;
        if matching && svd.rotations == 0 {
            return Err(Error::input(
                sample_path,
                "has no rotated copies (factorize with --rotations 72)",
            ));
        }
        let mut sample = Sample::from_svd(svd)?;
        sample.rotated_budget = quarter as usize;
        let n = sample.n;
        let r = gim.resolution;
        let mut position: Vec<f32> = gim.read("position")?;
        let unit = {
            let points: Vec<[f32; 3]> = position.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
            crate::mesh::extreme_scale(&points) as f32
        };
        if unit != 1.0 {
            position.iter_mut().for_each(|c| *c *= unit);
        }
        let surface = Surface {
            r,
            graph: gim.graph()?,
            face: gim.read("face")?,
            position,
            unit,
            normal: gim.read("normal")?,
            face_angle: face_angles(gim)?,
        };
        let reference = sample.neighbour_difference();
        let state = State::new(surface.graph.chart.clone(), n, r);
        let total = state.remaining;
        Ok(Synthesis {
            cfg: cfg.clone(),
            sample_path: sample_path.to_path_buf(),
            sample_paths: vec![sample_path.to_path_buf()],
            other_previews: Vec::new(),
            zipper_triangles: gim.zipper_triangles()?,
            sample,
            state,
            bfs: Bfs {
                stamp: vec![0; r * r],
                index: vec![0; r * r],
                epoch: 0,
            },
            matcher: Matcher::with_cache_budget(quarter as usize),
            reference,
            report: TileReport {
                texels: total,
                ..TileReport::default()
            },
            surface,
            painting: false,
            seam_sum: 0.0,
            seam_cnt: 0,
        })
    }

    /// Loads the sample's foreground mask m_P (a PNG the sample's size; any
    /// channel above one half counts as foreground, grey levels between).
    /// Call it before [`Synthesis::load`], which looks m_σ up per texel.
    pub(crate) fn set_mask(&mut self, path: &Path) -> Result<()> {
        let (w, h) = (self.sample.width, self.sample.height);
        let mask = crate::imageio::read_sized_mask(
            path,
            w,
            h,
            "the sample's foreground mask must be the sample's size",
        )?;
        if !mask.iter().any(|&m| m >= 0.5) {
            return Err(Error::input(
                path,
                "marks no foreground (no pixel above one half)",
            ));
        }
        self.sample.mask = Some(mask);
        Ok(())
    }

    /// Sets the constraint function m0 per atlas texel.
    pub(crate) fn set_target(&mut self, m0: Vec<f32>) {
        self.state.target = Some(m0);
    }

    /// Resolution R of the atlas.
    pub(crate) fn resolution(&self) -> usize {
        self.surface.r
    }

    /// The dense mesh graph.
    pub(crate) fn graph(&self) -> &crate::gim::DenseGraph {
        &self.surface.graph
    }

    /// 3D position of a dense vertex, in the mesh's units.
    pub(crate) fn position(&self, t: u32) -> [f32; 3] {
        let p = &self.surface.position[t as usize * 3..t as usize * 3 + 3];
        [p[0], p[1], p[2]].map(|c| c / self.surface.unit)
    }

    /// The constraint function m0 (empty when unconstrained).
    pub(crate) fn target(&self) -> &[f32] {
        self.state.target.as_deref().unwrap_or(&[])
    }

    /// The sample's width and foreground mask (empty without one).
    pub(crate) fn sample_mask(&self) -> (usize, &[f32]) {
        (self.sample.width, self.sample.mask.as_deref().unwrap_or(&[]))
    }

    /// Patch id per texel.
    pub(crate) fn patch_ids(&self) -> &[u32] {
        &self.state.patch
    }

    /// Starts from a decorated surface: its coordinates, rotations, patch
    /// ids, Jacobians and sample indices. The features are looked up in each
    /// texel's own sample; texels of another sample than the one opened
    /// (painting with a new sample) are projected into its basis, g ↦ P_aᵀ
    /// P_k g (both appearance bases orthonormal, so this is the closest
    /// vector of the active rank-n space to the texel's value), and count as
    /// background (m_σ = 0). The opened sample joins the surface's list if
    /// it is new.
    pub(crate) fn load(&mut self, quilt: &Quilt, progress: &dyn Progress) -> Result<()> {
        let r = self.surface.r;
        if quilt.resolution != r {
            return Err(Error::input(
                quilt.container().path(),
                format!("is {}² but its geometry image is {r}²", quilt.resolution),
            ));
        }
        let coords = quilt.coords()?;
        let patches = quilt.patches()?;
        let rotations = quilt.rotations()?;
        let jacobians = quilt.jacobians()?;
        let source = quilt.sample_index()?;
        let mut paths = quilt.samples.clone();
        let active = match paths.iter().position(|p| same_file(p, &self.sample_path)) {
            Some(k) => k,
            None if paths.len() < MAX_SAMPLES => {
                paths.push(self.sample_path.clone());
                paths.len() - 1
            }
            None => {
                return Err(Error::input(
                    quilt.container().path(),
                    format!("already draws from {MAX_SAMPLES} samples, the most one surface can"),
                ))
            }
        };
        // the other samples in use, with their projections into the active basis
        let mut others: Vec<Option<(Sample, Vec<f32>)>> = (0..paths.len()).map(|_| None).collect();
        let mut previews = vec![None; paths.len()];
        let mut used = vec![false; paths.len()];
        for (t, &k) in source.iter().enumerate() {
            used[k as usize] |= patches[t] != NO_PATCH;
        }
        let active_p = self.sample.svd.appearance()?;
        for k in (0..paths.len()).filter(|&k| used[k] && k != active) {
            let (svd_path, _tmp) = sample_svd(&paths[k], false, progress)?;
            let svd = SvdArtifact::open(&svd_path, self.cfg.memory)?;
            crate::bake::same_directions(&self.sample.svd, &svd)?;
            let projection = basis_projection(&active_p, self.sample.n, &svd.appearance()?, svd.terms);
            previews[k] = Some(svd.preview()?);
            others[k] = Some((Sample::from_svd(svd)?, projection));
        }
        let n = self.state.n;
        let mut scratch = Vec::new();
        let st = &mut self.state;
        st.active = active as u8;
        for b in st.buckets.iter_mut() {
            b.clear();
        }
        st.remaining = 0;
        let mut next = 0u32;
        for t in 0..r * r {
            if st.chart[t] == EMPTY {
                continue;
            }
            if patches[t] == NO_PATCH {
                return Err(Error::input(
                    quilt.container().path(),
                    "is not fully decorated (texels without a patch)",
                ));
            }
            st.synthesized[t] = true;
            st.coord[t] = coords[t];
            st.rotation[t] = rotations[t];
            st.patch[t] = patches[t];
            st.jacobian[t] = jacobians[t];
            st.source[t] = source[t];
            next = next.max(patches[t] + 1);
            let c = [coords[t][0] as f64, coords[t][1] as f64];
            match &others[source[t] as usize] {
                None => {
                    st.foreign[t] = NO_FOREIGN;
                    st.mask[t] = self.sample.mask_at(c);
                }
                Some((other, projection)) => {
                    scratch.clear();
                    scratch.resize(other.n, 0f32);
                    other.lookup(c, &mut scratch);
                    st.foreign[t] = (st.foreign_features.len() / n) as u32;
                    for a in 0..n {
                        let v = dot_f32(&projection[a * other.n..(a + 1) * other.n], &scratch);
                        st.foreign_features.push(v);
                    }
                    st.mask[t] = 0.0;
                }
            }
        }
        st.next_patch = next;
        self.sample_paths = paths;
        self.other_previews = previews;
        Ok(())
    }

    /// Writes the state as a `.quilt` (see [`tile`]); `paint_log` for a
    /// painted surface.
    pub(crate) fn write(
        &mut self,
        out: &Path,
        gim: &Gim,
        gim_path: &Path,
        paint_log: Option<&str>,
        start: Instant,
    ) -> Result<TileReport> {
        self.finish_report(start);
        let report = self.report.clone();
        write_quilt(out, &self.cfg, gim, gim_path, self, paint_log, &report)?;
        Ok(report)
    }

    /// The work-patch radius r_w: 32 per 512 texels of atlas (the paper's
    /// figure), but at most a quarter of the sample's smaller side, so a
    /// work image (about 2 r_w across) leaves room to place and turn the
    /// sample: on Spot at 1024² with a 128² BTF, r_w 32 instead of 64 took
    /// 17 s instead of 35–43 s with a seam ratio of 1.28 instead of 1.40;
    /// with a 192² crop, 48 instead of 64 gave 0.91 instead of 0.97.
    pub(crate) fn radius0(&self) -> usize {
        let cfg = &self.cfg;
        let by_atlas = 32 * self.surface.r / 512;
        let by_sample = self.sample.width.min(self.sample.height) / 4;
        cfg.patch_radius
            .unwrap_or(by_atlas.min(by_sample))
            .max(cfg.min_radius)
    }

    /// One step of the quilting loop (the paper's Fig. 4) at vertex `v`:
    /// work patch P(v) of radius r_w, work image I(v), patch matching,
    /// graphcut fitting, and the hierarchical search that shrinks r_w by 0.8
    /// (down to the minimum) while the seam cost exceeds T_c. Returns the
    /// vertices of the accepted work patch.
    pub(crate) fn step(&mut self, v: u32, radius0: usize, progress: &dyn Progress) -> Result<WorkPatch> {
        let cfg = self.cfg.clone();
        let cfg = &cfg;
        let mut radius = radius0;
        let mut flattening: Option<Flattening> = None;
        let painting = self.painting;
        // the rejected fitting with the lowest mean seam cost: if no radius
        // passes T_c, it is taken instead of the smallest patch (fewer,
        // larger pieces than always ending at r_w = 4)
        let mut best: Option<(f64, WorkPatch, Fit, bool)> = None;
        loop {
            let patch = self.bfs.patch(&self.surface.graph, v, radius);
            let (work, unfolded) = self.work_image(&patch, &mut flattening);
            let fit = self.match_and_fit(&patch, &work, painting, 0)?;
            let mean = if fit.seam_edges > 0 {
                fit.seam_cost / fit.seam_edges as f64
            } else {
                0.0
            };
            // (painting takes its one min-cut per fitting: its seams must
            // cross the foreground's border where m0 demands it, which T_c
            // would read as a bad fit)
            let (mut patch, mut fit, mut unfolded) = (patch, fit, unfolded);
            if !painting && mean > cfg.seam_threshold * self.reference && fit.taken_new_synth > 0 {
                if radius > cfg.min_radius {
                    if best.as_ref().is_none_or(|b| mean < b.0) {
                        best = Some((mean, patch, fit, unfolded));
                    }
                    radius = ((radius as f64 * 0.8) as usize).max(cfg.min_radius);
                    self.report.shrinks += 1;
                    continue;
                }
                if let Some(b) = best.take().filter(|b| b.0 < mean) {
                    if std::env::var_os("BTFQUILT_TRACE").is_some() {
                        progress.note(&format!("best of the radii: {:.3} instead of {mean:.3}", b.0));
                    }
                    (patch, fit, unfolded) = (b.1, b.2, b.3);
                }
            }
            if fit.taken == 0 && !painting {
                // nothing could be placed (sample too small for the work
                // image): shrink, or give up on this vertex at the minimum
                if radius > cfg.min_radius {
                    radius = ((radius as f64 * 0.8) as usize).max(cfg.min_radius);
                    self.report.shrinks += 1;
                    continue;
                }
                let (sw, sh) = (self.sample.width, self.sample.height);
                return Err(Error::input(
                    &self.sample_path,
                    format!("is too small ({sw}×{sh}) to cover a work patch of radius {radius}"),
                ));
            }
            if std::env::var_os("BTFQUILT_TRACE").is_some() {
                progress.note(&format!(
                    "patch {} v {v} radius {radius} texels {} taken {} remaining {} cross {}",
                    self.report.patches,
                    patch.texels.len(),
                    fit.taken,
                    self.state.remaining,
                    patch.crosses_charts
                ));
            }
            self.report.cross_chart_patches += patch.crosses_charts as usize;
            self.report.unfolded_patches += unfolded as usize;
            self.accept(&patch, &fit, progress);
            return Ok(patch);
        }
    }

    /// Seam refinement (Kwatra et al. 2003, §3.3, "patch placement on
    /// seams"): once the surface is covered, the most visible seams —
    /// edges of the dense graph (grid edges and zipper links) across patches whose step exceeds `step` × the sample's
    /// neighbour difference, largest first — each get one more work patch
    /// of radius `radius` centred on them, matched against the finished
    /// surface, whose core (3 hops around the seam) must take the new
    /// values; the graphcut with seam nodes then places the new seams, and
    /// the fitting is kept only if its cut costs less than 0.9 × the old
    /// seams it replaces. Returns how many were kept. Seams already inside
    /// a refined patch are not visited again.
    pub(crate) fn refine(&mut self, radius: usize, step: f64, progress: &dyn Progress) -> Result<usize> {
        let r = self.surface.r;
        let n = self.state.n;
        let (mut fa, mut fb) = (vec![0f32; n], vec![0f32; n]);
        let mut seeds: Vec<(f64, u32)> = Vec::new();
        let mut across: Vec<u32> = Vec::with_capacity(8);
        for t in 0..(r * r) as u32 {
            let tu = t as usize;
            if self.state.chart[tu] == EMPTY {
                continue;
            }
            // seams inside charts and across zippers alike: a seam that runs
            // along a chart border is as visible as any other
            across.clear();
            self.surface.graph.for_each_neighbour(t, |nb, _| {
                if nb > t && self.state.patch[nb as usize] != self.state.patch[tu] {
                    across.push(nb);
                }
            });
            if across.is_empty() {
                continue;
            }
            self.state.feature_into(&self.sample, t, &mut fa);
            let mut worst = 0f64;
            for &nb in &across {
                self.state.feature_into(&self.sample, nb, &mut fb);
                worst = worst.max(dist(&fa, &fb));
            }
            if worst > step * self.reference {
                seeds.push((worst, t));
            }
        }
        seeds.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut visited = vec![false; r * r];
        let mut kept = 0;
        for &(_, v) in &seeds {
            if visited[v as usize] {
                continue;
            }
            let patch = self.bfs.patch(&self.surface.graph, v, radius);
            let (work, _) = self.work_image(&patch, &mut None);
            let fit = self.best_of_placements(&patch, &work, self.cfg.refine_placements, 3)?;
            let rim = patch.depth.iter().copied().max().unwrap_or(0);
            for (&t, &d) in patch.texels.iter().zip(&patch.depth) {
                if d + 2 < rim {
                    visited[t as usize] = true;
                }
            }
            if fit.taken > 0 && fit.flow < 0.9 * fit.baseline {
                self.accept(&patch, &fit, progress);
                self.report.refined += 1;
                kept += 1;
            }
        }
        Ok(kept)
    }

    /// Patch matching of the work image against the sample, then the
    /// graphcut fitting of the chosen placement ([`fit_patch`], which says
    /// what `keep_outside_target` and `core` do), timed into the report.
    fn match_and_fit(
        &mut self,
        patch: &WorkPatch,
        work: &WorkImage,
        keep_outside_target: bool,
        core: u16,
    ) -> Result<Fit> {
        let t = Instant::now();
        let placement = place_covering(
            &mut self.sample,
            &mut self.matcher,
            work,
            &self.cfg,
            self.reference,
            self.report.patches as u64,
        )?;
        self.report.matching_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let fit = self.fit_placement(patch, work, &placement, keep_outside_target, core);
        self.report.graphcut_seconds += t.elapsed().as_secs_f64();
        Ok(fit)
    }

    /// The graphcut fitting of one placement ([`fit_patch`]).
    fn fit_placement(
        &self,
        patch: &WorkPatch,
        work: &WorkImage,
        placement: &PlacementChoice,
        keep_outside_target: bool,
        core: u16,
    ) -> Fit {
        fit_patch(
            &self.sample,
            &self.state,
            &self.surface,
            patch,
            work,
            placement,
            self.cfg.constraint_weight * self.reference,
            keep_outside_target,
            core,
        )
    }

    /// Seam refinement's fitting: the graphcut of each of the `count` best
    /// covering placements ([`distinct_best`]), the one with the cheapest cut
    /// kept. A refinement has to beat the seams already there, and the
    /// cheapest match is not always the cheapest cut.
    fn best_of_placements(
        &mut self,
        patch: &WorkPatch,
        work: &WorkImage,
        count: usize,
        core: u16,
    ) -> Result<Fit> {
        let t = Instant::now();
        let (rotation, covering) = covering_candidates(
            &mut self.sample,
            &mut self.matcher,
            work,
            &self.cfg,
            self.reference,
        )?;
        let mut picks: Vec<PlacementChoice> = distinct_best(&covering, count, REFINE_SPACING)
            .into_iter()
            .map(|p| PlacementChoice {
                rotation,
                dx: p.dx as f64,
                dy: p.dy as f64,
            })
            .collect();
        if picks.is_empty() {
            // no match covers the patch: the seeded spot the quilting step
            // would take
            let counter = self.report.patches as u64;
            picks.push(choose_placement(
                &self.sample,
                work,
                &self.cfg,
                counter,
                rotation,
                &covering,
            ));
        }
        self.report.matching_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut best: Option<Fit> = None;
        for placement in picks {
            let fit = self.fit_placement(patch, work, &placement, false, core);
            if best.as_ref().is_none_or(|b| fit.flow < b.flow) {
                best = Some(fit);
            }
        }
        self.report.graphcut_seconds += t.elapsed().as_secs_f64();
        Ok(best.expect("picks is not empty"))
    }

    /// Records an accepted fitting under the next patch id.
    fn accept(&mut self, patch: &WorkPatch, fit: &Fit, progress: &dyn Progress) {
        let id = self.state.next_patch;
        self.state.next_patch += 1;
        apply(
            &mut self.state,
            &self.sample,
            &self.surface,
            patch,
            fit,
            id,
            progress,
        );
        self.seam_sum += fit.seam_cost;
        self.seam_cnt += fit.seam_edges;
        self.report.patches += 1;
    }

    /// The work image I(v) of a work patch: the chart image inside a chart;
    /// across charts the flattening (reused from `flattening` when the same
    /// seed's patch shrinks), or the rigid unfolding where that fails — and
    /// whether it is that unfolding.
    fn work_image(&self, patch: &WorkPatch, flattening: &mut Option<Flattening>) -> (WorkImage, bool) {
        let (surface, state, bfs, zt) = (&self.surface, &self.state, &self.bfs, &self.zipper_triangles);
        if !patch.crosses_charts {
            return (chart_work_image(surface, &self.sample, state, patch), false);
        }
        if let Some(work) = flattening
            .as_ref()
            .and_then(|f| f.work_image(surface, &self.sample, state, patch, bfs, zt))
        {
            return (work, false);
        }
        if let Some((work, coords)) = flattened_work_image(
            surface,
            &self.sample,
            state,
            patch,
            bfs,
            zt,
            self.cfg.max_distortion,
        ) {
            let mut c: Vec<(u32, [f64; 2])> = patch.texels.iter().copied().zip(coords).collect();
            c.sort_unstable_by_key(|e| e.0);
            *flattening = Some(Flattening {
                coords: c,
                angle: work.angle,
            });
            return (work, false);
        }
        (
            unfolded_work_image(surface, &self.sample, state, patch, bfs),
            true,
        )
    }

    /// Verbatim copy (§IV): the sample's foreground, its point `centre`
    /// (unrotated sample pixels) put on dense vertex `v`, turned by `angle`
    /// (radians) from the field direction, over a work patch of `radius`.
    /// With `preview`, only writes the direct projection (no graphcut: the
    /// foreground pasted over the old colours in the patch's atlas box) and
    /// returns; otherwise merges it with a graphcut seam: foreground texels
    /// are forced to the copy, the rest chooses by the smoothness term.
    pub(crate) fn verbatim(
        &mut self,
        v: u32,
        radius: usize,
        angle: f64,
        centre: [f64; 2],
        preview: Option<&Path>,
        progress: &dyn Progress,
    ) -> Result<usize> {
        let t0 = Instant::now();
        let trace = |what: &str| crate::progress::trace(progress, t0, &format!("verbatim {what}"));
        let patch = self.bfs.patch(&self.surface.graph, v, radius);
        trace("work patch");
        let mut flattening = None;
        let (work, _) = self.work_image(&patch, &mut flattening);
        trace("work image");
        let rotations = self.sample.rotated.len();
        let rotation = rotation_index(work.angle + angle, rotations);
        let theta = rotation as f64 * std::f64::consts::TAU / rotations as f64;
        let (s, c) = theta.sin_cos();
        let mid = [
            (self.sample.width as f64 - 1.0) / 2.0,
            (self.sample.height as f64 - 1.0) / 2.0,
        ];
        let d = [centre[0] - mid[0], centre[1] - mid[1]];
        let q = [c * d[0] - s * d[1], s * d[0] + c * d[1]];
        let placement = PlacementChoice {
            rotation,
            dx: work.coords[0][0] - mid[0] - q[0],
            dy: work.coords[0][1] - mid[1] - q[1],
        };
        let placed: Vec<[f64; 2]> = work
            .coords
            .iter()
            .map(|&w| to_sample(&self.sample, rotation, placement.dx, placement.dy, w))
            .collect();
        let fg: Vec<f32> = placed.iter().map(|&c| self.sample.mask_at(c)).collect();
        trace("placed");
        if let Some(out) = preview {
            let colours = self.sample.svd.preview()?;
            let r = self.surface.r;
            let (x0, y0, w, h) = patch.atlas_box(r);
            let mut data = vec![0f32; w * h * 3];
            for y in 0..h {
                for x in 0..w {
                    let t = (y0 + y) * r + x0 + x;
                    if self.state.synthesized[t] {
                        let c = self.state.coord[t];
                        let from = self.other_previews.get(self.state.source[t] as usize);
                        let col = crate::bake::bilinear(
                            from.and_then(Option::as_ref).unwrap_or(&colours),
                            c[0],
                            c[1],
                        );
                        data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&col);
                    }
                }
            }
            for (i, &t) in patch.texels.iter().enumerate() {
                if fg[i] >= 0.5 {
                    let (x, y) = (t as usize % r - x0, t as usize / r - y0);
                    let col = crate::bake::bilinear(&colours, placed[i][0] as f32, placed[i][1] as f32);
                    data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&col);
                }
            }
            let img = crate::imageio::RgbImage {
                width: w,
                height: h,
                data,
            };
            trace("projected");
            crate::imageio::write_png(out, &img, crate::imageio::PngDepth::Eight)?;
            trace("written");
            return Ok(fg.iter().filter(|&&m| m >= 0.5).count());
        }
        // m0 = the placed foreground on the patch, 0 elsewhere
        let mut m0 = vec![0f32; self.state.chart.len()];
        for (i, &t) in patch.texels.iter().enumerate() {
            m0[t as usize] = fg[i];
        }
        self.state.target = Some(m0);
        let t = Instant::now();
        let fit = fit_patch(
            &self.sample,
            &self.state,
            &self.surface,
            &patch,
            &work,
            &placement,
            INFINITE.sqrt(),
            false,
            0,
        );
        self.report.graphcut_seconds += t.elapsed().as_secs_f64();
        self.accept(&patch, &fit, progress);
        Ok(fit.taken)
    }

    /// Mean seam cost per seam edge in units of the sample's neighbour
    /// difference.
    fn finish_report(&mut self, start: Instant) {
        self.report.mean_seam_cost = if self.seam_cnt > 0 {
            self.seam_sum / self.seam_cnt as f64 / self.reference
        } else {
            0.0
        };
        self.report.seconds = start.elapsed().as_secs_f64();
    }
}

/// Decorates the geometry image `gim_path` with the sample (`.svd`, or a
/// colour image factorized on the fly) into the `.quilt` artifact `out`.
/// With `cfg.sample_mask` (the sample's foreground mask), the constrained
/// graphcut keeps the foreground out of the background (m0 = 0 everywhere).
pub fn tile(
    gim_path: &Path,
    sample_path: &Path,
    out: &Path,
    cfg: &TileConfig,
    progress: &dyn Progress,
) -> Result<TileReport> {
    let start = Instant::now();
    cfg.validate()?;
    let mut inputs = vec![("the geometry image", gim_path), ("the sample", sample_path)];
    if let Some(mask) = &cfg.sample_mask {
        inputs.push(("the sample's foreground mask", mask.as_path()));
    }
    crate::staging::check_output(out, &inputs)?;
    let gim = Gim::open(gim_path, cfg.memory)?;
    let (svd_path, _tmp) = sample_svd(sample_path, true, progress)?;
    let mut syn = Synthesis::open(&gim, sample_path, &svd_path, cfg, true)?;
    if let Some(mask) = &cfg.sample_mask {
        syn.set_mask(mask)?;
        syn.set_target(vec![0.0; syn.surface.r * syn.surface.r]);
    }
    let r = gim.resolution;
    let radius0 = syn.radius0();
    progress.begin("tile", syn.state.remaining as u64);
    // the first vertex: a seeded choice among all dense vertices
    let mut first = {
        let covered: Vec<u32> = (0..(r * r) as u32)
            .filter(|&t| syn.state.chart[t as usize] != EMPTY)
            .collect();
        if covered.is_empty() {
            return Err(Error::input(gim_path, "has no dense vertices"));
        }
        Some(covered[(crate::rng::mix64(cfg.seed) % covered.len() as u64) as usize])
    };
    while syn.state.remaining > 0 {
        let v = first
            .take()
            .or_else(|| syn.state.most_constrained())
            .expect("remaining > 0");
        syn.step(v, radius0, progress)?;
    }
    progress.end();
    if let Some(step) = cfg.refine {
        syn.refine(radius0.max(cfg.min_radius), step, progress)?;
    }
    syn.finish_report(start);
    let report = syn.report.clone();
    write_quilt(out, cfg, &gim, gim_path, &syn, None, &report)?;
    Ok(report)
}

/// Refinement fits this many distinct placements per seam by default
/// ([`TileConfig::refine_placements`]).
pub const REFINE_PLACEMENTS: usize = 1;

/// Placements tried by a refinement are at least this many pixels apart.
const REFINE_SPACING: i32 = 4;

/// The matches of the work image against the sample at the work image's
/// rotation whose placement puts the seed and 95 % of the work image on
/// the sample.
fn covering_candidates(
    sample: &mut Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    cfg: &TileConfig,
    reference: f64,
) -> Result<(usize, Vec<matching::Placement>)> {
    let weight = (cfg.constraint_weight * reference).powi(2);
    let (rotation, candidates) = match_candidates(sample, matcher, work, weight)?;
    let step = (work.coords.len() / 400).max(1);
    let probe: Vec<[f64; 2]> = work.coords.iter().step_by(step).copied().collect();
    let covering = candidates
        .into_iter()
        .filter(|p| {
            let (dx, dy) = (p.dx as f64, p.dy as f64);
            if !inside_sample(sample, to_sample(sample, rotation, dx, dy, work.coords[0])) {
                return false;
            }
            let ok = probe
                .iter()
                .filter(|w| inside_sample(sample, to_sample(sample, rotation, dx, dy, **w)))
                .count();
            ok as f64 >= 0.95 * probe.len() as f64
        })
        .collect();
    Ok((rotation, covering))
}

/// Up to `count` placements of finite cost, cheapest first, each at least
/// `spacing` pixels (Chebyshev) from those already picked; ties in cost keep
/// the order given, so the pick is deterministic.
fn distinct_best(placements: &[matching::Placement], count: usize, spacing: i32) -> Vec<matching::Placement> {
    let mut order: Vec<&matching::Placement> = placements.iter().filter(|p| p.cost.is_finite()).collect();
    order.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut picks: Vec<matching::Placement> = Vec::with_capacity(count);
    for p in order {
        if picks.len() == count {
            break;
        }
        if picks
            .iter()
            .all(|q| (q.dx - p.dx).abs().max((q.dy - p.dy).abs()) >= spacing)
        {
            picks.push(*p);
        }
    }
    picks
}

/// A placement of the rotated sample over the work image.
struct PlacementChoice {
    rotation: usize,
    dx: f64,
    dy: f64,
}

/// Maps a work-image coordinate through a placement to unrotated sample
/// coordinates (the inverse of the rotated copy's construction).
fn to_sample(sample: &Sample, rotation: usize, dx: f64, dy: f64, w: [f64; 2]) -> [f64; 2] {
    let theta = rotation as f64 * std::f64::consts::TAU / sample.rotated.len() as f64;
    let (s, c) = theta.sin_cos();
    let cen = [
        (sample.width as f64 - 1.0) / 2.0,
        (sample.height as f64 - 1.0) / 2.0,
    ];
    let q = [w[0] - dx - cen[0], w[1] - dy - cen[1]];
    [c * q[0] + s * q[1] + cen[0], -s * q[0] + c * q[1] + cen[1]]
}

fn inside_sample(sample: &Sample, c: [f64; 2]) -> bool {
    sample.tileable
        || (c[0] >= 0.0
            && c[1] >= 0.0
            && c[0] <= sample.width as f64 - 1.0
            && c[1] <= sample.height as f64 - 1.0)
}

/// Places the sample over the work image (Kwatra et al.: the new patch must
/// cover the work patch): among the best matches, those that put the seed
/// and at least 95 % of the patch's vertices on the sample; a seeded choice
/// among the near-minimal ones; the sample centred on the seed if none does.
fn place_covering(
    sample: &mut Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    cfg: &TileConfig,
    reference: f64,
    counter: u64,
) -> Result<PlacementChoice> {
    let (rotation, covering) = covering_candidates(sample, matcher, work, cfg, reference)?;
    Ok(choose_placement(sample, work, cfg, counter, rotation, &covering))
}

/// A seeded choice among the near-minimal `covering` matches
/// ([`matching::choose`]), or, when there is none, a seeded spot on the
/// sample (one that best agrees with the constraint when the work image has
/// one).
fn choose_placement(
    sample: &Sample,
    work: &WorkImage,
    cfg: &TileConfig,
    counter: u64,
    rotation: usize,
    covering: &[matching::Placement],
) -> PlacementChoice {
    let step = (work.coords.len() / 400).max(1);
    if let Some(p) = matching::choose(covering, cfg.tolerance, cfg.seed, counter) {
        return PlacementChoice {
            rotation,
            dx: p.dx as f64,
            dy: p.dy as f64,
        };
    }
    // nothing known yet, or no match covers the patch: a seeded spot that
    // covers the seed's neighbourhood (the sample centre ± a margin)
    let (sw, sh) = (sample.width as f64, sample.height as f64);
    let theta = rotation as f64 * std::f64::consts::TAU / sample.rotated.len() as f64;
    let (s, c) = theta.sin_cos();
    let mid = [(sw - 1.0) / 2.0, (sh - 1.0) / 2.0];
    // the seed at unrotated sample point `cen`: solve for the translation
    let place = |cen: [f64; 2]| {
        let d = [cen[0] - mid[0], cen[1] - mid[1]];
        // q = R(θ) d (inverse of the rotation in `to_sample`)
        let q = [c * d[0] - s * d[1], s * d[0] + c * d[1]];
        PlacementChoice {
            rotation,
            dx: (work.coords[0][0] - mid[0] - q[0]).round(),
            dy: (work.coords[0][1] - mid[1] - q[1]).round(),
        }
    };
    let h = crate::rng::mix64(cfg.seed ^ crate::rng::mix64(counter + 1));
    let jitter = |bits: u64, span: f64| ((bits & 0xffff) as f64 / 65535.0 - 0.5) * span;
    if !work.constraint.is_empty() && sample.mask.is_some() {
        // constrained: among seeded spots anywhere on the sample, the one
        // whose foreground best agrees with m0 over the patch (outside the
        // sample counts as a full mismatch), the first of equals
        let probe: Vec<usize> = (0..work.coords.len()).step_by(step).collect();
        let mut best = (f64::INFINITY, place([mid[0], mid[1]]));
        for k in 0..64u64 {
            let b = crate::rng::mix64(h ^ crate::rng::mix64(k + 1));
            let choice = place([mid[0] + jitter(b, 0.9 * sw), mid[1] + jitter(b >> 16, 0.9 * sh)]);
            let cost: f64 = probe
                .iter()
                .map(|&i| {
                    let w = work.coords[i];
                    let m0 = work.constraint[(w[1].round() as usize).min(work.height - 1) * work.width
                        + (w[0].round() as usize).min(work.width - 1)];
                    let cs = to_sample(sample, rotation, choice.dx, choice.dy, w);
                    if inside_sample(sample, cs) {
                        (sample.mask_at(cs) - m0).abs() as f64
                    } else {
                        1.0
                    }
                })
                .sum();
            if cost < best.0 {
                best = (cost, choice);
            }
        }
        return best.1;
    }
    let margin = 0.25;
    place([
        (sw - 1.0) / 2.0 + jitter(h, margin * sw),
        (sh - 1.0) / 2.0 + jitter(h >> 16, margin * sh),
    ])
}

/// The rotation for the work image's field direction and the best matches
/// of that rotated copy (up to 64, cheapest first); jointly on features and
/// on the constraint (m0 against the rotated foreground mask, weighted by
/// `constraint_weight`) when the work image carries one (§IV).
fn match_candidates(
    sample: &mut Sample,
    matcher: &mut Matcher,
    work: &WorkImage,
    constraint_weight: f64,
) -> Result<(usize, Vec<matching::Placement>)> {
    let rotations = sample.rotated.len();
    let rot = rotation_index(work.angle, rotations);
    let (sw, sh, n) = (sample.width, sample.height, sample.n);
    let known_count: f64 = work.known.iter().map(|&k| k as f64).sum();
    if known_count == 0.0 {
        return Ok((rot, Vec::new()));
    }
    let constrained = !work.constraint.is_empty() && sample.mask.is_some();
    if constrained {
        sample.rotation_mask(rot);
    }
    sample.rotation(rot)?;
    let (maps, valid) = sample.rotated[rot].as_ref().expect("just loaded");
    let mask = if constrained {
        sample.rotated_mask[rot].as_deref()
    } else {
        None
    };
    let work_in = matching::Work {
        image: Image {
            width: work.width,
            height: work.height,
            channels: n,
            data: &work.features,
        },
        known: &work.known,
        constraint: mask.map(|_| Image {
            width: work.width,
            height: work.height,
            channels: 1,
            data: &work.constraint,
        }),
    };
    let sample_in = matching::Sample {
        image: Image {
            width: sw,
            height: sh,
            channels: n,
            data: maps,
        },
        valid,
        constraint: mask.map(|m| Image {
            width: sw,
            height: sh,
            channels: 1,
            data: m,
        }),
        key: rot as u64 | (constrained as u64) << 32,
    };
    let mc = MatchConfig {
        min_overlap: (0.5 * known_count).max(1.0),
        candidates: 64,
        tolerance: f64::INFINITY,
        constraint_weight,
        ..MatchConfig::default()
    };
    Ok((rot, matcher.match_patch(&work_in, &sample_in, &mc)?))
}

/// The outcome of a graphcut fitting.
struct Fit {
    /// Per patch vertex: take the new patch B? with its sample coordinate.
    take: Vec<bool>,
    coord: Vec<[f64; 2]>,
    /// m_P at B's coordinate per patch vertex (empty without a mask).
    new_mask: Vec<f32>,
    rotation: usize,
    jacobian: [f32; 4],
    seam_cost: f64,
    seam_edges: usize,
    taken: usize,
    taken_new_synth: usize,
    /// The min-cut's cost, and what keeping every old value would cost (the
    /// old seams inside the patch).
    flow: f64,
    baseline: f64,
}

const INFINITE: f64 = 1e30;

/// Graphcut between the old values A and the new patch B over the work
/// patch's vertices, with seam nodes on old seams (Kwatra et al. 2003, §3).
/// With `keep_outside_target` (region painting) texels where m0 = 0 keep
/// their old values, so a stroke changes nothing outside F and its
/// transition zone; synthesized texels less than `core` hops from the seed
/// must take the new values (seam refinement).
#[allow(clippy::too_many_arguments)]
fn fit_patch(
    sample: &Sample,
    state: &State,
    surface: &Surface,
    patch: &WorkPatch,
    work: &WorkImage,
    placement: &PlacementChoice,
    data_weight: f64,
    keep_outside_target: bool,
    core: u16,
) -> Fit {
    let n = state.n;
    let r = state.r;
    let m = patch.texels.len();
    let rotations = sample.rotated.len();
    let theta = placement.rotation as f64 * std::f64::consts::TAU / rotations as f64;
    let (s, c) = theta.sin_cos();
    let cen = [
        (sample.width as f64 - 1.0) / 2.0,
        (sample.height as f64 - 1.0) / 2.0,
    ];
    // B at every patch vertex: unrotated sample coordinate and value
    let mut coord = vec![[0f64; 2]; m];
    let mut valid = vec![false; m];
    let mut new_features = vec![0f32; m * n];
    for i in 0..m {
        let q = [
            work.coords[i][0] - placement.dx - cen[0],
            work.coords[i][1] - placement.dy - cen[1],
        ];
        let cc = [c * q[0] + s * q[1] + cen[0], -s * q[0] + c * q[1] + cen[1]];
        coord[i] = cc;
        valid[i] = sample.lookup(cc, &mut new_features[i * n..(i + 1) * n]);
    }
    // the Jacobian (sample offset per atlas +x / +y) for in-chart patches
    let j = work.atlas_to_work.map(|a| {
        [
            c * a[0] + s * a[2],
            -s * a[0] + c * a[2],
            c * a[1] + s * a[3],
            -s * a[1] + c * a[3],
        ]
    });
    let jacobian = j
        .map(|v| v.map(|x| x as f32))
        .unwrap_or([c as f32, -s as f32, s as f32, c as f32]);

    // nodes: one per patch vertex, plus seam nodes; Source = keep A, Sink = take B
    let mut g = Graph::new(m, m * 3);
    let mut take = vec![false; m];
    let mut order: Vec<(u32, u32)> = patch
        .texels
        .iter()
        .enumerate()
        .map(|(i, &t)| (t, i as u32))
        .collect();
    order.sort_unstable();
    let find = |t: u32| {
        order
            .binary_search_by_key(&t, |e| e.0)
            .ok()
            .map(|k| order[k].1 as usize)
    };
    let max_depth = patch.depth.iter().copied().max().unwrap_or(0);
    let mut new_mask = vec![0f32; if sample.mask.is_some() { m } else { 0 }];
    for i in 0..new_mask.len() {
        new_mask[i] = sample.mask_at(coord[i]);
    }
    for i in 0..m {
        let t = patch.texels[i];
        let synth = state.synthesized[t as usize];
        // the data term of constrained synthesis (§IV): D_p(σ) = |m_σ(p) −
        // m0(p)| on the t-links — keeping A costs D_p(A) (the sink edge is
        // cut), taking B costs D_p(B)
        if let (Some(m0), false, true) = (&state.target, new_mask.is_empty(), synth && valid[i]) {
            let d_a = (state.mask[t as usize] - m0[t as usize]).abs() as f64;
            let d_b = (new_mask[i] - m0[t as usize]).abs() as f64;
            g.add_tweights(i as u32, data_weight * d_b, data_weight * d_a);
        }
        let outside = keep_outside_target && state.target.as_ref().is_some_and(|m0| m0[t as usize] <= 0.0);
        if valid[i] && synth && patch.depth[i] < core {
            // refinement: the core around the seed takes the new patch
            g.add_tweights(i as u32, 0.0, INFINITE);
        } else if !valid[i] || (synth && outside) {
            // B cannot reach here, or region painting keeps everything
            // outside F and its transition zone: keep A (or stay
            // unsynthesized)
            g.add_tweights(i as u32, INFINITE, 0.0);
        } else if !synth {
            g.add_tweights(i as u32, 0.0, INFINITE);
        } else if patch.depth[i] == max_depth && max_depth > 0 {
            g.add_tweights(i as u32, INFINITE, 0.0);
        }
    }
    // the old values A at the patch's synthesized vertices
    let mut old_values = vec![0f32; m * n];
    for (i, &t) in patch.texels.iter().enumerate() {
        if state.synthesized[t as usize] {
            state.feature_into(sample, t, &mut old_values[i * n..(i + 1) * n]);
        }
    }
    let a_at = |i: usize| &old_values[i * n..(i + 1) * n];
    let b_at = |i: usize| &new_features[i * n..(i + 1) * n];
    // continue old patch at s one step (dx, dy in atlas texels) into t
    let old_continued = |s_t: u32, step: (f64, f64), out: &mut [f32]| -> bool {
        let jc = state.jacobian[s_t as usize];
        let cs = state.coord[s_t as usize];
        let cc = [
            cs[0] as f64 + jc[0] as f64 * step.0 + jc[2] as f64 * step.1,
            cs[1] as f64 + jc[1] as f64 * step.0 + jc[3] as f64 * step.1,
        ];
        sample.lookup(cc, out)
    };
    let mut tmp_a = vec![0f32; n];
    let mut tmp_b = vec![0f32; n];
    let mut edges: Vec<(usize, usize, f64)> = Vec::new();
    // the cost of the old seams inside the patch: what keeping every old
    // value would cost (refinement compares the cut with it)
    let mut baseline = 0.0;
    for i in 0..m {
        let t = patch.texels[i];
        let (x, y) = (t as usize % r, t as usize / r);
        let mut neighbours: Vec<(u32, Option<(f64, f64)>)> = Vec::with_capacity(4);
        if x + 1 < r && state.chart[t as usize + 1] == state.chart[t as usize] {
            neighbours.push((t + 1, Some((1.0, 0.0))));
        }
        if y + 1 < r && state.chart[t as usize + r] == state.chart[t as usize] {
            neighbours.push((t + r as u32, Some((0.0, 1.0))));
        }
        surface.graph.for_each_neighbour(t, |nb, zipper| {
            if zipper && nb > t {
                neighbours.push((nb, None));
            }
        });
        for (nb, step) in neighbours {
            let Some(k) = find(nb) else { continue };
            if !valid[i] || !valid[k] {
                continue;
            }
            let (si, sk) = (state.synthesized[t as usize], state.synthesized[nb as usize]);
            let d_s = if si { dist(a_at(i), b_at(i)) } else { 0.0 };
            let d_t = if sk { dist(a_at(k), b_at(k)) } else { 0.0 };
            let weight = match (si, sk) {
                (true, true) => d_s + d_t,
                (true, false) => 2.0 * d_s,
                (false, true) => 2.0 * d_t,
                (false, false) => 0.0,
            };
            let old_seam = si && sk && state.patch[t as usize] != state.patch[nb as usize];
            match (old_seam, step) {
                (true, Some(st)) => {
                    // seam node (Kwatra et al. 2003): s–n = M(A_s, B), n–t = M(A_t, B), n–sink = M(A_s, A_t)
                    let ok_a = old_continued(t, st, &mut tmp_a); // A_s at nb
                    let ok_b = old_continued(nb, (-st.0, -st.1), &mut tmp_b); // A_t at t
                    if ok_a && ok_b {
                        let m_s = dist(a_at(i), b_at(i)) + dist(&tmp_a, b_at(k));
                        let m_t = dist(&tmp_b, b_at(i)) + dist(a_at(k), b_at(k));
                        let old = dist(a_at(i), &tmp_b) + dist(&tmp_a, a_at(k));
                        baseline += old;
                        let node = g.add_node();
                        g.add_edge(i as u32, node, m_s, m_s);
                        g.add_edge(node, k as u32, m_t, m_t);
                        g.add_tweights(node, 0.0, old);
                        edges.push((i, k, weight));
                        continue;
                    }
                    g.add_edge(i as u32, k as u32, weight, weight);
                    edges.push((i, k, weight));
                }
                _ => {
                    g.add_edge(i as u32, k as u32, weight, weight);
                    edges.push((i, k, weight));
                }
            }
        }
    }
    let flow = g.maxflow();
    if std::env::var_os("BTFQUILT_TRACE").is_some() && !state.synthesized[patch.texels[0] as usize] {
        eprintln!(
            "seed valid {} segment {:?} coord {:?} work {:?}",
            valid[0],
            g.segment(0),
            coord[0],
            work.coords[0]
        );
    }
    let mut taken = 0;
    let mut taken_new_synth = 0;
    for i in 0..m {
        take[i] = valid[i] && g.segment(i as u32) == Segment::Sink;
        if take[i] {
            taken += 1;
            taken_new_synth += state.synthesized[patch.texels[i] as usize] as usize;
        }
    }
    // the seam: edges whose ends took different sides, both synthesized after
    let (mut seam_cost, mut seam_edges) = (0.0, 0usize);
    for &(i, k, w) in &edges {
        let ti = state.synthesized[patch.texels[i] as usize] || take[i];
        let tk = state.synthesized[patch.texels[k] as usize] || take[k];
        if take[i] != take[k] && ti && tk {
            seam_cost += w;
            seam_edges += 1;
        }
    }
    Fit {
        take,
        coord,
        new_mask,
        rotation: placement.rotation,
        jacobian,
        seam_cost,
        seam_edges,
        taken,
        taken_new_synth,
        flow,
        baseline,
    }
}

/// Records the vertices that took the new patch.
fn apply(
    state: &mut State,
    sample: &Sample,
    surface: &Surface,
    patch: &WorkPatch,
    fit: &Fit,
    id: u32,
    progress: &dyn Progress,
) {
    let mut newly = 0u64;
    for (i, &t) in patch.texels.iter().enumerate() {
        if !fit.take[i] {
            continue;
        }
        let tu = t as usize;
        state.coord[tu] = [fit.coord[i][0] as f32, fit.coord[i][1] as f32];
        state.jacobian[tu] = fit.jacobian;
        state.rotation[tu] = fit.rotation as u8;
        state.patch[tu] = id;
        state.source[tu] = state.active;
        state.foreign[tu] = NO_FOREIGN;
        if sample.mask.is_some() {
            state.mask[tu] = fit.new_mask[i];
        }
        if !state.synthesized[tu] {
            state.synthesized[tu] = true;
            state.remaining -= 1;
            newly += 1;
            let b = state.count[tu] as usize;
            state.buckets[b.min(15)].remove(&t);
            surface.graph.for_each_neighbour(t, |nb, _| {
                let nu = nb as usize;
                if !state.synthesized[nu] {
                    let old = (state.count[nu] as usize).min(15);
                    state.buckets[old].remove(&nb);
                    state.count[nu] = state.count[nu].saturating_add(1);
                    state.buckets[(state.count[nu] as usize).min(15)].insert(nb);
                }
            });
        }
    }
    // the Jacobian per taken texel from finite differences of the sample
    // coordinates over atlas neighbours of the same patch and chart (exact
    // for flattened patches, whose map to the sample varies per chart);
    // the patch-wide estimate where a texel has no such neighbour
    for (i, &t) in patch.texels.iter().enumerate() {
        if fit.take[i] {
            state.jacobian[t as usize] = local_jacobian(state, t, id).unwrap_or(fit.jacobian);
        }
    }
    progress.advance(newly);
}

/// Sample offset per atlas +x and +y step at `t`, from the coordinates of
/// its grid neighbours that belong to patch `id` in the same chart.
fn local_jacobian(state: &State, t: u32, id: u32) -> Option<[f32; 4]> {
    let r = state.r;
    let (x, y) = (t as usize % r, t as usize / r);
    let same = |nx: isize, ny: isize| -> Option<[f32; 2]> {
        if nx < 0 || ny < 0 || nx >= r as isize || ny >= r as isize {
            return None;
        }
        let n = ny as usize * r + nx as usize;
        (state.patch[n] == id && state.chart[n] == state.chart[t as usize]).then(|| state.coord[n])
    };
    let c = state.coord[t as usize];
    let axis = |dx: isize, dy: isize| -> Option<[f32; 2]> {
        let (x, y) = (x as isize, y as isize);
        match (same(x + dx, y + dy), same(x - dx, y - dy)) {
            (Some(a), Some(b)) => Some([(a[0] - b[0]) / 2.0, (a[1] - b[1]) / 2.0]),
            (Some(a), None) => Some([a[0] - c[0], a[1] - c[1]]),
            (None, Some(b)) => Some([c[0] - b[0], c[1] - b[1]]),
            (None, None) => None,
        }
    };
    let (ax, ay) = (axis(1, 0)?, axis(0, 1)?);
    Some([ax[0], ax[1], ay[0], ay[1]])
}

/// Writes the synthesis state as a `.quilt`; `paint_log` (a JSON array of
/// strokes) when the surface was painted.
fn write_quilt(
    out: &Path,
    cfg: &TileConfig,
    gim: &Gim,
    gim_path: &Path,
    syn: &Synthesis,
    paint_log: Option<&str>,
    report: &TileReport,
) -> Result<()> {
    let (sample, state) = (&syn.sample, &syn.state);
    let r = gim.resolution as u64;
    let t = TILE as u64;
    let mut w = ContainerWriter::create(out, KIND)?;
    w.set_level(cfg.level);
    w.set_seed(cfg.seed);
    record_dependency(&mut w, out, "gim", gim_path)?;
    let paths = &syn.sample_paths;
    record_dependency(&mut w, out, "sample", &paths[0])?;
    if paths.len() > 1 {
        w.set_param("sample_count", Param::Int(paths.len() as i64));
        for (k, p) in paths.iter().enumerate().skip(1) {
            record_dependency(&mut w, out, &format!("sample_{k}"), p)?;
        }
    }
    if let Some(mask) = &cfg.sample_mask {
        record_dependency(&mut w, out, "sample_mask", mask)?;
        if state.active > 0 {
            w.set_param("mask_sample", Param::Int(state.active as i64));
        }
    }
    if let Some(log) = paint_log {
        w.set_param("paint_log", Param::Text(log.to_string()));
    }
    w.set_param("resolution", Param::Int(r as i64));
    w.set_param("sample_width", Param::Int(sample.width as i64));
    w.set_param("sample_height", Param::Int(sample.height as i64));
    w.set_param("terms", Param::Int(sample.n as i64));
    w.set_param("rotations", Param::Int(sample.rotated.len() as i64));
    w.set_param("patches", Param::Int(state.next_patch as i64));
    w.set_param("mean_seam_cost", Param::Float(report.mean_seam_cost));
    let coord: Vec<f32> = state.coord.iter().flatten().copied().collect();
    let id = w.add_array(ArraySpec::new("coord", DType::F32, &[r, r, 2], &[t, t, 2])?)?;
    w.write_array(id, &coord)?;
    let jacobian: Vec<f32> = state.jacobian.iter().flatten().copied().collect();
    let id = w.add_array(ArraySpec::new("jacobian", DType::F32, &[r, r, 4], &[t, t, 4])?)?;
    w.write_array(id, &jacobian)?;
    let id = w.add_array(ArraySpec::new("rotation", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.rotation)?;
    let id = w.add_array(ArraySpec::new("patch", DType::U32, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.patch)?;
    if paths.len() > 1 {
        let id = w.add_array(ArraySpec::new("sample", DType::U8, &[r, r], &[t, t])?)?;
        w.write_array(id, &state.source)?;
    }
    let seams = seam_flags(&state.patch, &state.chart, gim.resolution, &gim.zipper_links()?);
    let id = w.add_array(ArraySpec::new("seam", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &seams)?;
    if let (Some(m0), Some(_)) = (&state.target, paint_log) {
        let id = w.add_array(ArraySpec::new("region", DType::F32, &[r, r], &[t, t])?)?;
        w.write_array(id, m0)?;
    }
    w.finish()
}

/// Records a file the quilt at `out` depends on under `role` (a parameter of
/// that name): its path relative to the quilt's folder (so the quilt and its
/// inputs can move together, and be read from any working directory), its
/// length (`ROLE_bytes`) and its content hash (an input of that name).
fn record_dependency(w: &mut ContainerWriter, out: &Path, role: &str, path: &Path) -> Result<()> {
    let (bytes, hash) = crate::container::file_identity(path)?;
    w.add_input(role, hash);
    w.set_param(
        role,
        Param::Text(crate::staging::relative_to_folder_of(out, path)),
    );
    w.set_param(&format!("{role}_bytes"), Param::Int(bytes as i64));
    Ok(())
}

/// One file a decorated surface depends on, as its quilt records it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Dependency {
    /// What it is: `gim`, `sample`, `sample_K` (painted in) or `sample_mask`.
    pub role: String,
    /// Where it is: the recorded path, resolved against the quilt's folder.
    pub path: PathBuf,
    /// Its recorded length in bytes.
    pub bytes: u64,
    /// Its recorded content hash ([`crate::container::file_identity`]).
    pub hash: u64,
}

impl Dependency {
    /// What the role means, for messages.
    fn what(&self) -> String {
        match self.role.as_str() {
            "gim" => "the geometry image".into(),
            "sample" => "the sample".into(),
            "sample_mask" => "the sample's foreground mask".into(),
            r => format!("the sample painted in as '{r}'"),
        }
    }
}

/// The seam flags of a texel ([`Quilt::seams`]): a seam to the +x
/// neighbour in the atlas.
pub const SEAM_X: u8 = 1;
/// A seam to the +y neighbour in the atlas.
pub const SEAM_Y: u8 = 2;
/// A seam across one of the texel's zipper links (to another chart).
pub const SEAM_ZIPPER: u8 = 4;

/// Per texel: which of its mesh edges the patches meet across (the seams
/// the graphcut left), as [`SEAM_X`] | [`SEAM_Y`] | [`SEAM_ZIPPER`].
fn seam_flags(patch: &[u32], chart: &[u32], r: usize, zipper_links: &[[u32; 2]]) -> Vec<u8> {
    let mut flags = vec![0u8; r * r];
    let seam = |a: usize, b: usize| chart[a] == chart[b] && chart[a] != EMPTY && patch[a] != patch[b];
    for y in 0..r {
        for x in 0..r {
            let t = y * r + x;
            if x + 1 < r && seam(t, t + 1) {
                flags[t] |= SEAM_X;
            }
            if y + 1 < r && seam(t, t + r) {
                flags[t] |= SEAM_Y;
            }
        }
    }
    for &[a, b] in zipper_links {
        let (a, b) = (a as usize, b as usize);
        if patch[a] != patch[b] {
            flags[a] |= SEAM_ZIPPER;
            flags[b] |= SEAM_ZIPPER;
        }
    }
    flags
}

/// A decorated surface opened for reading.
pub struct Quilt {
    container: Container,
    pub resolution: usize,
    pub gim: PathBuf,
    /// Every sample its texels draw from: the one it was tiled with first,
    /// then each other sample painted in (see [`Quilt::sample_index`]).
    pub samples: Vec<PathBuf>,
    /// The foreground mask of the last stroke's (or the tiling's) sample, if
    /// one was given.
    pub sample_mask: Option<PathBuf>,
    /// The files it depends on, with what they held when it was written.
    pub dependencies: Vec<Dependency>,
}

impl Quilt {
    /// Opens a `.quilt`.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<Quilt> {
        let container = Container::open_kind(path, KIND, budget)?;
        let m = container.metadata();
        let mut dependencies = Vec::new();
        let mut dependency = |role: &str| -> Result<PathBuf> {
            let Some(Param::Text(s)) = m.param(role) else {
                return Err(Error::input(
                    path,
                    format!("metadata parameter '{role}' is missing"),
                ));
            };
            let resolved = crate::staging::resolve_in_folder_of(path, Path::new(s));
            let bytes = match m.param(&format!("{role}_bytes")) {
                Some(Param::Int(b)) if *b >= 0 => *b as u64,
                _ => {
                    return Err(Error::input(
                        path,
                        format!(
                            "records no size and content hash for its {role} {}: it was written by an older btfquilt; tile it again",
                            resolved.display()
                        ),
                    ))
                }
            };
            let hash = m
                .inputs
                .iter()
                .find(|i| i.name == role)
                .map(|i| i.hash)
                .ok_or_else(|| Error::input(path, format!("records no content hash for its {role}")))?;
            dependencies.push(Dependency {
                role: role.to_string(),
                path: resolved.clone(),
                bytes,
                hash,
            });
            Ok(resolved)
        };
        let resolution = match m.param("resolution") {
            Some(Param::Int(v)) if *v > 0 => *v as usize,
            _ => return Err(Error::input(path, "metadata parameter 'resolution' is missing")),
        };
        // the arrays must match the resolution everything sizes itself by
        let why = format!("parameter 'resolution' is {resolution}");
        let r = resolution as u64;
        for (name, dtype, channels, required) in [
            ("coord", DType::F32, 2, true),
            ("jacobian", DType::F32, 4, false),
            ("rotation", DType::U8, 1, false),
            ("patch", DType::U32, 1, false),
            ("sample", DType::U8, 1, false),
            ("seam", DType::U8, 1, false),
            ("region", DType::F32, 1, false),
        ] {
            if required || container.array(name).is_ok() {
                let shape = if channels == 1 {
                    vec![r, r]
                } else {
                    vec![r, r, channels]
                };
                container.array_shaped(name, dtype, &shape, &why)?;
            }
        }
        if resolution > crate::gim::MAX_RESOLUTION {
            return Err(Error::input(
                path,
                format!(
                    "parameter 'resolution' is {resolution}, more than the {} an atlas may have",
                    crate::gim::MAX_RESOLUTION
                ),
            ));
        }
        let gim = dependency("gim")?;
        let sample = dependency("sample")?;
        let count = match m.param("sample_count") {
            None => 1,
            Some(Param::Int(v)) if (1..=MAX_SAMPLES as i64).contains(v) => *v as usize,
            Some(_) => {
                return Err(Error::input(
                    path,
                    "metadata parameter 'sample_count' is out of range",
                ))
            }
        };
        let mut samples = vec![sample];
        for k in 1..count {
            samples.push(dependency(&format!("sample_{k}"))?);
        }
        let sample_mask = match m.param("sample_mask") {
            Some(_) => Some(dependency("sample_mask")?),
            None => None,
        };
        Ok(Quilt {
            resolution,
            gim,
            samples,
            sample_mask,
            dependencies,
            container,
        })
    }

    /// The recorded dependency of `role`, if the quilt has one.
    pub fn dependency(&self, role: &str) -> Option<&Dependency> {
        self.dependencies.iter().find(|d| d.role == role)
    }

    /// Checks that the file at `at` (the recorded path, or one the user
    /// gave in its place) is the one the quilt was made from: same length,
    /// same content hash. The error names the quilt and the file.
    pub fn verify(&self, role: &str, at: &Path) -> Result<()> {
        let Some(d) = self.dependency(role) else {
            return Err(Error::input(
                self.container.path(),
                format!("has no '{role}' dependency"),
            ));
        };
        if !at.exists() {
            return Err(Error::input(
                self.container.path(),
                format!("{} {} is gone: put it back", d.what(), at.display()),
            ));
        }
        let (bytes, hash) = crate::container::file_identity(at)?;
        if (bytes, hash) != (d.bytes, d.hash) {
            return Err(Error::input(
                at,
                format!(
                    "is not {} that {} was made from (recorded {} bytes, content {:016x}; found {} bytes, content {:016x}): \
                     put the original back, or decorate again",
                    d.what(),
                    self.container.path().display(),
                    d.bytes,
                    d.hash,
                    bytes,
                    hash
                ),
            ));
        }
        Ok(())
    }

    /// Opens the geometry image (`at`, or the recorded one), after checking
    /// it is the one the quilt was made from.
    pub fn open_gim(&self, at: Option<&Path>, budget: MemoryBudget) -> Result<Gim> {
        let path = at.unwrap_or(&self.gim);
        self.verify("gim", path)?;
        Gim::open(path, budget)
    }

    /// Refuses `out` when it is the quilt or one of the files it depends on.
    pub fn check_output(&self, out: &Path) -> Result<()> {
        let files = self.input_files();
        let inputs: Vec<(&str, &Path)> = files.iter().map(|(r, p)| (r.as_str(), p.as_path())).collect();
        crate::staging::check_output(out, &inputs)
    }

    /// Every file the quilt depends on, with its role for messages: what an
    /// output must never overwrite.
    pub fn input_files(&self) -> Vec<(String, PathBuf)> {
        self.dependencies
            .iter()
            .map(|d| (d.what(), d.path.clone()))
            .chain(std::iter::once((
                "the decorated surface".to_string(),
                self.container.path().to_path_buf(),
            )))
            .collect()
    }

    /// The container underneath.
    pub fn container(&self) -> &Container {
        &self.container
    }

    /// Per texel sample coordinates (unrotated sample pixels).
    pub fn coords(&self) -> Result<Vec<[f32; 2]>> {
        let v: Vec<f32> = self.container.read_array(self.container.array("coord")?)?;
        Ok(v.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
    }

    /// Per texel patch ids ([`NO_PATCH`] where empty).
    pub fn patches(&self) -> Result<Vec<u32>> {
        self.container.read_array(self.container.array("patch")?)
    }

    /// Per texel sample offset per atlas step: `[dx/dX, dy/dX, dx/dY, dy/dY]`
    /// (sample pixels per atlas texel along +X, then along +Y; y down in
    /// both), the local frame that maps the sample onto the surface.
    pub fn jacobians(&self) -> Result<Vec<[f32; 4]>> {
        let v: Vec<f32> = self.container.read_array(self.container.array("jacobian")?)?;
        Ok(v.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect())
    }

    /// Per texel rotation index.
    pub fn rotations(&self) -> Result<Vec<u8>> {
        self.container.read_array(self.container.array("rotation")?)
    }

    /// Per texel seam flags ([`SEAM_X`], [`SEAM_Y`], [`SEAM_ZIPPER`]): where
    /// the patches meet.
    pub fn seams(&self) -> Result<Vec<u8>> {
        self.container.read_array(self.container.array("seam")?)
    }

    /// Per texel index into [`Quilt::samples`] (all 0 for a surface that
    /// draws from one sample, which stores no such array).
    pub fn sample_index(&self) -> Result<Vec<u8>> {
        let texels = self.resolution * self.resolution;
        let Ok(id) = self.container.array("sample") else {
            return Ok(vec![0; texels]);
        };
        let v: Vec<u8> = self.container.read_array(id)?;
        if v.len() != texels || v.iter().any(|&k| k as usize >= self.samples.len()) {
            return Err(Error::input(
                self.container.path(),
                format!(
                    "its sample indices do not match its {} samples",
                    self.samples.len()
                ),
            ));
        }
        Ok(v)
    }

    /// Which sample the recorded `sample_mask` belongs to (the last painted
    /// stroke's sample; 0 for a tiling).
    pub fn mask_sample(&self) -> usize {
        match self.container.metadata().param("mask_sample") {
            Some(Param::Int(v)) if *v >= 0 => *v as usize,
            _ => 0,
        }
    }
}

/// How many samples one surface may draw from (the tiling's and those
/// painted in), so a texel's sample index fits a byte.
pub const MAX_SAMPLES: usize = 255;
