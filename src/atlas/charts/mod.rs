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
use crate::math;
use crate::mesh::{dunit_or, to_dvec3, Mesh, Topology, NO_FACE};
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

mod maps;
mod patch;
use maps::{evaluate, parameterize_relaxing, within_cone, Outcome};
use patch::Patch;

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
            cos_max: math::cos((cfg.max_normal_deviation as f64).to_radians()),
            max_stretch: cfg.max_stretch as f64,
            max_area_distortion: cfg.max_area_distortion as f64,
            max_linf_stretch: cfg.max_linf_stretch as f64,
            max_relaxed_linf: RELAXED_LINF_SHARE * cfg.max_linf_stretch as f64,
            compact: cfg.compact,
        }
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
/// disk that [`parameterize`](maps::parameterize) maps and within the normal cone (waived for
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
pub(super) mod tests;
