//! Segmentation of a mesh into few large disk-shaped charts, each
//! parameterised by a least-squares conformal map (Lévy et al. 2002), or by
//! its as-rigid-as-possible relaxation (Liu et al. 2008) where the conformal
//! map is over a stretch limit.
//!
//! The segmentation grows charts from seed faces over the dual graph, by
//! geodesic distance penalised by normal deviation, with a normal-cone limit
//! (in the spirit of D-Charts, Julius et al. 2005, and the iso-charts of Zhou
//! et al. 2004), and moves the seeds to the chart centres for a few Lloyd
//! iterations. Every chart is then checked to be a topological disk, mapped
//! with LSCM, and split in two while it is not a disk, has a flipped triangle,
//! folds over itself in uv (two of its boundary edges cross, see
//! `src/atlas/overlap.rs`), or its texture stretch (Sander et al. 2001) or
//! area distortion exceeds its limit and the ARAP relaxation of its map
//! (`src/atlas/arap.rs`) does not bring it within them. Then, smallest first,
//! each chart is merged into one of its neighbours (longest shared border
//! first) when the union is a disk with a map that passes the same checks
//! and its faces stay within the normal cone of the union's mean normal; the
//! cone is waived for tiny charts (under 1% of their component's area). A
//! tiny chart no neighbour takes whole is then shared out among all its
//! neighbours, each face to the nearest one, when every grown neighbour
//! still maps (relaxed by ARAP if need be).
//! Finally chart borders are straightened once more (the spikes and notches
//! merging leaves), keeping only the moves after which every chart they
//! touch still passes.

use super::arap::{relax, ARAP_ITERATIONS};
use super::lscm::{local_frame, lscm, stretch};
use crate::mesh::{dunit_or, to_dvec3, Mesh, Topology, NO_FACE};
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

const NONE: u32 = u32::MAX;
/// Lloyd iterations (re-seeding at chart centres) of the segmentation.
const LLOYD_ITERATIONS: usize = 3;
/// Weight of the normal deviation (1 − cos) in the growth priority.
const NORMAL_PENALTY: f64 = 4.0;
/// Charts below this fraction of their component's area may merge into a
/// neighbour regardless of the normal cone (the stretch limit still holds).
const TINY_CHART: f64 = 0.01;
/// Cosine of the dihedral angle (30°) above which border straightening
/// treats an edge as a crease the border should keep.
const CREASE_COS: f64 = 0.866_025_403_784_438_6;
/// An ARAP-relaxed map is kept only while its L∞ stretch stays within this
/// share of [`ChartConfig::max_linf_stretch`]: relaxation trades angle for
/// area, and with the whole limit L∞ and the 99th-percentile stretch rose
/// on four of the ten shared meshes (docs/measurements.md, "Atlas").
const RELAXED_LINF_SHARE: f64 = 0.75;
/// Neighbours tried when merging a chart.
const MERGE_CANDIDATES: usize = 3;

/// Chart segmentation parameters.
#[derive(Clone, Debug)]
pub struct ChartConfig {
    /// Faces join a chart only while their normal stays within this angle of
    /// the chart's mean normal (degrees). Default 70.
    pub max_normal_deviation: f32,
    /// A chart whose L2 stretch exceeds this is split. Default 1.25.
    pub max_stretch: f32,
    /// A chart is split when more than 5 % of its area has its texel density
    /// off the chart's mean by more than this factor (LSCM is conformal, not
    /// equiareal, so a round chart shrinks towards its rim and the texture
    /// quilted into it grows there). Default 1.5.
    pub max_area_distortion: f32,
    /// A chart is split while one of its triangles stretches more than this
    /// in some direction (L∞, the largest singular value of its uv → 3D
    /// map at the chart's uniform density). Default 2.
    pub max_linf_stretch: f32,
    /// A more compact atlas: a chart over a stretch or area-distortion limit
    /// is relaxed (ARAP) before it is split, merges and the straightening
    /// after them use relaxed maps too, and the packer also tries eighth
    /// turns. Fewer charts and shorter seams; the atlas differs from the
    /// default one. Default off.
    pub compact: bool,
}

impl Default for ChartConfig {
    fn default() -> Self {
        ChartConfig {
            max_normal_deviation: 70.0,
            max_stretch: 1.25,
            max_area_distortion: 1.5,
            max_linf_stretch: 2.0,
            compact: false,
        }
    }
}

/// One chart: a disk of faces with its own vertex copies and a conformal
/// parameterisation.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Global face ids, ascending.
    pub faces: Vec<u32>,
    /// Local vertex -> global vertex id (ascending).
    pub vertices: Vec<u32>,
    /// Local vertex indices, same order as `faces`, same winding as the mesh.
    pub triangles: Vec<[u32; 3]>,
    /// Per local vertex, in surface units: scaled so the chart's uv area
    /// equals its 3D area (uniform density across charts), rotated so the
    /// chart's longest extent lies along u (the longer side of the
    /// minimum-area bounding rectangle; PCA if the hull is degenerate),
    /// translated so min u = min v = 0. Orientation is preserved: uv
    /// triangles are counter-clockwise.
    pub uv: Vec<[f32; 2]>,
    /// L2 texture stretch (Sander et al. 2001) at uniform density.
    pub l2_stretch: f32,
    /// L∞ texture stretch (largest singular value of uv → 3D).
    pub linf_stretch: f32,
}

/// Per-face geometry and the dual graph.
struct Ctx<'a> {
    mesh: &'a Mesh,
    adj: &'a [[u32; 3]],
    component: &'a [u32],
    component_area: Vec<f64>,
    normal: Vec<DVec3>,
    area: Vec<f64>,
    /// Dual edge length across edge i: centroid → edge midpoint → centroid.
    weight: Vec<[f64; 3]>,
    cos_max: f64,
    max_stretch: f64,
    max_area_distortion: f64,
    max_linf_stretch: f64,
    /// [`RELAXED_LINF_SHARE`] of `max_linf_stretch`.
    max_relaxed_linf: f64,
    /// [`ChartConfig::compact`].
    compact: bool,
}

/// Heap key for a non-negative finite f64 (bit order = numeric order).
fn key(x: f64) -> u64 {
    x.max(0.0).to_bits()
}

impl<'a> Ctx<'a> {
    fn new(mesh: &'a Mesh, topology: &'a Topology, cfg: &ChartConfig) -> Self {
        let nf = mesh.triangles.len();
        let mut normal = Vec::with_capacity(nf);
        let mut area = Vec::with_capacity(nf);
        let mut centroid = Vec::with_capacity(nf);
        for f in 0..nf {
            let c = mesh.corners(f).map(to_dvec3);
            let n = (c[1] - c[0]).cross(c[2] - c[0]);
            area.push(0.5 * n.length());
            normal.push(dunit_or(n, DVec3::ZERO));
            centroid.push((c[0] + c[1] + c[2]) / 3.0);
        }
        let mut weight = vec![[0.0; 3]; nf];
        for f in 0..nf {
            let t = mesh.triangles[f];
            for i in 0..3 {
                let g = topology.face_adjacency[f][i];
                if g == NO_FACE {
                    continue;
                }
                let a = to_dvec3(mesh.positions[t[i] as usize]);
                let b = to_dvec3(mesh.positions[t[(i + 1) % 3] as usize]);
                let m = (a + b) * 0.5;
                weight[f][i] = centroid[f].distance(m) + m.distance(centroid[g as usize]);
            }
        }
        let mut component_area = vec![0.0; topology.components];
        for (f, &c) in topology.face_component.iter().enumerate() {
            component_area[c as usize] += area[f];
        }
        Ctx {
            mesh,
            adj: &topology.face_adjacency,
            component: &topology.face_component,
            component_area,
            normal,
            area,
            weight,
            cos_max: (cfg.max_normal_deviation as f64).to_radians().cos(),
            max_stretch: cfg.max_stretch as f64,
            max_area_distortion: cfg.max_area_distortion as f64,
            max_linf_stretch: cfg.max_linf_stretch as f64,
            max_relaxed_linf: RELAXED_LINF_SHARE * cfg.max_linf_stretch as f64,
            compact: cfg.compact,
        }
    }
}

/// A set of faces with adjacency in local indices ([`NONE`] across the
/// patch border).
struct Patch {
    faces: Vec<u32>,
    adj: Vec<[u32; 3]>,
}

impl Patch {
    fn whole(ctx: &Ctx) -> Patch {
        let adj = ctx
            .adj
            .iter()
            .map(|a| a.map(|g| if g == NO_FACE { NONE } else { g }))
            .collect();
        Patch {
            faces: (0..ctx.adj.len() as u32).collect(),
            adj,
        }
    }

    /// `faces` must be sorted ascending.
    fn new(ctx: &Ctx, faces: Vec<u32>) -> Patch {
        let adj = faces
            .iter()
            .map(|&f| {
                ctx.adj[f as usize].map(|g| {
                    if g == NO_FACE {
                        NONE
                    } else {
                        faces.binary_search(&g).map_or(NONE, |i| i as u32)
                    }
                })
            })
            .collect();
        Patch { faces, adj }
    }

    fn len(&self) -> usize {
        self.faces.len()
    }

    fn weight(&self, ctx: &Ctx, f: u32, i: usize) -> f64 {
        ctx.weight[self.faces[f as usize] as usize][i]
    }

    /// Grows one region per seed simultaneously (Dijkstra over the dual graph
    /// with the priority geodesic distance × (1 + k (1 − n·N)), N the region's
    /// current mean normal). With a cone limit a face joins only if n·N ≥ cos
    /// of the limit; faces nobody can take stay [`NONE`].
    fn grow(&self, ctx: &Ctx, seeds: &[u32], cone: Option<f64>) -> Vec<u32> {
        let mut label = vec![NONE; self.len()];
        let mut sum = vec![DVec3::ZERO; seeds.len()];
        let mut mean = vec![DVec3::ZERO; seeds.len()];
        let mut heap = BinaryHeap::new();
        for (r, &s) in seeds.iter().enumerate() {
            heap.push(Reverse((0u64, s, r as u32, 0u64)));
        }
        while let Some(Reverse((_, f, r, d))) = heap.pop() {
            if label[f as usize] != NONE {
                continue;
            }
            let g = self.faces[f as usize] as usize;
            let n = ctx.normal[g];
            let ru = r as usize;
            if let Some(c) = cone {
                // faces without a normal (zero area) fit anywhere
                if sum[ru] != DVec3::ZERO && n != DVec3::ZERO && n.dot(mean[ru]) < c {
                    continue;
                }
            }
            label[f as usize] = r;
            let a = ctx.area[g].max(1e-300);
            sum[ru] += a * n;
            mean[ru] = dunit_or(sum[ru], DVec3::ZERO);
            let d = f64::from_bits(d);
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE || label[h as usize] != NONE {
                    continue;
                }
                let dh = d + self.weight(ctx, f, i);
                let nh = ctx.normal[self.faces[h as usize] as usize];
                let prio = dh * (1.0 + NORMAL_PENALTY * (1.0 - nh.dot(mean[ru])));
                heap.push(Reverse((key(prio), h, r, dh.to_bits())));
            }
        }
        label
    }

    /// Connected components of equal-label faces: (component per face,
    /// count), components numbered in order of their smallest face.
    fn components(&self, label: &[u32]) -> (Vec<u32>, usize) {
        let mut comp = vec![NONE; self.len()];
        let mut count = 0u32;
        let mut stack = Vec::new();
        for s in 0..self.len() {
            if comp[s] != NONE {
                continue;
            }
            comp[s] = count;
            stack.push(s as u32);
            while let Some(f) = stack.pop() {
                for &h in &self.adj[f as usize] {
                    if h != NONE && comp[h as usize] == NONE && label[h as usize] == label[f as usize] {
                        comp[h as usize] = count;
                        stack.push(h);
                    }
                }
            }
            count += 1;
        }
        (comp, count as usize)
    }

    /// For every connected component of equal-label faces, the face farthest
    /// (dual geodesic distance) from the component's border, or its first
    /// face if it has no border. Returns (label, face) in component order.
    fn centres(&self, ctx: &Ctx, label: &[u32]) -> Vec<(u32, u32)> {
        let (comp, count) = self.components(label);
        let mut d = vec![f64::INFINITY; self.len()];
        let mut heap = BinaryHeap::new();
        for f in 0..self.len() {
            for i in 0..3 {
                let h = self.adj[f][i];
                if h == NONE || label[h as usize] != label[f] {
                    // half the dual edge: distance to the border edge
                    let w = if h == NONE {
                        0.0
                    } else {
                        0.5 * self.weight(ctx, f as u32, i)
                    };
                    if w < d[f] {
                        d[f] = w;
                    }
                }
            }
            if d[f].is_finite() {
                heap.push(Reverse((key(d[f]), f as u32)));
            }
        }
        while let Some(Reverse((k, f))) = heap.pop() {
            if k != key(d[f as usize]) {
                continue;
            }
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE || label[h as usize] != label[f as usize] {
                    continue;
                }
                let dh = d[f as usize] + self.weight(ctx, f, i);
                if dh < d[h as usize] {
                    d[h as usize] = dh;
                    heap.push(Reverse((key(dh), h)));
                }
            }
        }
        let mut best: Vec<Option<(f64, u32)>> = vec![None; count];
        for f in 0..self.len() {
            let c = comp[f] as usize;
            let df = if d[f].is_finite() { d[f] } else { -1.0 };
            if best[c].map_or(true, |(bd, _)| df > bd) {
                best[c] = Some((df, f as u32));
            }
        }
        best.into_iter()
            .map(|b| b.expect("component has a face").1)
            .map(|f| (label[f as usize], f))
            .collect()
    }

    /// The face farthest from `s` (dual geodesic distance within the patch).
    fn farthest_from(&self, ctx: &Ctx, s: u32) -> u32 {
        let mut d = vec![f64::INFINITY; self.len()];
        d[s as usize] = 0.0;
        let mut heap = BinaryHeap::new();
        heap.push(Reverse((0u64, s)));
        let mut far = (0.0, s);
        while let Some(Reverse((k, f))) = heap.pop() {
            let df = d[f as usize];
            if k != key(df) {
                continue;
            }
            if df > far.0 {
                far = (df, f);
            }
            for i in 0..3 {
                let h = self.adj[f as usize][i];
                if h == NONE {
                    continue;
                }
                let dh = df + self.weight(ctx, f, i);
                if dh < d[h as usize] {
                    d[h as usize] = dh;
                    heap.push(Reverse((key(dh), h)));
                }
            }
        }
        far.1
    }

    /// Whether the patch is a topological disk: connected, every vertex on
    /// at most one border fan (no pinch), and Euler characteristic 1.
    fn is_disk(&self, ctx: &Ctx) -> bool {
        let (_, count) = self.components(&vec![0; self.len()]);
        if count != 1 {
            return false;
        }
        let mut verts: Vec<u32> = Vec::with_capacity(self.len() * 3);
        let mut border: Vec<u32> = Vec::new();
        let mut interior_half = 0usize;
        for (f, &g) in self.faces.iter().enumerate() {
            let t = ctx.mesh.triangles[g as usize];
            verts.extend_from_slice(&t);
            for i in 0..3 {
                if self.adj[f][i] == NONE {
                    border.push(t[i]);
                    border.push(t[(i + 1) % 3]);
                } else {
                    interior_half += 1;
                }
            }
        }
        if border.is_empty() {
            return false;
        }
        verts.sort_unstable();
        verts.dedup();
        border.sort_unstable();
        // a vertex on more than two border edges is a pinch
        if border.windows(3).any(|w| w[0] == w[2]) {
            return false;
        }
        let e = interior_half / 2 + border.len() / 2;
        verts.len() as i64 - e as i64 + self.len() as i64 == 1
    }

    /// Straightens the borders between the labels of the patch's faces: a
    /// face that meets its own region along at most one edge (the tip of a
    /// one-face-wide spike, a notch of a saw-toothed border, a lone face)
    /// moves to a region it meets along two edges, or, the tip of a spike
    /// between two regions, once to the one its normal is closer to — never
    /// across a crease (see [`CREASE_COS`]). A face meeting its own region
    /// along one edge is a leaf of it, so no region comes apart, and a
    /// region keeps its last face; each move to a region met along two
    /// edges shortens the border, so the sweeps end.
    fn straighten(&self, ctx: &Ctx, label: &mut [u32]) {
        let mut tipped = vec![false; label.len()];
        // faces per label: a region's last face stays (a split stays a split)
        let labels = label
            .iter()
            .filter(|&&l| l != NONE)
            .max()
            .map_or(0, |&l| l as usize + 1);
        let mut count = vec![0usize; labels];
        for &l in label.iter().filter(|&&l| l != NONE) {
            count[l as usize] += 1;
        }
        loop {
            let mut moved = false;
            for f in 0..label.len() {
                let own = label[f];
                if own == NONE || count[own as usize] == 1 {
                    continue;
                }
                let mut others = [NONE; 3];
                let mut same = 0;
                for (i, &g) in self.adj[f].iter().enumerate() {
                    if g == NONE || label[g as usize] == NONE {
                        continue;
                    }
                    let l = label[g as usize];
                    if l == own {
                        same += 1;
                    } else {
                        others[i] = l;
                    }
                }
                if same > 1 {
                    continue;
                }
                // the least bend (cosine) from this face to a neighbour in `l`
                let normal = |f: u32| ctx.normal[self.faces[f as usize] as usize];
                let n = normal(f as u32);
                let bend = |l: u32| {
                    self.adj[f]
                        .iter()
                        .filter(|&&g| g != NONE && label[g as usize] == l)
                        .map(|&g| n.dot(normal(g)))
                        .fold(f64::INFINITY, f64::min)
                };
                let met = |l: u32| others.iter().filter(|&&m| m == l).count();
                let to = match others.iter().copied().find(|&l| l != NONE && met(l) >= 2) {
                    Some(l) => l,
                    None if same == 1 && !tipped[f] && others.iter().filter(|&&l| l != NONE).count() == 2 => {
                        // a spike's tip between two regions
                        let mut two = others.iter().copied().filter(|&l| l != NONE);
                        let (a, b) = (two.next().unwrap_or(NONE), two.next().unwrap_or(NONE));
                        tipped[f] = true;
                        if bend(b) > bend(a) {
                            b
                        } else {
                            a
                        }
                    }
                    None => continue,
                };
                // not across a crease: the face bends by less than
                // CREASE towards the region, or no more than towards its own
                if same == 0 || bend(to) >= CREASE_COS.min(bend(own)) {
                    count[own as usize] -= 1;
                    count[to as usize] += 1;
                    label[f] = to;
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
    }

    /// Splits the patch in two by growing from the two faces farthest apart.
    fn split_in_two(&self, ctx: &Ctx) -> Vec<Vec<u32>> {
        let a = self.farthest_from(ctx, 0);
        let mut b = self.farthest_from(ctx, a);
        if b == a {
            b = if a == 0 { 1 } else { 0 };
        }
        let mut label = self.grow(ctx, &[a, b], None);
        self.straighten(ctx, &mut label);
        let mut parts = vec![Vec::new(), Vec::new()];
        let mut rest = Vec::new();
        for (f, &l) in label.iter().enumerate() {
            match l {
                0 | 1 => parts[l as usize].push(self.faces[f]),
                _ => rest.push(self.faces[f]), // unreachable from both seeds
            }
        }
        if !rest.is_empty() {
            parts.push(rest);
        }
        parts
    }

    /// Faces grouped by component, in global ids.
    fn split_components(&self) -> Vec<Vec<u32>> {
        let (comp, count) = self.components(&vec![0; self.len()]);
        let mut parts = vec![Vec::new(); count];
        for (f, &c) in comp.iter().enumerate() {
            parts[c as usize].push(self.faces[f]);
        }
        parts
    }
}

/// Initial segmentation of the whole mesh into connected regions (face
/// lists, ascending): grow from one seed per component, seed every area left
/// uncovered by the normal cone at its centre and regrow, then
/// [`LLOYD_ITERATIONS`] times move each seed to its region's centre.
fn segment(ctx: &Ctx) -> Vec<Vec<u32>> {
    let whole = Patch::whole(ctx);
    let nf = whole.len();
    // one seed per mesh component, at its centre
    let mut seeds: Vec<u32> = whole
        .centres(ctx, &vec![0; nf])
        .into_iter()
        .map(|(_, f)| f)
        .collect();
    let mut label;
    let mut iteration = 0;
    loop {
        loop {
            label = whole.grow(ctx, &seeds, Some(ctx.cos_max));
            if !label.contains(&NONE) {
                break;
            }
            // a new seed at the centre of every uncovered area
            seeds.extend(
                whole
                    .centres(ctx, &label)
                    .into_iter()
                    .filter(|&(l, _)| l == NONE)
                    .map(|(_, f)| f),
            );
        }
        if iteration == LLOYD_ITERATIONS {
            break;
        }
        iteration += 1;
        let mut centres = whole.centres(ctx, &label);
        centres.sort_unstable();
        seeds = centres.into_iter().map(|(_, f)| f).collect();
    }
    whole.straighten(ctx, &mut label);
    let mut regions = vec![Vec::new(); seeds.len()];
    for (f, &l) in label.iter().enumerate() {
        regions[l as usize].push(f as u32);
    }
    regions.retain(|r| !r.is_empty());
    regions
}

/// LSCM of a set of faces (sorted), or for a compact atlas its ARAP
/// relaxation when LSCM is over a stretch limit (the relaxed map within
/// [`RELAXED_LINF_SHARE`] of the L∞ limit), normalised to uniform density
/// and oriented; `None` if a triangle flips, the map folds over itself (two
/// boundary edges cross) or both maps are over a limit.
fn parameterize(ctx: &Ctx, faces: &[u32]) -> Option<Chart> {
    parameterize_relaxing(ctx, faces, ctx.compact)
}

/// [`parameterize`], relaxing a stretched conformal map (ARAP) when
/// `relax_stretched`.
fn parameterize_relaxing(ctx: &Ctx, faces: &[u32], relax_stretched: bool) -> Option<Chart> {
    let mesh = ctx.mesh;
    let mut vertices: Vec<u32> = faces.iter().flat_map(|&f| mesh.triangles[f as usize]).collect();
    vertices.sort_unstable();
    vertices.dedup();
    let local = |v: u32| vertices.binary_search(&v).expect("vertex of the chart") as u32;
    let triangles: Vec<[u32; 3]> = faces
        .iter()
        .map(|&f| mesh.triangles[f as usize].map(local))
        .collect();
    let positions: Vec<[f32; 3]> = vertices.iter().map(|&v| mesh.positions[v as usize]).collect();
    let uv = if faces.len() == 1 {
        // local vertices are sorted by global id; triangle corners may not be
        let mut uv = vec![[0.0; 2]; 3];
        let (q, _) = local_frame(triangles[0].map(|v| to_dvec3(positions[v as usize])));
        for (k, &v) in triangles[0].iter().enumerate() {
            uv[v as usize] = q[k];
        }
        uv
    } else {
        let conformal = lscm(&positions, &triangles).ok()?;
        // no flip and no fold, or the chart is split; within the stretch
        // limits, or the ARAP relaxation of the conformal map must be
        match acceptable(
            ctx,
            faces,
            &positions,
            &triangles,
            &conformal,
            ctx.max_linf_stretch,
        ) {
            Some(Check::Within) => conformal,
            Some(Check::Stretched) if relax_stretched => {
                let relaxed = relax(&positions, &triangles, &conformal, ARAP_ITERATIONS)?;
                match acceptable(ctx, faces, &positions, &triangles, &relaxed, ctx.max_relaxed_linf) {
                    Some(Check::Within) => relaxed,
                    _ => return None,
                }
            }
            Some(Check::Stretched) | None => return None,
        }
    };
    let (l2, linf) = stretch(&positions, &triangles, &uv);
    let uv = normalize_uv(&positions, &triangles, &uv);
    Some(Chart {
        faces: faces.to_vec(),
        vertices,
        triangles,
        uv,
        l2_stretch: l2 as f32,
        linf_stretch: linf as f32,
    })
}

enum Check {
    /// No flip, no fold, within every stretch limit.
    Within,
    /// No flip and no fold, but over a stretch or area-distortion limit.
    Stretched,
}

/// Judges a map of several faces against the chart limits, with `max_linf`
/// for its L∞ stretch: `None` if a triangle flips or the map folds over
/// itself (two boundary edges cross).
fn acceptable(
    ctx: &Ctx,
    faces: &[u32],
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: &[[f64; 2]],
    max_linf: f64,
) -> Option<Check> {
    for (&f, t) in faces.iter().zip(triangles) {
        let (a, b, c) = (uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]);
        let s = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        if !(s > 0.0 || ctx.area[f as usize] == 0.0) {
            return None;
        }
    }
    if super::overlap::boundary_crosses(uv, triangles) {
        return None;
    }
    let (l2, linf) = stretch(positions, triangles, uv);
    if l2.is_nan()
        || l2 > ctx.max_stretch
        || linf > max_linf
        || area_distortion_tail(positions, triangles, uv) > ctx.max_area_distortion
    {
        return Some(Check::Stretched);
    }
    Some(Check::Within)
}

/// A chart is split when more than this fraction of its area is off its
/// mean texel density by more than [`ChartConfig::max_area_distortion`].
const AREA_DISTORTION_SHARE: f64 = 0.05;

/// The chart's area distortion at the [`AREA_DISTORTION_SHARE`] tail: the
/// area-weighted (1 − share)-quantile of max(r, 1/r), r a triangle's
/// uv-to-3D area ratio over the chart's.
fn area_distortion_tail(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> f64 {
    super::lscm::area_distortion_quantile(positions, triangles, uv, 1.0 - AREA_DISTORTION_SHARE)
}

/// Scales uv to the 3D area, rotates the longer side of the minimum-area
/// bounding rectangle onto u, and moves the minimum to the origin.
fn normalize_uv(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> Vec<[f32; 2]> {
    let mut a3 = 0.0;
    let mut auv = 0.0;
    for t in triangles {
        let (_, a) = local_frame(t.map(|v| to_dvec3(positions[v as usize])));
        a3 += a;
        let (p, q, r) = (uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]);
        auv += 0.5 * ((q[0] - p[0]) * (r[1] - p[1]) - (r[0] - p[0]) * (q[1] - p[1])).abs();
    }
    let s = if a3 > 0.0 && auv > 0.0 {
        (a3 / auv).sqrt()
    } else {
        1.0
    };
    let n = uv.len() as f64;
    let mean = uv
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (sin, cos) = orientation(uv).sin_cos();
    let rotated: Vec<[f64; 2]> = uv
        .iter()
        .map(|p| {
            let (x, y) = ((p[0] - mean[0]) * s, (p[1] - mean[1]) * s);
            [cos * x + sin * y, -sin * x + cos * y]
        })
        .collect();
    let lo = rotated
        .iter()
        .fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
    rotated
        .iter()
        .map(|p| [(p[0] - lo[0]) as f32, (p[1] - lo[1]) as f32])
        .collect()
}

/// Whether all faces lie within the normal cone around their area-weighted
/// mean normal.
fn within_cone(ctx: &Ctx, faces: &[u32]) -> bool {
    let mut sum = DVec3::ZERO;
    for &f in faces {
        let (n, a) = (ctx.normal[f as usize], ctx.area[f as usize]);
        sum += a * n;
    }
    let mean = dunit_or(sum, DVec3::ZERO);
    faces.iter().all(|&f| {
        let n = ctx.normal[f as usize];
        n == DVec3::ZERO || n.dot(mean) >= ctx.cos_max
    })
}

/// Angle of the direction to rotate onto +u: the longer side of the
/// minimum-area bounding rectangle (one side lies on a convex-hull edge), or
/// the principal axis (PCA) when the hull is degenerate.
fn orientation(uv: &[[f64; 2]]) -> f64 {
    let mut pts: Vec<[f64; 2]> = uv.to_vec();
    pts.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup();
    let cross =
        |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    // Andrew's monotone chain
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(pts.len() + 1);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    let mut best: Option<(f64, f64)> = None; // (area, angle)
    if hull.len() >= 3 {
        for i in 0..hull.len() {
            let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
            let d = [b[0] - a[0], b[1] - a[1]];
            let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if l <= 0.0 {
                continue;
            }
            let (ux, uy) = (d[0] / l, d[1] / l);
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for p in &hull {
                let (x, y) = (p[0] * ux + p[1] * uy, -p[0] * uy + p[1] * ux);
                lo = [lo[0].min(x), lo[1].min(y)];
                hi = [hi[0].max(x), hi[1].max(y)];
            }
            let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
            let area = w * h;
            let mut angle = uy.atan2(ux);
            if h > w {
                angle += std::f64::consts::FRAC_PI_2;
            }
            if best.map_or(true, |(a, _)| area < a * (1.0 - 1e-9)) {
                best = Some((area, angle));
            }
        }
    }
    if let Some((_, angle)) = best {
        return angle;
    }
    let n = uv.len() as f64;
    let mean = uv
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in uv {
        let (x, y) = (p[0] - mean[0], p[1] - mean[1]);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    0.5 * (2.0 * sxy).atan2(sxx - syy)
}

enum Outcome {
    Done(Chart),
    Split(Vec<Vec<u32>>),
}

/// Checks and parameterises one region, or says how to split it.
fn evaluate(ctx: &Ctx, faces: &[u32]) -> Outcome {
    if faces.len() == 1 {
        return Outcome::Done(parameterize(ctx, faces).expect("a single triangle always maps"));
    }
    let patch = Patch::new(ctx, faces.to_vec());
    let parts = patch.split_components();
    if parts.len() > 1 {
        return Outcome::Split(parts);
    }
    if patch.is_disk(ctx) {
        if let Some(chart) = parameterize(ctx, faces) {
            return Outcome::Done(chart);
        }
    }
    Outcome::Split(patch.split_in_two(ctx))
}

/// Maps every region, splitting those that fail [`evaluate`]'s checks until
/// all parts map.
fn split_until_mapped(ctx: &Ctx, mut pending: Vec<Vec<u32>>) -> Vec<Chart> {
    let mut charts = Vec::new();
    while !pending.is_empty() {
        let outcomes: Vec<Outcome> = pending.par_iter().map(|faces| evaluate(ctx, faces)).collect();
        pending = Vec::new();
        for o in outcomes {
            match o {
                Outcome::Done(c) => charts.push(c),
                Outcome::Split(parts) => pending.extend(parts),
            }
        }
    }
    charts
}

/// Per face, the index of the chart holding it.
fn owners(ctx: &Ctx, charts: &[Chart]) -> Vec<u32> {
    let mut owner = vec![NONE; ctx.adj.len()];
    for (c, chart) in charts.iter().enumerate() {
        for &f in &chart.faces {
            owner[f as usize] = c as u32;
        }
    }
    owner
}

/// Merges charts into neighbours, smallest first, while the union stays a
/// disk that [`parameterize`] maps and within the normal cone (waived for
/// tiny charts).
fn merge(ctx: &Ctx, mut charts: Vec<Chart>) -> Vec<Chart> {
    let mut owner = owners(ctx, &charts);
    let area = |chart: &Chart| chart.faces.iter().map(|&f| ctx.area[f as usize]).sum::<f64>();
    let is_tiny = |chart: &Chart| {
        let component = ctx.component[chart.faces[0] as usize] as usize;
        area(chart) < TINY_CHART * ctx.component_area[component]
    };
    let mut order: Vec<(f64, u32, usize)> = charts
        .iter()
        .enumerate()
        .map(|(c, ch)| (area(ch), ch.faces[0], c))
        .collect();
    order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut alive = vec![true; charts.len()];
    for &(_, _, c) in &order {
        let tiny = is_tiny(&charts[c]);
        let mut shared: Vec<(u32, u32)> = Vec::new(); // (neighbour, shared edges)
        for &f in &charts[c].faces {
            for &g in &ctx.adj[f as usize] {
                if g != NO_FACE && owner[g as usize] != c as u32 {
                    let o = owner[g as usize];
                    match shared.iter_mut().find(|s| s.0 == o) {
                        Some(s) => s.1 += 1,
                        None => shared.push((o, 1)),
                    }
                }
            }
        }
        shared.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        shared.truncate(MERGE_CANDIDATES);
        let tries: Vec<Option<Chart>> = shared
            .par_iter()
            .map(|&(n, _)| {
                let mut faces = charts[c].faces.clone();
                faces.extend_from_slice(&charts[n as usize].faces);
                faces.sort_unstable();
                if !tiny && !within_cone(ctx, &faces) {
                    return None;
                }
                map_disk(ctx, faces, ctx.compact)
            })
            .collect();
        if let Some((k, merged)) = tries.into_iter().enumerate().find_map(|(k, t)| t.map(|m| (k, m))) {
            let n = shared[k].0 as usize;
            for &f in &charts[c].faces {
                owner[f as usize] = n as u32;
            }
            charts[n] = merged;
            charts[c].faces.clear();
            alive[c] = false;
        }
    }
    // tiny charts no neighbour takes whole are shared out among them
    for &(_, _, c) in &order {
        if charts[c].faces.is_empty() || !is_tiny(&charts[c]) {
            continue;
        }
        if let Some(grown) = dissolve(ctx, &charts, &owner, c) {
            for (n, chart) in grown {
                for &f in &chart.faces {
                    owner[f as usize] = n as u32;
                }
                charts[n] = chart;
            }
            charts[c].faces.clear();
            alive[c] = false;
        }
    }
    charts
        .into_iter()
        .zip(alive)
        .filter(|(_, a)| *a)
        .map(|(c, _)| c)
        .collect()
}

/// The chart of `faces` (ascending) if they form one topological disk
/// ([`Patch::is_disk`]: connected, no pinch, Euler characteristic 1) that
/// [`parameterize_relaxing`] maps.
fn map_disk(ctx: &Ctx, faces: Vec<u32>, relax_stretched: bool) -> Option<Chart> {
    let patch = Patch::new(ctx, faces);
    if !patch.is_disk(ctx) {
        return None;
    }
    parameterize_relaxing(ctx, &patch.faces, relax_stretched)
}

/// Shares a tiny chart that merges whole into none of its neighbours out
/// among all of them: each face goes to the neighbour nearest over the dual
/// graph (Dijkstra from the chart's border), and the share is kept only if
/// every neighbour that grows stays a disk that maps within the limits, its
/// conformal map relaxed by ARAP where it is over one. Returns the grown
/// neighbours, in ascending id.
fn dissolve(ctx: &Ctx, charts: &[Chart], owner: &[u32], c: usize) -> Option<Vec<(usize, Chart)>> {
    let faces = &charts[c].faces;
    let local = |g: u32| faces.binary_search(&g).ok();
    let mut label = vec![NONE; faces.len()];
    let mut heap = BinaryHeap::new();
    for (i, &f) in faces.iter().enumerate() {
        for (e, &g) in ctx.adj[f as usize].iter().enumerate() {
            if g != NO_FACE && owner[g as usize] != c as u32 {
                let d = ctx.weight[f as usize][e];
                heap.push(Reverse((key(d), owner[g as usize], i as u32, d.to_bits())));
            }
        }
    }
    while let Some(Reverse((_, n, i, d))) = heap.pop() {
        if label[i as usize] != NONE {
            continue;
        }
        label[i as usize] = n;
        let f = faces[i as usize] as usize;
        for (e, &g) in ctx.adj[f].iter().enumerate() {
            if let Some(j) = (g != NO_FACE).then(|| local(g)).flatten() {
                if label[j] == NONE {
                    let dj = f64::from_bits(d) + ctx.weight[f][e];
                    heap.push(Reverse((key(dj), n, j as u32, dj.to_bits())));
                }
            }
        }
    }
    if label.contains(&NONE) {
        return None; // a closed chart with no neighbour
    }
    let mut grown: Vec<usize> = label.iter().map(|&n| n as usize).collect();
    grown.sort_unstable();
    grown.dedup();
    let mapped: Vec<Option<Chart>> = grown
        .par_iter()
        .map(|&n| {
            let mut union = charts[n].faces.clone();
            union.extend(
                faces
                    .iter()
                    .zip(&label)
                    .filter(|(_, &l)| l as usize == n)
                    .map(|(&f, _)| f),
            );
            union.sort_unstable();
            map_disk(ctx, union, true)
        })
        .collect();
    grown
        .into_iter()
        .zip(mapped)
        .map(|(n, m)| m.map(|m| (n, m)))
        .collect()
}

/// Straightens chart borders once more after merging (a merged tiny chart
/// often leaves a spike or a notch): the moves of [`Patch::straighten`] over
/// all charts, kept where every chart they touch stays one disk that maps
/// within the limits; moves touching a chart that does not are undone, and
/// the charts they touch checked again.
fn straighten_charts(ctx: &Ctx, mut charts: Vec<Chart>) -> Vec<Chart> {
    let before = owners(ctx, &charts);
    let mut label = before.clone();
    Patch::whole(ctx).straighten(ctx, &mut label);
    loop {
        let mut changed = vec![false; charts.len()];
        for (&now, &was) in label.iter().zip(&before) {
            if now != was {
                changed[now as usize] = true;
                changed[was as usize] = true;
            }
        }
        let ids: Vec<usize> = (0..charts.len()).filter(|&c| changed[c]).collect();
        if ids.is_empty() {
            return charts;
        }
        let mut faces = vec![Vec::new(); charts.len()];
        for (f, &l) in label.iter().enumerate() {
            if changed[l as usize] {
                faces[l as usize].push(f as u32);
            }
        }
        let remapped: Vec<Option<Chart>> = ids
            .par_iter()
            .map(|&c| map_disk(ctx, faces[c].clone(), ctx.compact))
            .collect();
        if remapped.iter().all(Option::is_some) {
            for (&c, chart) in ids.iter().zip(remapped) {
                charts[c] = chart.expect("checked");
            }
            return charts;
        }
        let mut failed = vec![false; charts.len()];
        for (&c, chart) in ids.iter().zip(&remapped) {
            failed[c] = chart.is_none();
        }
        for (now, &was) in label.iter_mut().zip(&before) {
            if failed[*now as usize] || failed[was as usize] {
                *now = was;
            }
        }
    }
}

/// Segments the surface into few large disk-shaped charts and parameterises
/// each with LSCM (Lévy et al. 2002), relaxed by ARAP where needed; see the
/// module documentation. Every face is in exactly one chart; a closed
/// component yields at least two charts.
/// Deterministic (independent of thread count); charts are ordered by their
/// first face.
pub fn build_charts(mesh: &Mesh, topology: &Topology, cfg: &ChartConfig) -> Result<Vec<Chart>> {
    let nf = mesh.triangles.len();
    if topology.face_adjacency.len() != nf
        || topology.face_component.len() != nf
        || topology
            .face_component
            .iter()
            .any(|&c| c as usize >= topology.components)
    {
        return Err(Error::Config(format!(
            "build_charts: topology has {} faces, mesh {nf}",
            topology.face_adjacency.len()
        )));
    }
    if topology
        .face_adjacency
        .iter()
        .flatten()
        .any(|&g| g != NO_FACE && g as usize >= nf)
    {
        return Err(Error::Config(
            "build_charts: face adjacency names a face past the mesh".into(),
        ));
    }
    if mesh.positions.iter().flatten().any(|c| !c.is_finite()) {
        return Err(Error::Config("build_charts: non-finite vertex position".into()));
    }
    if mesh
        .triangles
        .iter()
        .flatten()
        .any(|&v| v as usize >= mesh.positions.len())
    {
        return Err(Error::Config(
            "build_charts: a triangle indexes past the vertex list".into(),
        ));
    }
    if mesh
        .triangles
        .iter()
        .any(|t| t[0] == t[1] || t[1] == t[2] || t[2] == t[0])
    {
        return Err(Error::Config("build_charts: a triangle repeats a vertex".into()));
    }
    if !(cfg.max_normal_deviation > 0.0 && cfg.max_normal_deviation <= 180.0) {
        return Err(Error::Config(format!(
            "max_normal_deviation must be in (0, 180] degrees, got {}",
            cfg.max_normal_deviation
        )));
    }
    if !(cfg.max_stretch.is_finite() && cfg.max_stretch >= 1.0) {
        return Err(Error::Config(format!(
            "--max-stretch {}: must be a finite number ≥ 1",
            cfg.max_stretch
        )));
    }
    if !(cfg.max_area_distortion.is_finite() && cfg.max_area_distortion >= 1.0) {
        return Err(Error::Config(format!(
            "--max-area-distortion {}: must be a finite number ≥ 1",
            cfg.max_area_distortion
        )));
    }
    if !(cfg.max_linf_stretch.is_finite() && cfg.max_linf_stretch >= 1.0) {
        return Err(Error::Config(format!(
            "--max-linf-stretch {}: must be a finite number ≥ 1",
            cfg.max_linf_stretch
        )));
    }
    if nf == 0 {
        return Ok(Vec::new());
    }
    let ctx = Ctx::new(mesh, topology, cfg);
    let mut charts = merge(&ctx, split_until_mapped(&ctx, segment(&ctx)));
    charts = straighten_charts(&ctx, charts);
    charts.sort_unstable_by_key(|c| c.faces[0]);
    Ok(charts)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
        Mesh {
            positions,
            triangles,
            ..Mesh::default()
        }
    }

    fn cube() -> Mesh {
        let p = (0..8)
            .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
            .collect();
        // outward-facing quads (counter-clockwise seen from outside)
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let t = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        mesh(p, t)
    }

    fn coverage(m: &Mesh, charts: &[Chart]) -> Vec<u32> {
        let mut seen = vec![0u32; m.triangles.len()];
        for c in charts {
            for (&f, t) in c.faces.iter().zip(&c.triangles) {
                seen[f as usize] += 1;
                assert_eq!(t.map(|v| c.vertices[v as usize]), m.triangles[f as usize]);
            }
        }
        seen
    }

    #[test]
    fn cube_sides_and_corners() {
        let m = cube();
        let cfg = ChartConfig::default();
        let topo = m.topology();
        // the segmentation keeps the sides apart (90° > 70°) ...
        let ctx = Ctx::new(&m, &topo, &cfg);
        assert_eq!(segment(&ctx).len(), 6);
        // ... but three sides around a corner stay within 70° of their mean
        // normal (54.7°), so merging may join them
        let charts = build_charts(&m, &topo, &cfg).unwrap();
        assert!((2..=6).contains(&charts.len()), "{}", charts.len());
        assert!(coverage(&m, &charts).iter().all(|&s| s == 1));
        for c in &charts {
            assert!(c.l2_stretch <= cfg.max_stretch);
        }
        let sides = ChartConfig {
            max_normal_deviation: 40.0,
            ..cfg
        };
        let charts = build_charts(&m, &topo, &sides).unwrap();
        assert_eq!(charts.len(), 6);
        for c in &charts {
            assert!((c.l2_stretch - 1.0).abs() < 1e-5 && (c.linf_stretch - 1.0).abs() < 1e-5);
            let max =
                c.uv.iter()
                    .fold([0f32; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
            assert!(
                (max[0] - 1.0).abs() < 1e-5 && (max[1] - 1.0).abs() < 1e-5,
                "{max:?}"
            );
        }
    }

    #[test]
    fn two_components_and_a_sliver() {
        // a cube plus a flat strip whose boundary edge carries a zero-area sliver
        let mut m = cube();
        let base = m.positions.len() as u32;
        for i in 0..4 {
            m.positions.push([3.0 + i as f32, 0.0, 0.0]);
            m.positions.push([3.0 + i as f32, 1.0, 0.0]);
        }
        m.positions.push([3.5, 0.0, 0.0]); // midpoint of the first bottom edge
        let (a, b, c, mid) = (base, base + 2, base + 1, base + 8);
        m.triangles.push([a, mid, c]);
        m.triangles.push([mid, b, c]);
        m.triangles.push([a, b, mid]); // zero area
        m.triangles.push([b, base + 3, c]);
        for i in 1..3 {
            let (p, q, r, s) = (base + 2 * i, base + 2 * i + 2, base + 2 * i + 3, base + 2 * i + 1);
            m.triangles.push([p, q, r]);
            m.triangles.push([p, r, s]);
        }
        let topo = m.topology();
        assert_eq!(topo.components, 2);
        let sides = ChartConfig {
            max_normal_deviation: 40.0,
            ..ChartConfig::default()
        };
        let charts = build_charts(&m, &topo, &sides).unwrap();
        assert!(coverage(&m, &charts).iter().all(|&s| s == 1));
        assert_eq!(
            charts.len(),
            7,
            "six cube sides and the strip: {:?}",
            charts.iter().map(|c| &c.faces).collect::<Vec<_>>()
        );
    }

    /// A dome: the sphere's cap down to `polar` degrees from the pole, `n`
    /// rings.
    pub(crate) fn dome(n: usize, polar: f64) -> Mesh {
        let (rings, segments) = (n, 4 * n);
        let mut p = vec![[0.0, 0.0, 1.0]];
        for i in 1..=rings {
            let th = (polar * i as f64 / rings as f64).to_radians();
            for j in 0..segments {
                let ph = std::f64::consts::TAU * j as f64 / segments as f64;
                p.push([
                    (th.sin() * ph.cos()) as f32,
                    (th.sin() * ph.sin()) as f32,
                    th.cos() as f32,
                ]);
            }
        }
        let id = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
        let mut t = Vec::new();
        for j in 0..segments {
            t.push([0, id(1, j), id(1, j + 1)]);
        }
        for i in 1..rings {
            for j in 0..segments {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        mesh(p, t)
    }

    /// With every limit out of the way the dome maps into charts whose
    /// `worst` exceeds `limit`; with only `tighten` applied, more charts,
    /// each within it, still covering every face once.
    fn dome_split_by(tighten: fn(&mut ChartConfig), limit: f64, worst: &dyn Fn(&Mesh, &Chart) -> f64) {
        // deep enough that even the relaxed map is over every limit
        let m = dome(12, 150.0);
        let topo = m.topology();
        let loose = ChartConfig {
            max_normal_deviation: 180.0,
            max_stretch: 100.0,
            max_area_distortion: 100.0,
            max_linf_stretch: 100.0,
            compact: true,
        };
        let worst = |charts: &[Chart]| charts.iter().map(|c| worst(&m, c)).fold(1.0f64, f64::max);
        let one = build_charts(&m, &topo, &loose).unwrap();
        assert!(worst(&one) > limit, "the dome in few charts: {}", worst(&one));
        let mut strict = loose.clone();
        tighten(&mut strict);
        let split = build_charts(&m, &topo, &strict).unwrap();
        assert!(coverage(&m, &split).iter().all(|&s| s == 1));
        assert!(split.len() > one.len(), "{} vs {}", split.len(), one.len());
        assert!(worst(&split) <= limit, "{}", worst(&split));
    }

    #[test]
    fn a_cap_lscm_must_split_maps_whole_when_relaxed() {
        let m = dome(12, 80.0);
        let topo = m.topology();
        let cfg = ChartConfig {
            max_normal_deviation: 180.0,
            compact: true,
            ..ChartConfig::default()
        };
        // without relaxation, LSCM's rim splits the cap
        let conformal_only = ChartConfig {
            compact: false,
            ..cfg.clone()
        };
        assert!(build_charts(&m, &topo, &conformal_only).unwrap().len() > 1);
        let faces: Vec<u32> = (0..m.triangles.len() as u32).collect();
        let conformal = lscm(&m.positions, &m.triangles).unwrap();
        let limit = cfg.max_area_distortion as f64;
        assert!(area_distortion_tail(&m.positions, &m.triangles, &conformal) > limit);
        let charts = build_charts(&m, &topo, &cfg).unwrap();
        assert_eq!(
            charts.len(),
            1,
            "{:?}",
            charts.iter().map(|c| c.faces.len()).collect::<Vec<_>>()
        );
        let c = &charts[0];
        assert_eq!(c.faces, faces);
        let pos: Vec<[f32; 3]> = c.vertices.iter().map(|&v| m.positions[v as usize]).collect();
        let uv: Vec<[f64; 2]> = c.uv.iter().map(|q| [q[0] as f64, q[1] as f64]).collect();
        assert!(area_distortion_tail(&pos, &c.triangles, &uv) <= limit);
        let (l2, linf) = stretch(&pos, &c.triangles, &uv);
        assert!(
            linf <= RELAXED_LINF_SHARE * cfg.max_linf_stretch as f64 + 1e-6,
            "{linf}"
        );
        assert!(l2 <= cfg.max_stretch as f64, "{l2}");
    }

    /// Faces meeting their own chart along at most one edge and another
    /// chart along two: the spikes and notches straightening removes.
    fn spikes(ctx: &Ctx, charts: &[Chart]) -> usize {
        let owner = owners(ctx, charts);
        (0..ctx.adj.len())
            .filter(|&f| {
                let around: Vec<u32> = ctx.adj[f]
                    .iter()
                    .filter(|&&g| g != NO_FACE)
                    .map(|&g| owner[g as usize])
                    .collect();
                let same = around.iter().filter(|&&o| o == owner[f]).count();
                same <= 1
                    && around
                        .iter()
                        .any(|&o| o != owner[f] && around.iter().filter(|&&p| p == o).count() >= 2)
            })
            .count()
    }

    #[test]
    fn straightening_after_merging_removes_spikes_and_keeps_charts_valid() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/cow_5.8k.obj");
        if !path.is_file() {
            eprintln!("skipping: {} not found", path.display());
            return;
        }
        let (m, _) = crate::mesh::io::load(&path, &Default::default()).unwrap();
        let topo = m.topology();
        let cfg = ChartConfig {
            compact: true,
            ..ChartConfig::default()
        };
        let ctx = Ctx::new(&m, &topo, &cfg);
        let merged = merge(&ctx, split_until_mapped(&ctx, segment(&ctx)));
        let straight = straighten_charts(&ctx, merged.clone());
        let (before, after) = (spikes(&ctx, &merged), spikes(&ctx, &straight));
        println!("cow: {before} spike faces after merging, {after} after straightening");
        assert!(after < before, "{after} spikes after, {before} before");
        assert_eq!(straight.len(), merged.len());
        assert!(coverage(&m, &straight).iter().all(|&s| s == 1));
        for (a, b) in merged.iter().zip(&straight) {
            if a.faces != b.faces {
                // a changed chart is mapped afresh, within the limits
                let again = parameterize(&ctx, &b.faces).expect("a kept chart maps");
                assert_eq!(again.uv, b.uv);
            }
        }
    }

    #[test]
    fn charts_keep_their_texel_density_within_the_area_limit() {
        // a conformal map of a dome shrinks its rim against its pole
        dome_split_by(|c| c.max_area_distortion = 1.5, 1.5, &|m, c| {
            let pos: Vec<[f32; 3]> = c.vertices.iter().map(|&v| m.positions[v as usize]).collect();
            let uv: Vec<[f64; 2]> = c.uv.iter().map(|q| [q[0] as f64, q[1] as f64]).collect();
            area_distortion_tail(&pos, &c.triangles, &uv)
        });
    }

    #[test]
    fn charts_keep_every_triangle_within_the_linf_limit() {
        dome_split_by(|c| c.max_linf_stretch = 1.2, 1.2, &|_, c| c.linf_stretch as f64);
    }

    /// A flat `n`×`n` grid of unit squares, two triangles each.
    fn grid(n: usize) -> Mesh {
        let id = |x: usize, y: usize| (y * (n + 1) + x) as u32;
        let p = (0..=n)
            .flat_map(|y| (0..=n).map(move |x| [x as f32, y as f32, 0.0]))
            .collect();
        let mut t = Vec::new();
        for y in 0..n {
            for x in 0..n {
                t.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                t.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        mesh(p, t)
    }

    #[test]
    fn straightening_removes_spikes_and_teeth_and_keeps_regions_whole() {
        let n = 16;
        let m = grid(n);
        let topo = m.topology();
        let ctx = Ctx::new(&m, &topo, &ChartConfig::default());
        let whole = Patch::whole(&ctx);
        // left and right halves, the border zig-zagging by a column per
        // row, a one-face-wide spike of the left reaching along row 8, a
        // lone right face inside the left and a third region of one face
        let mut label: Vec<u32> = (0..m.triangles.len())
            .map(|f| {
                let (x, y) = ((f / 2) % n, (f / 2) / n);
                let edge = n / 2 + y % 2;
                u32::from(x >= edge)
            })
            .collect();
        for x in n / 2..n - 2 {
            label[2 * (8 * n + x)] = 0;
        }
        label[2 * (3 * n + 2)] = 1;
        label[2 * (12 * n + 12) + 1] = 2;
        let border = |label: &[u32]| {
            (0..label.len())
                .flat_map(|f| ctx.adj[f].map(|g| (f, g)))
                .filter(|&(f, g)| g != NO_FACE && label[f] != label[g as usize])
                .count()
                / 2
        };
        let before = border(&label);
        whole.straighten(&ctx, &mut label);
        let after = border(&label);
        assert!(after < before / 2, "border {before} -> {after} edges");
        // every region is still there and in one piece
        for l in 0..3 {
            let faces: Vec<u32> = (0..label.len() as u32)
                .filter(|&f| label[f as usize] == l)
                .collect();
            assert!(!faces.is_empty(), "region {l} vanished");
            assert_eq!(
                Patch::new(&ctx, faces).split_components().len(),
                1,
                "region {l} torn"
            );
        }
        // no face is left meeting another region along two edges while
        // meeting its own along at most one (the flat grid has no crease)
        for f in 0..label.len() {
            let others: Vec<u32> = ctx.adj[f]
                .iter()
                .filter(|&&g| g != NO_FACE && label[g as usize] != label[f])
                .map(|&g| label[g as usize])
                .collect();
            let same = ctx.adj[f].iter().filter(|&&g| g != NO_FACE).count() - others.len();
            let pair = others
                .iter()
                .any(|&l| others.iter().filter(|&&k| k == l).count() >= 2);
            let last = label.iter().filter(|&&l| l == label[f]).count() == 1;
            assert!(same > 1 || !pair || last, "face {f} still a spike or notch");
        }
    }

    #[test]
    fn a_tiny_chart_is_shared_out_to_its_nearest_neighbours() {
        let n = 8;
        let m = grid(n);
        let topo = m.topology();
        let ctx = Ctx::new(&m, &topo, &ChartConfig::default());
        let column = |f: u32| (f as usize / 2) % n;
        let row = |f: u32| (f as usize / 2) / n;
        // left and right halves, and a 2×2-square chart astride their border
        let part = |f: u32| match (column(f), row(f)) {
            (3..=4, 3..=4) => 2,
            (x, _) => usize::from(x >= n / 2),
        };
        let faces =
            |p: usize| -> Vec<u32> { (0..m.triangles.len() as u32).filter(|&f| part(f) == p).collect() };
        let charts: Vec<Chart> = (0..3)
            .map(|p| parameterize(&ctx, &faces(p)).expect("a flat disk maps"))
            .collect();
        let owner = owners(&ctx, &charts);
        let grown = dissolve(&ctx, &charts, &owner, 2).expect("both halves take their side");
        assert_eq!(grown.iter().map(|g| g.0).collect::<Vec<_>>(), [0, 1]);
        for (k, chart) in grown {
            // each half takes the tiny chart's faces on its own side
            let want: Vec<u32> = (0..m.triangles.len() as u32)
                .filter(|&f| usize::from(column(f) >= n / 2) == k)
                .collect();
            assert_eq!(chart.faces, want, "half {k}");
            assert!(chart.l2_stretch < 1.0001, "a flat chart maps isometrically");
        }
        // a chart with no neighbour (the whole grid) cannot be shared out
        let all = vec![parameterize(&ctx, &(0..m.triangles.len() as u32).collect::<Vec<_>>()).unwrap()];
        assert!(dissolve(&ctx, &all, &owners(&ctx, &all), 0).is_none());
    }

    #[test]
    fn bad_input() {
        let m = cube();
        let topo = m.topology();
        let bad = ChartConfig {
            max_stretch: 0.5,
            ..ChartConfig::default()
        };
        assert!(build_charts(&m, &topo, &bad).is_err());
        let bad = ChartConfig {
            max_area_distortion: 0.9,
            ..ChartConfig::default()
        };
        assert!(build_charts(&m, &topo, &bad).is_err());
        let bad = ChartConfig {
            max_linf_stretch: f32::NAN,
            ..ChartConfig::default()
        };
        assert!(build_charts(&m, &topo, &bad).is_err());
        let bad = ChartConfig {
            max_normal_deviation: 0.0,
            ..ChartConfig::default()
        };
        assert!(build_charts(&m, &topo, &bad).is_err());
        let other = mesh(vec![[0.0; 3]; 3], vec![[0, 1, 2]]);
        assert!(build_charts(&other, &topo, &ChartConfig::default()).is_err());
        let empty = Mesh::default();
        assert!(build_charts(&empty, &empty.topology(), &ChartConfig::default())
            .unwrap()
            .is_empty());
    }
}
