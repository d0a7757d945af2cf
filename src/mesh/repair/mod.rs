//! Mesh repair: welding, degenerate-face removal, splitting of non-manifold
//! edges and vertices, consistent orientation and compaction.
//!
//! [`repair`] leaves a mesh in which every edge has at most two faces and the
//! faces around every vertex form a single fan, so [`Mesh::topology`] is well
//! defined. The result depends only on the input, never on hash order.

use super::{dunit_or, to_dvec3, Mesh, NO_FACE};
use crate::math;
use glam::DVec3;
use std::collections::HashMap;
use std::fmt;

/// What [`repair`] found and changed.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RepairReport {
    /// Vertices before repair.
    pub input_vertices: usize,
    /// Faces before repair.
    pub input_faces: usize,
    /// Vertices merged into others by welding.
    pub welded_vertices: usize,
    /// Faces dropped: repeated vertex, zero area, or a duplicate of an earlier face.
    pub degenerate_faces: usize,
    /// Vertices removed because no face used them (welded ones not included).
    pub unreferenced_vertices: usize,
    /// Edges that had more than two faces (before splitting).
    pub nonmanifold_edges: usize,
    /// Extra vertex copies created so that every vertex is a single fan.
    pub split_vertices: usize,
    /// Faces flipped to orient each component consistently.
    pub inconsistent_orientation: usize,
    /// Connected components after repair.
    pub components: usize,
    /// Boundary loops after repair.
    pub boundary_loops: usize,
}

impl RepairReport {
    /// True if repair changed nothing.
    pub fn is_clean(&self) -> bool {
        self.welded_vertices == 0
            && self.degenerate_faces == 0
            && self.unreferenced_vertices == 0
            && self.nonmanifold_edges == 0
            && self.split_vertices == 0
            && self.inconsistent_orientation == 0
    }

    /// Vertices after repair.
    pub fn output_vertices(&self) -> usize {
        (self.input_vertices + self.split_vertices)
            .saturating_sub(self.welded_vertices + self.unreferenced_vertices)
    }

    /// Faces after repair.
    pub fn output_faces(&self) -> usize {
        self.input_faces.saturating_sub(self.degenerate_faces)
    }
}

fn plural(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

impl fmt::Display for RepairReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (v, faces) = (self.output_vertices(), self.output_faces());
        write!(
            f,
            "{}, {}",
            plural(v, "vertex", "vertices"),
            plural(faces, "face", "faces")
        )?;
        if v != self.input_vertices || faces != self.input_faces {
            write!(f, " (input {}, {})", self.input_vertices, self.input_faces)?;
        }
        write!(
            f,
            ", {}, {}; ",
            plural(self.components, "component", "components"),
            plural(self.boundary_loops, "boundary loop", "boundary loops")
        )?;
        if self.is_clean() {
            return write!(f, "no repair needed");
        }
        // (count, what was done, singular, plural)
        let repairs = [
            (self.welded_vertices, "welded {}", "vertex", "vertices"),
            (
                self.degenerate_faces,
                "dropped {}",
                "degenerate face",
                "degenerate faces",
            ),
            (
                self.nonmanifold_edges,
                "separated faces at {}",
                "non-manifold edge",
                "non-manifold edges",
            ),
            (
                self.split_vertices,
                "split off {} at non-manifold vertices",
                "vertex copy",
                "vertex copies",
            ),
            (
                self.inconsistent_orientation,
                "flipped {} to match orientation",
                "face",
                "faces",
            ),
            (
                self.unreferenced_vertices,
                "removed {}",
                "unreferenced vertex",
                "unreferenced vertices",
            ),
        ];
        let parts: Vec<String> = repairs
            .iter()
            .filter(|r| r.0 > 0)
            .map(|&(n, done, one, many)| done.replace("{}", &plural(n, one, many)))
            .collect();
        write!(f, "repaired: {}", parts.join(", "))
    }
}

/// Repairs `mesh` in place: weld vertices within `weld_tolerance` times the
/// median edge length (lowest index survives), drop degenerate and duplicate
/// faces, separate faces at non-manifold edges and give every fan of faces
/// around a vertex its own vertex copy, orient each orientable component
/// consistently (keeping the majority orientation), and remove unreferenced
/// vertices. Faces with out-of-range indices or non-finite corners count as
/// degenerate; colour/weight vectors of the wrong length are padded or cut.
pub fn repair(mesh: &mut Mesh, weld_tolerance: f32) -> RepairReport {
    let mut report = RepairReport {
        input_vertices: mesh.positions.len(),
        input_faces: mesh.triangles.len(),
        ..Default::default()
    };
    let n = mesh.positions.len();
    if let Some(c) = &mut mesh.vertex_colors {
        c.resize(n, [0.0; 3]);
    }
    if let Some(w) = &mut mesh.vertex_weights {
        w.resize(n, 0.0);
    }
    let edge = median_edge_length(mesh);
    report.welded_vertices = weld(mesh, weld_tolerance, edge);
    report.degenerate_faces = drop_degenerate(mesh);
    let (nonmanifold, split) = make_manifold(mesh);
    report.nonmanifold_edges = nonmanifold;
    report.split_vertices = split;
    report.inconsistent_orientation = orient(mesh);
    let removed = remove_unreferenced(mesh);
    report.unreferenced_vertices = removed.saturating_sub(report.welded_vertices);
    report.components = mesh.topology().components;
    report.boundary_loops = boundary_loops(mesh);
    report
}

fn is_finite(p: [f32; 3]) -> bool {
    p.iter().all(|c| c.is_finite())
}

/// Median length (f64) of the finite, non-zero edges of faces whose indices
/// are in range; 0 if there is none.
fn median_edge_length(mesh: &Mesh) -> f64 {
    let n = mesh.positions.len();
    let mut lengths: Vec<f64> = Vec::with_capacity(mesh.triangles.len() * 3);
    for t in &mesh.triangles {
        if t.iter().any(|&v| v as usize >= n) {
            continue;
        }
        for i in 0..3 {
            let (a, b) = (
                mesh.positions[t[i] as usize],
                mesh.positions[t[(i + 1) % 3] as usize],
            );
            let d = dist2(a, b).sqrt();
            if d.is_finite() && d > 0.0 {
                lengths.push(d);
            }
        }
    }
    if lengths.is_empty() {
        return 0.0;
    }
    let mid = lengths.len() / 2;
    *lengths.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

fn dist2(a: [f32; 3], b: [f32; 3]) -> f64 {
    to_dvec3(a).distance_squared(to_dvec3(b))
}

/// Welds vertices closer than `tolerance` times `edge` (the median edge
/// length; a length of the surface's own detail, so that a small component
/// far from the rest keeps its vertices apart, unlike a tolerance relative to
/// the bounding box); returns how many were merged into others.
fn weld(mesh: &mut Mesh, tolerance: f32, edge: f64) -> usize {
    let n = mesh.positions.len();
    let pos = &mesh.positions;
    let mut target: Vec<u32> = (0..n as u32).collect();
    let tol = if tolerance.is_finite() && tolerance > 0.0 {
        tolerance as f64 * edge
    } else {
        0.0
    };
    if tol > 0.0 && tol.is_finite() {
        // Grid of cell size `tol`: a vertex joins the lowest-index survivor
        // within `tol` in the 27 surrounding cells, else becomes a survivor.
        let inv = 1.0 / tol;
        let tol2 = tol * tol;
        let cell = |p: [f32; 3]| p.map(|c| (c as f64 * inv).floor() as i64);
        let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for v in 0..n {
            let p = pos[v];
            if !is_finite(p) {
                continue;
            }
            let c = cell(p);
            let mut best: Option<u32> = None;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let key = [
                            c[0].wrapping_add(dx),
                            c[1].wrapping_add(dy),
                            c[2].wrapping_add(dz),
                        ];
                        for &u in grid.get(&key).map(|l| l.as_slice()).unwrap_or(&[]) {
                            if dist2(p, pos[u as usize]) <= tol2 && best.map_or(true, |b| u < b) {
                                best = Some(u);
                            }
                        }
                    }
                }
            }
            match best {
                Some(u) => target[v] = u,
                None => grid.entry(c).or_default().push(v as u32),
            }
        }
    } else {
        // Exact duplicates (+0 and -0 equal): sort by position, then index.
        let key = |v: u32| pos[v as usize].map(|c| (c + 0.0).to_bits());
        let mut order: Vec<u32> = (0..n as u32).filter(|&v| is_finite(pos[v as usize])).collect();
        order.sort_unstable_by_key(|&v| (key(v), v));
        let mut i = 0;
        while i < order.len() {
            let mut j = i + 1;
            while j < order.len() && key(order[j]) == key(order[i]) {
                target[order[j] as usize] = order[i];
                j += 1;
            }
            i = j;
        }
    }
    let welded = target
        .iter()
        .enumerate()
        .filter(|&(v, &t)| t as usize != v)
        .count();
    if welded > 0 {
        for t in &mut mesh.triangles {
            for v in t.iter_mut() {
                if let Some(&w) = target.get(*v as usize) {
                    *v = w;
                }
            }
        }
    }
    welded
}

/// Drops faces with bad or repeated indices, zero area (at most 1e-12 times
/// the square of the face's own longest edge: a sliver judged by its own size,
/// so a small component far from the rest is not dropped), or the same vertex
/// set as an earlier face; returns how many.
fn drop_degenerate(mesh: &mut Mesh) -> usize {
    let n = mesh.positions.len();
    let pos = &mesh.positions;
    let usable = |t: &[u32; 3]| {
        if t.iter().any(|&v| v as usize >= n) || t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return false;
        }
        let [a, b, c] = t.map(|v| pos[v as usize]);
        if !(is_finite(a) && is_finite(b) && is_finite(c)) {
            return false;
        }
        let (e1, e2) = (to_dvec3(b) - to_dvec3(a), to_dvec3(c) - to_dvec3(a));
        let longest2 = dist2(a, b).max(dist2(b, c)).max(dist2(c, a));
        0.5 * e1.cross(e2).length() > 1e-12 * longest2
    };
    let before = mesh.triangles.len();
    let kept: Vec<[u32; 3]> = mesh.triangles.iter().copied().filter(|t| usable(t)).collect();
    let mut keys: Vec<([u32; 3], usize)> = kept
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut s = *t;
            s.sort_unstable();
            (s, i)
        })
        .collect();
    keys.sort_unstable();
    let mut duplicate = vec![false; kept.len()];
    for w in keys.windows(2) {
        if w[0].0 == w[1].0 {
            duplicate[w[1].1] = true;
        }
    }
    mesh.triangles = kept
        .into_iter()
        .zip(duplicate)
        .filter(|(_, d)| !d)
        .map(|(t, _)| t)
        .collect();
    before - mesh.triangles.len()
}

/// Union-find with path halving.
struct UnionFind(Vec<usize>);

impl UnionFind {
    fn new(n: usize) -> Self {
        UnionFind((0..n).collect())
    }

    fn find(&mut self, mut x: usize) -> usize {
        while self.0[x] != x {
            self.0[x] = self.0[self.0[x]];
            x = self.0[x];
        }
        x
    }

    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.0[ra.max(rb)] = ra.min(rb);
        }
    }
}

/// One face side of an undirected edge: (low vertex, high vertex, face, corner
/// where the edge starts).
type EdgeSide = (u32, u32, u32, u8);

/// All edge sides sorted, so equal (low, high) pairs are adjacent.
fn sorted_edges(triangles: &[[u32; 3]]) -> Vec<EdgeSide> {
    let mut edges = Vec::with_capacity(triangles.len() * 3);
    for (f, t) in triangles.iter().enumerate() {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            edges.push((a.min(b), a.max(b), f as u32, i as u8));
        }
    }
    edges.sort_unstable();
    edges
}

/// Calls `f` on each run of edge sides sharing one undirected edge.
fn for_each_edge(edges: &[EdgeSide], mut f: impl FnMut(&[EdgeSide])) {
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j].0 == edges[i].0 && edges[j].1 == edges[i].1 {
            j += 1;
        }
        f(&edges[i..j]);
        i = j;
    }
}

/// Number of boundary edges (edges with one face) of each face.
fn boundary_counts(edges: &[EdgeSide], faces: usize) -> Vec<u8> {
    let mut boundary = vec![0u8; faces];
    for_each_edge(edges, |run| {
        if run.len() == 1 {
            boundary[run[0].2 as usize] += 1;
        }
    });
    boundary
}

/// Corner index (3·face + k) at which `side`'s face holds vertex `v`.
fn corner_of(triangles: &[[u32; 3]], side: EdgeSide, v: u32) -> usize {
    let (f, i) = (side.2 as usize, side.3 as usize);
    if triangles[f][i] == v {
        3 * f + i
    } else {
        3 * f + (i + 1) % 3
    }
}

/// True if the face runs the edge from its low to its high vertex.
fn runs_forward(triangles: &[[u32; 3]], side: EdgeSide) -> bool {
    triangles[side.2 as usize][side.3 as usize] == side.0
}

/// Groups the faces of an edge with more than two faces into pairs of
/// opposite direction that are neighbours around the edge, preferring (in
/// order) pairs of faces not dangling by boundary edges (so stray fins come
/// off), pairs enclosing a wedge their normals point away from (so outward
/// oriented solids touching at an edge stay apart), and flatter pairs; then
/// other opposite pairs; the rest are singletons. `boundary[f]` counts face
/// f's boundary edges. Returns indices into `run`, the group holding the
/// lowest face first.
fn pair_faces(mesh: &Mesh, run: &[EdgeSide], boundary: &[u8]) -> Vec<Vec<usize>> {
    let tris = &mesh.triangles;
    let p = |v: u32| to_dvec3(mesh.positions[v as usize]);
    let (lo, hi) = (p(run[0].0), p(run[0].1));
    let axis = hi - lo;
    let len2 = axis.length_squared();
    // Radial direction of each face's third corner, perpendicular to the edge.
    let radial: Vec<DVec3> = run
        .iter()
        .map(|s| {
            let t = tris[s.2 as usize];
            let c = t[(s.3 as usize + 2) % 3];
            let r = p(c) - lo;
            let along = if len2 > 0.0 { r.dot(axis) / len2 } else { 0.0 };
            r - along * axis
        })
        .collect();
    let u = radial[0];
    let v = axis.cross(u);
    let angle: Vec<f64> = radial
        .iter()
        .map(|r| {
            let a = math::atan2(r.dot(v), r.dot(u));
            if a.is_finite() {
                a
            } else {
                0.0
            }
        })
        .collect();
    let mut order: Vec<usize> = (0..run.len()).collect();
    order.sort_by(|&a, &b| angle[a].total_cmp(&angle[b]).then(a.cmp(&b)));
    let forward: Vec<bool> = run.iter().map(|s| runs_forward(tris, *s)).collect();
    let mut paired = vec![false; run.len()];
    let mut groups = Vec::new();
    // Pass 1: neighbours in angle order, best first.
    let m = order.len();
    let mut candidates = Vec::new();
    for k in 0..m {
        let (a, b) = (order[k], order[(k + 1) % m]);
        if forward[a] != forward[b] {
            let dangling = boundary[run[a].2 as usize] + boundary[run[b].2 as usize];
            let inward = forward[a] || !forward[b];
            let bend = dunit_or(radial[a], DVec3::ZERO).dot(dunit_or(radial[b], DVec3::ZERO));
            candidates.push((dangling, inward, bend, a.min(b), a.max(b)));
        }
    }
    candidates.sort_by(|x, y| {
        (x.0, x.1)
            .cmp(&(y.0, y.1))
            .then(x.2.total_cmp(&y.2))
            .then((x.3, x.4).cmp(&(y.3, y.4)))
    });
    for &(_, _, _, a, b) in &candidates {
        if !paired[a] && !paired[b] {
            paired[a] = true;
            paired[b] = true;
            groups.push(vec![a, b]);
        }
    }
    // Pass 2: any opposite neighbours among the rest.
    let rest: Vec<usize> = order.iter().copied().filter(|&a| !paired[a]).collect();
    let m = rest.len();
    for k in 0..m {
        let (a, b) = (rest[k], rest[(k + 1) % m]);
        if a != b && !paired[a] && !paired[b] && forward[a] != forward[b] {
            paired[a] = true;
            paired[b] = true;
            groups.push(vec![a.min(b), a.max(b)]);
        }
    }
    groups.extend((0..run.len()).filter(|&a| !paired[a]).map(|a| vec![a]));
    // The group with the lowest face keeps the edge.
    groups.sort();
    groups
}

/// Separates faces at non-manifold edges and gives each fan around a vertex
/// its own vertex. Returns (non-manifold edges, vertex copies made).
fn make_manifold(mesh: &mut Mesh) -> (usize, usize) {
    let mut nonmanifold = 0;
    let mut copies = 0;
    let mut first = true;
    loop {
        let edges = sorted_edges(&mesh.triangles);
        let mut uf = UnionFind::new(mesh.triangles.len() * 3);
        let boundary = boundary_counts(&edges, mesh.triangles.len());
        let tris = &mesh.triangles;
        let join = |uf: &mut UnionFind, a: EdgeSide, b: EdgeSide| {
            for v in [a.0, a.1] {
                uf.union(corner_of(tris, a, v), corner_of(tris, b, v));
            }
        };
        for_each_edge(&edges, |run| {
            if run.len() == 2 {
                join(&mut uf, run[0], run[1]);
            } else if run.len() > 2 {
                if first {
                    nonmanifold += 1;
                }
                for g in pair_faces(mesh, run, &boundary) {
                    if g.len() == 2 {
                        join(&mut uf, run[g[0]], run[g[1]]);
                    }
                }
            }
        });
        first = false;
        copies += split_fans(mesh, &mut uf);
        // Rarely a surface touches itself along an edge so that both ends
        // stay single fans; detach all but the first group with new copies.
        let edges = sorted_edges(&mesh.triangles);
        let mut overfull = Vec::new();
        for_each_edge(&edges, |run| {
            if run.len() > 2 {
                overfull.push(run.to_vec());
            }
        });
        if overfull.is_empty() {
            return (nonmanifold, copies);
        }
        let boundary = boundary_counts(&edges, mesh.triangles.len());
        let mut touched = vec![false; mesh.triangles.len()];
        for run in overfull {
            if run.iter().any(|s| touched[s.2 as usize]) {
                continue; // stale after an earlier change; next round
            }
            for s in &run {
                touched[s.2 as usize] = true;
            }
            for g in pair_faces(mesh, &run, &boundary).into_iter().skip(1) {
                for v in [run[0].0, run[0].1] {
                    let copy = copy_vertex(mesh, v);
                    copies += 1;
                    for &k in &g {
                        let c = corner_of(&mesh.triangles, run[k], v);
                        mesh.triangles[c / 3][c % 3] = copy;
                    }
                }
            }
        }
    }
}

/// Appends a copy of vertex `v` (with its paint); returns the new index.
fn copy_vertex(mesh: &mut Mesh, v: u32) -> u32 {
    let v = v as usize;
    let new = mesh.positions.len() as u32;
    mesh.positions.push(mesh.positions[v]);
    if let Some(c) = &mut mesh.vertex_colors {
        c.push(c[v]);
    }
    if let Some(w) = &mut mesh.vertex_weights {
        w.push(w[v]);
    }
    new
}

/// Gives every class of corners (a fan) its own vertex; the fan met first in
/// corner order keeps the original. Returns the number of copies made.
fn split_fans(mesh: &mut Mesh, uf: &mut UnionFind) -> usize {
    let nc = mesh.triangles.len() * 3;
    let mut fan_vertex = vec![u32::MAX; nc];
    let mut claimed = vec![false; mesh.positions.len()];
    let mut copies = 0;
    for c in 0..nc {
        let v = mesh.triangles[c / 3][c % 3];
        let root = uf.find(c);
        if fan_vertex[root] == u32::MAX {
            fan_vertex[root] = if !claimed[v as usize] {
                claimed[v as usize] = true;
                v
            } else {
                copies += 1;
                copy_vertex(mesh, v)
            };
        }
        mesh.triangles[c / 3][c % 3] = fan_vertex[root];
    }
    copies
}

/// Orients each orientable component consistently, keeping the orientation
/// most of its faces already have (ties: that of its lowest face). Returns
/// the number of faces flipped.
fn orient(mesh: &mut Mesh) -> usize {
    let topo = mesh.topology();
    let tris = &mesh.triangles;
    let nf = tris.len();
    let mut flip = vec![false; nf];
    let mut seen = vec![false; nf];
    let mut stack = Vec::new();
    let mut flipped = 0;
    for start in 0..nf {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut component = Vec::new();
        let mut orientable = true;
        while let Some(f) = stack.pop() {
            component.push(f);
            for i in 0..3 {
                let g = topo.face_adjacency[f][i];
                if g == NO_FACE {
                    continue;
                }
                let g = g as usize;
                let (a, b) = (tris[f][i], tris[f][(i + 1) % 3]);
                let same = (0..3).any(|j| tris[g][j] == a && tris[g][(j + 1) % 3] == b);
                let want = flip[f] ^ same;
                if !seen[g] {
                    seen[g] = true;
                    flip[g] = want;
                    stack.push(g);
                } else if flip[g] != want {
                    orientable = false;
                }
            }
        }
        let count = component.iter().filter(|&&f| flip[f]).count();
        if !orientable {
            for &f in &component {
                flip[f] = false;
            }
        } else if 2 * count > component.len() {
            for &f in &component {
                flip[f] = !flip[f];
            }
            flipped += component.len() - count;
        } else {
            flipped += count;
        }
    }
    for (t, &fl) in mesh.triangles.iter_mut().zip(&flip) {
        if fl {
            t.swap(1, 2);
        }
    }
    flipped
}

/// Removes vertices no face uses, keeping order; returns how many.
fn remove_unreferenced(mesh: &mut Mesh) -> usize {
    let n = mesh.positions.len();
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let removed = used.iter().filter(|&&u| !u).count();
    if removed == 0 {
        return 0;
    }
    let mut new_index = vec![u32::MAX; n];
    let mut next = 0u32;
    for v in 0..n {
        if used[v] {
            new_index[v] = next;
            next += 1;
        }
    }
    fn compact<T: Copy>(values: &mut Vec<T>, used: &[bool]) {
        let mut i = 0;
        values.retain(|_| {
            i += 1;
            used[i - 1]
        });
    }
    compact(&mut mesh.positions, &used);
    if let Some(c) = &mut mesh.vertex_colors {
        compact(c, &used);
    }
    if let Some(w) = &mut mesh.vertex_weights {
        compact(w, &used);
    }
    for t in &mut mesh.triangles {
        for v in t.iter_mut() {
            *v = new_index[*v as usize];
        }
    }
    removed
}

/// Number of closed loops formed by boundary edges (edges with one face).
fn boundary_loops(mesh: &Mesh) -> usize {
    let mut uf = UnionFind::new(mesh.positions.len());
    let mut on_boundary = vec![false; mesh.positions.len()];
    for_each_edge(&sorted_edges(&mesh.triangles), |run| {
        if run.len() == 1 {
            let (a, b) = (run[0].0 as usize, run[0].1 as usize);
            on_boundary[a] = true;
            on_boundary[b] = true;
            uf.union(a, b);
        }
    });
    (0..mesh.positions.len())
        .filter(|&v| on_boundary[v] && uf.find(v) == v)
        .count()
}

#[cfg(test)]
mod tests;
