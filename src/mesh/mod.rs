//! Triangle meshes as flat vectors, with topology derived only when asked
//! (`Mesh::topology`).
//!
//! After [`io::load`] (which repairs what can be repaired, see [`repair`]),
//! every edge has at most two faces and every vertex a single fan, so face
//! adjacency is well defined. Several components and open boundaries are fine.

pub mod exposure;
pub mod io;
pub mod repair;

use glam::{DVec3, Vec3};

use crate::math;

/// Index of a face.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct FaceId(pub u32);

/// Marks "no face" in adjacency tables.
pub const NO_FACE: u32 = u32::MAX;

/// A triangle mesh: positions and index triples, plus optional per-vertex
/// paint (colours or scalar weights, as painted in a modeller).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex RGB in 0..1, if the file had vertex colours.
    pub vertex_colors: Option<Vec<[f32; 3]>>,
    /// Per-vertex scalar (PLY `quality`/`weight`/`value`), if present.
    pub vertex_weights: Option<Vec<f32>>,
}

/// Derived adjacency of a manifold mesh.
#[derive(Clone, Debug)]
pub struct Topology {
    /// For face f and edge i (from corner i to corner i+1), the face across
    /// that edge, or [`NO_FACE`] on a boundary.
    pub face_adjacency: Vec<[u32; 3]>,
    /// Connected component of each face (faces connected through edges).
    pub face_component: Vec<u32>,
    /// Number of components.
    pub components: usize,
}

/// Bounding-box diagonal of the finite positions, in f64 (0 if none).
pub(crate) fn finite_diagonal_f64(positions: &[[f32; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut any = false;
    for p in positions.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        any = true;
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    if !any {
        return 0.0;
    }
    ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt()
}

/// The power of two that brings the bounding-box diagonal of `positions`
/// nearest to 1 when it lies outside [2⁻²⁰, 2²⁰] (about 1e-6 to 1e6 units),
/// else 1: every stage that computes in f32 works on positions multiplied by
/// it, exactly (see [`Mesh::normalize_extreme_scale`]).
pub fn extreme_scale(positions: &[[f32; 3]]) -> f64 {
    let diag = finite_diagonal_f64(positions);
    if !(diag.is_finite() && diag > 0.0) {
        return 1.0;
    }
    if (2f64.powi(-20)..=2f64.powi(20)).contains(&diag) {
        return 1.0;
    }
    2f64.powi(-math::log2(diag).round() as i32)
}

/// `v / |v|`, each component divided by the length, or `fallback` when the
/// length is not positive (a zero vector, or NaN). glam's `normalize*`
/// multiply by the reciprocal length instead, which can round differently in
/// the last bit; every unit vector of the pipeline is made here so that its
/// bits stay those it always had.
pub(crate) fn unit_or(v: Vec3, fallback: Vec3) -> Vec3 {
    let l = v.length();
    if l > 0.0 {
        v / l
    } else {
        fallback
    }
}

/// A stored f32 point in f64 (each component converted exactly).
pub(crate) fn to_dvec3(p: [f32; 3]) -> DVec3 {
    Vec3::from(p).as_dvec3()
}

/// [`unit_or`] in f64.
pub(crate) fn dunit_or(v: DVec3, fallback: DVec3) -> DVec3 {
    let l = v.length();
    if l > 0.0 {
        v / l
    } else {
        fallback
    }
}

impl Mesh {
    /// A unit sphere: a regular icosahedron whose faces are split in four
    /// `levels` times, new vertices pushed out to the sphere (test and
    /// example geometry; 20 · 4^levels faces).
    pub fn icosphere(levels: usize) -> Mesh {
        let g = (1.0 + 5f32.sqrt()) / 2.0;
        let mut p: Vec<[f32; 3]> = vec![
            [-1.0, g, 0.0],
            [1.0, g, 0.0],
            [-1.0, -g, 0.0],
            [1.0, -g, 0.0],
            [0.0, -1.0, g],
            [0.0, 1.0, g],
            [0.0, -1.0, -g],
            [0.0, 1.0, -g],
            [g, 0.0, -1.0],
            [g, 0.0, 1.0],
            [-g, 0.0, -1.0],
            [-g, 0.0, 1.0],
        ];
        let mut t: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        let norm = |a: [f32; 3]| {
            let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            [a[0] / l, a[1] / l, a[2] / l]
        };
        for q in p.iter_mut() {
            *q = norm(*q);
        }
        for _ in 0..levels {
            let mut mid: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
            let mut next = Vec::new();
            for tri in &t {
                let mut m = [0u32; 3];
                for i in 0..3 {
                    let (a, b) = (tri[i], tri[(i + 1) % 3]);
                    m[i] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                        let (pa, pb) = (p[a as usize], p[b as usize]);
                        p.push(norm([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]]));
                        (p.len() - 1) as u32
                    });
                }
                next.push([tri[0], m[0], m[2]]);
                next.push([tri[1], m[1], m[0]]);
                next.push([tri[2], m[2], m[1]]);
                next.push([m[0], m[1], m[2]]);
            }
            t = next;
        }
        Mesh {
            positions: p,
            triangles: t,
            ..Mesh::default()
        }
    }

    /// The three corner positions of a face.
    pub fn corners(&self, f: usize) -> [[f32; 3]; 3] {
        let t = self.triangles[f];
        [
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
        ]
    }

    /// Unnormalised face normal (twice the area in length).
    pub fn face_cross(&self, f: usize) -> [f32; 3] {
        let [a, b, c] = self.corners(f).map(Vec3::from);
        (b - a).cross(c - a).to_array()
    }

    /// Face area.
    pub fn face_area(&self, f: usize) -> f32 {
        0.5 * Vec3::from(self.face_cross(f)).length()
    }

    /// Unit face normal (zero for a degenerate face).
    pub fn face_normal(&self, f: usize) -> [f32; 3] {
        unit_or(self.face_cross(f).into(), Vec3::ZERO).to_array()
    }

    /// Area-weighted unit vertex normals.
    pub fn vertex_normals(&self) -> Vec<[f32; 3]> {
        let mut n = vec![Vec3::ZERO; self.positions.len()];
        for f in 0..self.triangles.len() {
            let c = Vec3::from(self.face_cross(f));
            for &v in &self.triangles[f] {
                n[v as usize] += c;
            }
        }
        n.into_iter().map(|v| unit_or(v, Vec3::ZERO).to_array()).collect()
    }

    /// Length of the bounding-box diagonal.
    pub fn bbox_diagonal(&self) -> f32 {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if self.positions.is_empty() {
            0.0
        } else {
            (Vec3::from(hi) - Vec3::from(lo)).length()
        }
    }

    /// Rescales a mesh of extreme size so that the atlas computations (which
    /// work in f32 and have absolute thresholds) see ordinary numbers: if the
    /// bounding-box diagonal lies outside [2⁻²⁰, 2²⁰] (about 1e-6 to 1e6
    /// units), every position is multiplied by the power of two that brings
    /// the diagonal nearest to 1. Returns the factor that maps the rescaled
    /// positions back to the user's units (1.0 if nothing changed). Scaling
    /// by a power of two is exact, so mapping back restores the input bits
    /// (barring f32 denormals).
    pub fn normalize_extreme_scale(&mut self) -> f64 {
        let scale = extreme_scale(&self.positions);
        if scale == 1.0 {
            return 1.0;
        }
        for p in &mut self.positions {
            *p = p.map(|c| (c as f64 * scale) as f32);
        }
        1.0 / scale
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|f| self.face_area(f) as f64).sum()
    }

    /// Face adjacency and components. Edges shared by more than two faces
    /// (which [`repair`] removes) are treated as boundaries.
    pub fn topology(&self) -> Topology {
        let nf = self.triangles.len();
        // (min vertex, max vertex, face, edge) sorted: equal keys are one edge
        let mut edges: Vec<(u32, u32, u32, u8)> = Vec::with_capacity(nf * 3);
        for (f, t) in self.triangles.iter().enumerate() {
            for i in 0..3 {
                let (a, b) = (t[i], t[(i + 1) % 3]);
                edges.push((a.min(b), a.max(b), f as u32, i as u8));
            }
        }
        edges.sort_unstable();
        let mut face_adjacency = vec![[NO_FACE; 3]; nf];
        let mut i = 0;
        while i < edges.len() {
            let mut j = i + 1;
            while j < edges.len() && edges[j].0 == edges[i].0 && edges[j].1 == edges[i].1 {
                j += 1;
            }
            if j - i == 2 {
                let (e0, e1) = (edges[i], edges[i + 1]);
                face_adjacency[e0.2 as usize][e0.3 as usize] = e1.2;
                face_adjacency[e1.2 as usize][e1.3 as usize] = e0.2;
            }
            i = j;
        }
        let mut face_component = vec![u32::MAX; nf];
        let mut components = 0u32;
        let mut stack = Vec::new();
        for start in 0..nf {
            if face_component[start] != u32::MAX {
                continue;
            }
            face_component[start] = components;
            stack.push(start as u32);
            while let Some(f) = stack.pop() {
                for &g in &face_adjacency[f as usize] {
                    if g != NO_FACE && face_component[g as usize] == u32::MAX {
                        face_component[g as usize] = components;
                        stack.push(g);
                    }
                }
            }
            components += 1;
        }
        Topology {
            face_adjacency,
            face_component,
            components: components as usize,
        }
    }
}
