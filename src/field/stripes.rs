//! The smoothest stripe pattern along a field (F. Knöppel, K. Crane, U.
//! Pinkall, P. Schröder, "Stripe Patterns on Surfaces", ACM TOG 34(4),
//! 2015), for a sample whose features run in rows (brick courses, lines of
//! text) laid along the field with the rows `period` mesh units apart.
//! Rows cannot stay unbroken wherever the field's lines converge or
//! diverge, nor around its singularities; the smoothest pattern places the
//! fewest such ends its energy allows, letting the row spacing vary where
//! that costs less than an end. [`forced_ends`] counts them, a reference
//! for what a tiling that follows the field shows; [`StripePattern`] gives
//! the phase of the same pattern, its row spacing evened by inverse
//! iterations at unit modulus, anywhere on the surface, which `tile
//! --courses locked` lays every patch's rows along.
//!
//! The pattern is a complex value ψ per vertex whose argument is the row
//! phase. Its energy Σ_ij w_ij |ψ_j − e^{iω_ij} ψ_i|² (cotangent weights
//! w_ij, ω_ij the phase the rows should gain along edge ij: 2π/period
//! times the edge's length across the field) is minimised over unit
//! mass-norm ψ, the smallest eigenvector of its Hermitian form against the
//! lumped vertex masses, found by inverse iteration. A face where the
//! corrected phase differences around its edges add up to ±2π·k holds k
//! row ends (the paper's singular faces). The mesh is subdivided until its
//! edges are a third of `period` long on average.

use glam::DVec3;

use crate::math;
use crate::mesh::Mesh;
use crate::{Error, Result};

/// How the forced ends were counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ForcedEnds {
    /// Row ends: the sum over faces of |winding| of the smoothest pattern.
    pub ends: usize,
    /// Midpoint subdivisions applied to the mesh.
    pub subdivisions: usize,
    /// Vertices of the subdivided mesh.
    pub vertices: usize,
}

/// Inverse iterations; the count settles long before.
const ITERATIONS: usize = 40;

/// Inverse iterations of [`StripePattern`]'s ψ held at unit modulus
/// after the eigenvector: its row spacing settles within them (on Spot,
/// the share of the surface whose rows are more than 15 % closer or
/// wider than the period falls from 19 % to 9 % in five, 8 % in twenty;
/// coherence with the brick wall is the same for both).
const EVEN_ITERATIONS: usize = 5;

/// Vertices past which the mesh is not subdivided further (the count on a
/// coarser mesh differs by a few per cent).
pub const MAX_VERTICES: usize = 100_000;

/// Memory the solve takes per vertex of the subdivided mesh (measured:
/// about 2.9 kB on Spot).
pub const BYTES_PER_VERTEX: u64 = 3 << 10;

/// The row ends that rows `period` mesh units apart, laid along `field`
/// (one unit tangent per face of `mesh`), must show. The mesh is
/// subdivided by its geometry alone, never past [`MAX_VERTICES`], so the
/// count is the same for any budget; a solve that would take more than
/// `budget` bytes (its share of a `--memory` of `memory` bytes, which the
/// message scales to the `--memory` that would do) is refused.
/// Deterministic.
pub fn forced_ends(
    mesh: &Mesh,
    field: &[[f32; 3]],
    period: f64,
    budget: u64,
    memory: u64,
) -> Result<ForcedEnds> {
    let fine = Subdivided::new(
        mesh,
        field,
        period,
        (budget, memory),
        "counting the course ends the field forces",
    )?;
    let (subdivisions, vertices) = (fine.subdivisions, fine.positions.len());
    let ends = match Solved::new(&fine, period, 0) {
        Some(solved) => solved.count_ends(&fine),
        None => 0,
    };
    Ok(ForcedEnds {
        ends,
        subdivisions,
        vertices,
    })
}

/// The smoothest stripe pattern along a field, its row spacing evened: the
/// row phase anywhere on the surface. Tiling with `--courses locked` bends every work image so
/// that its rows follow this phase (section III-B's work image, with its
/// across-field coordinate taken from the pattern).
pub struct StripePattern {
    fine: Subdivided,
    /// Rows are this many mesh units apart.
    period: f64,
    /// Per vertex of the subdivided mesh: ψ as (re, im) pairs.
    psi: Vec<f64>,
    /// Per face of the subdivided mesh: the unit direction across the field.
    across: Vec<DVec3>,
    /// 2π / period.
    nu: f64,
    /// Row ends (counted as [`forced_ends`] counts them).
    ends: usize,
}

impl StripePattern {
    /// The smoothest pattern of rows `period` mesh units apart along
    /// `field` (one unit tangent per face of `mesh`), its spacing evened by
    /// unit-modulus iterations; the mesh subdivided
    /// as for [`forced_ends`], a solve over `budget` bytes (of `memory`)
    /// refused. `None` when the form cannot be factorized (a degenerate
    /// mesh).
    pub fn new(
        mesh: &Mesh,
        field: &[[f32; 3]],
        period: f64,
        budget: u64,
        memory: u64,
    ) -> Result<Option<StripePattern>> {
        let fine = Subdivided::new(
            mesh,
            field,
            period,
            (budget, memory),
            "locking the courses to the field",
        )?;
        Ok(Solved::new(&fine, period, EVEN_ITERATIONS).map(|solved| StripePattern::of(fine, period, solved)))
    }

    /// The pattern of [`StripePattern::new`] for the same mesh, field and
    /// period from its stored ψ ([`StripePattern::psi`], in single
    /// precision), without solving: the subdivision and the field across
    /// each face are derived again. `None` when `psi` does not hold a pair
    /// per vertex of the subdivided mesh (another mesh's or period's).
    pub fn from_psi(
        mesh: &Mesh,
        field: &[[f32; 3]],
        period: f64,
        psi: &[f32],
    ) -> Result<Option<StripePattern>> {
        let fine = Subdivided::new(
            mesh,
            field,
            period,
            (u64::MAX, u64::MAX),
            "a stored stripe pattern",
        )?;
        if psi.len() != 2 * fine.positions.len() {
            return Ok(None);
        }
        let solved = Solved {
            form: Form::new(&fine, period),
            psi: psi.iter().map(|&x| f64::from(x)).collect(),
        };
        Ok(Some(StripePattern::of(fine, period, solved)))
    }

    fn of(fine: Subdivided, period: f64, solved: Solved) -> StripePattern {
        StripePattern {
            ends: solved.count_ends(&fine),
            psi: solved.psi,
            across: solved.form.face_across,
            fine,
            period,
            nu: std::f64::consts::TAU / period,
        }
    }

    /// ψ as (re, im) pairs per vertex of the subdivided mesh: what a quilt
    /// stores so that strokes painted on it need not solve again
    /// ([`StripePattern::from_psi`]).
    pub fn psi(&self) -> &[f64] {
        &self.psi
    }

    /// The rows' spacing, in mesh units.
    pub fn period(&self) -> f64 {
        self.period
    }

    /// The row ends the pattern holds: those [`forced_ends`] counts at the
    /// same period, or a few fewer where the evening paired some off.
    pub fn ends(&self) -> usize {
        self.ends
    }

    /// The row phase (radians, in (−π, π]) at point `p` of face `face` of
    /// the original mesh: the face's child holding `p` found through the
    /// midpoint subdivisions, then ψ of its corners carried to `p` along
    /// the rows (ψ_k e^{iν n·(p − p_k)}, n across the field) and averaged
    /// by barycentric weight.
    pub fn phase(&self, face: usize, p: [f64; 3]) -> f64 {
        let fine = &self.fine;
        let p = DVec3::from(p);
        // child k of a face keeps the face's corner k
        let corner = |k: usize| {
            let mut g = face;
            for _ in 0..fine.subdivisions {
                g = 4 * g + k;
            }
            fine.positions[fine.triangles[g][k] as usize]
        };
        let mut bc = barycentric(p, [corner(0), corner(1), corner(2)]);
        let mut f = face;
        for _ in 0..fine.subdivisions {
            // the children [a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]
            let (k, next) = if bc[0] >= 0.5 {
                (0, [2.0 * bc[0] - 1.0, 2.0 * bc[1], 2.0 * bc[2]])
            } else if bc[1] >= 0.5 {
                (1, [2.0 * bc[0], 2.0 * bc[1] - 1.0, 2.0 * bc[2]])
            } else if bc[2] >= 0.5 {
                (2, [2.0 * bc[0], 2.0 * bc[1], 2.0 * bc[2] - 1.0])
            } else {
                (3, [1.0 - 2.0 * bc[2], 1.0 - 2.0 * bc[0], 1.0 - 2.0 * bc[1]])
            };
            f = 4 * f + k;
            bc = next;
        }
        let n = self.across[f];
        let (mut re, mut im) = (0.0, 0.0);
        for (k, &v) in fine.triangles[f].iter().enumerate() {
            let v = v as usize;
            let (s, c) = math::sin_cos(self.nu * n.dot(p - fine.positions[v]));
            let (x, y) = (self.psi[2 * v], self.psi[2 * v + 1]);
            re += bc[k] * (x * c - y * s);
            im += bc[k] * (x * s + y * c);
        }
        math::atan2(im, re)
    }
}

/// Barycentric coordinates of `p` (projected onto the triangle's plane)
/// in triangle `c`, clamped into the triangle.
fn barycentric(p: DVec3, c: [DVec3; 3]) -> [f64; 3] {
    let (v0, v1, v2) = (c[1] - c[0], c[2] - c[0], p - c[0]);
    let (d00, d01, d11) = (v0.dot(v0), v0.dot(v1), v1.dot(v1));
    let (d20, d21) = (v2.dot(v0), v2.dot(v1));
    let den = d00 * d11 - d01 * d01;
    if !(den.abs() > 0.0) {
        return [1.0 / 3.0; 3];
    }
    let l1 = ((d11 * d20 - d01 * d21) / den).clamp(0.0, 1.0);
    let l2 = ((d00 * d21 - d01 * d20) / den).clamp(0.0, 1.0 - l1);
    [1.0 - l1 - l2, l1, l2]
}

/// The mesh midpoint-subdivided until its edges are a third of the period
/// long on average (never past [`MAX_VERTICES`]), the field carried to the
/// children.
struct Subdivided {
    positions: Vec<DVec3>,
    triangles: Vec<[u32; 3]>,
    field: Vec<DVec3>,
    subdivisions: usize,
}

impl Subdivided {
    /// Refuses a non-positive period, a field of the wrong length, and a
    /// solve over `budget` bytes, the step's share of a `--memory` of
    /// `memory` bytes (`what` names the step in the message).
    fn new(
        mesh: &Mesh,
        field: &[[f32; 3]],
        period: f64,
        (budget, memory): (u64, u64),
        what: &str,
    ) -> Result<Subdivided> {
        if !(period.is_finite() && period > 0.0) {
            return Err(Error::Config(format!(
                "row period {period}: must be a positive number of mesh units"
            )));
        }
        if field.len() != mesh.triangles.len() {
            return Err(Error::Config(format!(
                "the field has {} directions for {} faces",
                field.len(),
                mesh.triangles.len()
            )));
        }
        let mut positions: Vec<DVec3> = mesh
            .positions
            .iter()
            .map(|p| DVec3::from(p.map(f64::from)))
            .collect();
        let mut triangles = mesh.triangles.clone();
        let mut field: Vec<DVec3> = field.iter().map(|f| DVec3::from(f.map(f64::from))).collect();
        let mut subdivisions = 0;
        loop {
            let edges = edge_list(&triangles);
            let mean = edges
                .iter()
                .map(|&(a, b)| positions[a as usize].distance(positions[b as usize]))
                .sum::<f64>()
                / edges.len().max(1) as f64;
            if mean <= period / 3.0 || positions.len() + edges.len() > MAX_VERTICES {
                break;
            }
            (positions, triangles, field) = subdivide(&positions, &triangles, &field, &edges);
            subdivisions += 1;
        }
        let vertices = positions.len();
        let needed = vertices as u64 * BYTES_PER_VERTEX;
        if needed > budget {
            let mib = |b: u64| b.div_ceil(1 << 20);
            // the step's share grows with --memory in proportion
            let enough = (needed as u128 * memory as u128).div_ceil(budget.max(1) as u128);
            return Err(Error::Config(format!(
                "{what} solves on {vertices} vertices, about {} MiB, \
                 more than the {} MiB this step may use of --memory {}MiB: give --memory {}MiB or more",
                mib(needed),
                mib(budget),
                mib(memory),
                mib(enough.min(u64::MAX as u128) as u64)
            )));
        }
        Ok(Subdivided {
            positions,
            triangles,
            field,
            subdivisions,
        })
    }
}

/// The mesh's edges as sorted (low, high) vertex pairs, each once.
fn edge_list(triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut e: Vec<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    e.sort_unstable();
    e.dedup();
    e
}

fn edge_index(edges: &[(u32, u32)], a: u32, b: u32) -> usize {
    edges
        .binary_search(&(a.min(b), a.max(b)))
        .expect("an edge of the mesh")
}

/// One midpoint subdivision (each face into four); the new faces keep
/// their parent's field direction.
fn subdivide(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    field: &[DVec3],
    edges: &[(u32, u32)],
) -> (Vec<DVec3>, Vec<[u32; 3]>, Vec<DVec3>) {
    let n = positions.len() as u32;
    let mut p = positions.to_vec();
    p.extend(
        edges
            .iter()
            .map(|&(a, b)| 0.5 * (positions[a as usize] + positions[b as usize])),
    );
    let mut t = Vec::with_capacity(4 * triangles.len());
    let mut f = Vec::with_capacity(4 * triangles.len());
    for (tri, dir) in triangles.iter().zip(field) {
        let m = |k: usize| n + edge_index(edges, tri[k], tri[(k + 1) % 3]) as u32;
        let (ab, bc, ca) = (m(0), m(1), m(2));
        for c in [[tri[0], ab, ca], [ab, tri[1], bc], [ca, bc, tri[2]], [ab, bc, ca]] {
            t.push(c);
            f.push(*dir);
        }
    }
    (p, t, f)
}

/// Half the cotangent of triangle `c`'s angle opposite its edge from
/// corner `k` to corner k + 1: that edge's share of the cotangent weight
/// from this triangle.
fn half_cotangent(c: [DVec3; 3], k: usize) -> f64 {
    let o = (k + 2) % 3;
    let (u, v) = (c[k] - c[o], c[(k + 1) % 3] - c[o]);
    0.5 * u.dot(v) / u.cross(v).length().max(1e-300)
}

/// The pattern's form on a subdivided mesh: its edges with the phase ω
/// the rows gain along each and its cotangent weight, the direction across
/// the field per face and the lumped vertex masses.
struct Form {
    edges: Vec<(u32, u32)>,
    /// ω along each edge from its low to its high vertex.
    omega: Vec<f64>,
    weight: Vec<f64>,
    face_across: Vec<DVec3>,
    mass: Vec<f64>,
}

impl Form {
    fn new(fine: &Subdivided, period: f64) -> Form {
        use std::f64::consts::TAU;
        let (positions, triangles) = (&fine.positions, &fine.triangles);
        let nv = positions.len();
        let nu = TAU / period;
        let edges = edge_list(triangles);
        // per edge: cotangent weight and the sum of its faces' across-field directions
        let mut weight = vec![0f64; edges.len()];
        let mut across = vec![DVec3::ZERO; edges.len()];
        let mut face_across = Vec::with_capacity(triangles.len());
        let mut mass = vec![0f64; nv];
        for (t, dir) in triangles.iter().zip(&fine.field) {
            let c = t.map(|v| positions[v as usize]);
            let normal = (c[1] - c[0]).cross(c[2] - c[0]);
            let area = 0.5 * normal.length();
            let n = normal.normalize_or_zero().cross(*dir).normalize_or_zero();
            face_across.push(n);
            for k in 0..3 {
                mass[t[k] as usize] += area / 3.0;
                let e = edge_index(&edges, t[k], t[(k + 1) % 3]);
                weight[e] += half_cotangent(c, k);
                across[e] += n;
            }
        }
        let omega: Vec<f64> = edges
            .iter()
            .zip(&across)
            .map(|(&(a, b), n)| {
                nu * n
                    .normalize_or_zero()
                    .dot(positions[b as usize] - positions[a as usize])
            })
            .collect();
        Form {
            edges,
            omega,
            weight,
            face_across,
            mass,
        }
    }
}

/// The smoothest stripe pattern's solve on a subdivided mesh: its form
/// and ψ.
struct Solved {
    form: Form,
    /// ψ as (re, im) pairs per vertex, unit in the mass norm.
    psi: Vec<f64>,
}

impl Solved {
    /// The smallest eigenvector of the pattern's Hermitian form against
    /// the lumped masses, by inverse iteration, then `even` inverse
    /// iterations each started from ψ scaled to unit modulus at every
    /// vertex; `None` if the form cannot be factorized or the iteration
    /// collapses.
    ///
    /// The eigenvector's modulus is uneven: where it is small the energy
    /// barely holds the phase, and rows bunch or spread there. The rows
    /// follow the phase alone, so the later iterations weigh every vertex
    /// alike (a projected power iteration for the energy over unit-modulus
    /// ψ): the row spacing evens out and the ends stay where they were or
    /// a few pair off.
    fn new(fine: &Subdivided, period: f64, even: usize) -> Option<Solved> {
        use std::f64::consts::TAU;
        let nv = fine.positions.len();
        let nu = TAU / period;
        let form = Form::new(fine, period);
        let (edges, omega, weight, mass) = (&form.edges, &form.omega, &form.weight, &form.mass);
        let total_mass: f64 = mass.iter().sum();
        let floor = 1e-9 * total_mass / nv.max(1) as f64;
        // the real 2V × 2V form (upper triangle) of A + shift·M; a negative
        // cotangent weight (an obtuse pair) is clamped to keep A positive
        let mut diagonal: Vec<f64> = mass.iter().map(|m| 1e-4 * nu * nu * m.max(floor)).collect();
        let mut upper = Vec::with_capacity(edges.len());
        for ((&(i, j), &w), &om) in edges.iter().zip(weight).zip(omega) {
            let w = w.max(1e-6);
            let (i, j) = (i as usize, j as usize);
            diagonal[i] += w;
            diagonal[j] += w;
            // entry (i, j) = −w e^{−iω}
            upper.push((i, j, -w * math::cos(om), w * math::sin(om)));
        }
        let factor = super::factorize_hermitian(&upper, &diagonal)?;
        let mut psi: Vec<f64> = (0..2 * nv)
            .map(|k| (k as f64 * 0.618_034).fract() - 0.5)
            .collect();
        for k in 0..ITERATIONS + even {
            if k >= ITERATIONS {
                for v in psi.chunks_exact_mut(2) {
                    let m = math::hypot(v[0], v[1]);
                    if m > 0.0 {
                        v.iter_mut().for_each(|x| *x /= m);
                    }
                }
            }
            let b: Vec<f64> = (0..2 * nv).map(|k| mass[k / 2] * psi[k]).collect();
            psi = factor.solve(b);
            let norm = (0..nv)
                .map(|i| mass[i] * (psi[2 * i].powi(2) + psi[2 * i + 1].powi(2)))
                .sum::<f64>()
                .sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return None;
            }
            psi.iter_mut().for_each(|x| *x /= norm);
        }
        Some(Solved { form, psi })
    }

    /// Σ |winding| over the faces: the row ends.
    fn count_ends(&self, fine: &Subdivided) -> usize {
        use std::f64::consts::TAU;
        let (edges, omega, psi) = (&self.form.edges, &self.form.omega, &self.psi);
        let arg = |v: u32| math::atan2(psi[2 * v as usize + 1], psi[2 * v as usize]);
        let mut ends = 0usize;
        for t in &fine.triangles {
            let mut turn = 0.0;
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = edge_index(edges, a, b);
                let om = if a < b { omega[e] } else { -omega[e] };
                turn += om + super::wrap_angle(arg(b) - arg(a) - om);
            }
            ends += (turn / TAU).round().abs() as usize;
        }
        ends
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A UV sphere of radius 1: `rings` × `segments` quads split in two.
    fn sphere(rings: usize, segments: usize) -> Mesh {
        let mut m = Mesh::default();
        m.positions.push([0.0, 0.0, 1.0]);
        for r in 1..rings {
            let th = std::f64::consts::PI * r as f64 / rings as f64;
            for s in 0..segments {
                let ph = std::f64::consts::TAU * s as f64 / segments as f64;
                m.positions.push([
                    (math::sin(th) * math::cos(ph)) as f32,
                    (math::sin(th) * math::sin(ph)) as f32,
                    math::cos(th) as f32,
                ]);
            }
        }
        m.positions.push([0.0, 0.0, -1.0]);
        let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
        let south = (m.positions.len() - 1) as u32;
        for s in 0..segments {
            m.triangles.push([0, ring(1, s), ring(1, s + 1)]);
            m.triangles
                .push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
        }
        for r in 1..rings - 1 {
            for s in 0..segments {
                let (a, b, c, d) = (ring(r, s), ring(r + 1, s), ring(r + 1, s + 1), ring(r, s + 1));
                m.triangles.push([a, b, c]);
                m.triangles.push([a, c, d]);
            }
        }
        m
    }

    /// Per face: the unit tangent along the latitude circle (east), or along
    /// the meridian (south).
    fn sphere_field(m: &Mesh, east: bool) -> Vec<[f32; 3]> {
        (0..m.triangles.len())
            .map(|f| {
                let c = m.triangles[f].map(|v| DVec3::from(m.positions[v as usize].map(f64::from)));
                let p = ((c[0] + c[1] + c[2]) / 3.0).normalize();
                let e = DVec3::Z.cross(p).normalize();
                let d = if east { e } else { p.cross(e) };
                d.as_vec3().to_array()
            })
            .collect()
    }

    /// The unit square in the z = 0 plane, `n` × `n` quads split in two,
    /// wound counter-clockwise (normal +z).
    fn unit_square(n: usize) -> Mesh {
        let mut m = Mesh::default();
        for y in 0..=n {
            for x in 0..=n {
                m.positions.push([x as f32 / n as f32, y as f32 / n as f32, 0.0]);
            }
        }
        let w = (n + 1) as u32;
        for y in 0..n as u32 {
            for x in 0..n as u32 {
                let i = y * w + x;
                m.triangles.push([i, i + 1, i + w + 1]);
                m.triangles.push([i, i + w + 1, i + w]);
            }
        }
        m
    }

    #[test]
    fn rows_on_a_plane_never_end() {
        let m = unit_square(12);
        let field = vec![[0.6f32, 0.8, 0.0]; m.triangles.len()];
        let r = forced_ends(&m, &field, 0.07, u64::MAX, u64::MAX).unwrap();
        assert_eq!(r.ends, 0);
        assert!(r.subdivisions >= 1, "edges of 1/12 are longer than 0.07 / 4");
    }

    #[test]
    fn rows_must_end_where_the_field_converges() {
        // rows along the latitude circles stay parallel (spacing measured
        // along the meridians); rows along the meridians converge at the
        // poles, where all of them must end: 2π / period rows cross the
        // equator, so at least that many ends in each hemisphere
        let m = sphere(24, 48);
        let period = 0.35;
        let along_latitudes = forced_ends(&m, &sphere_field(&m, true), period, u64::MAX, u64::MAX).unwrap();
        assert!(along_latitudes.ends <= 2, "{along_latitudes:?}");
        let along_meridians = forced_ends(&m, &sphere_field(&m, false), period, u64::MAX, u64::MAX).unwrap();
        let crossing = std::f64::consts::TAU / period;
        assert!(
            along_meridians.ends as f64 >= 2.0 * crossing - 2.0,
            "{along_meridians:?} < 2 × {crossing:.1}"
        );
        assert!(
            along_meridians.ends as f64 <= 3.0 * crossing,
            "{along_meridians:?}"
        );
    }

    /// `n` seeded points on `m`: a face and a point inside it.
    fn points_on(m: &Mesh, seed: u64, n: usize) -> Vec<(usize, DVec3)> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                state = crate::rng::mix64(state);
                let f = (state % m.triangles.len() as u64) as usize;
                let (a, b) = (
                    (state >> 20) as f64 / (1u64 << 44) as f64,
                    (state >> 40) as f64 / (1u64 << 24) as f64,
                );
                let (a, b) = if a + b > 1.0 { (1.0 - a, 1.0 - b) } else { (a, b) };
                let c = m.triangles[f].map(|v| DVec3::from(m.positions[v as usize].map(f64::from)));
                (f, c[0] + a * (c[1] - c[0]) + b * (c[2] - c[0]))
            })
            .collect()
    }

    /// On a plane with a constant field the smoothest pattern is the plane
    /// wave e^{iν n·p} (its energy is zero): the phase anywhere, found
    /// through the subdivisions, is ν n·p up to one constant.
    #[test]
    fn the_pattern_on_a_plane_is_a_plane_wave() {
        let m = unit_square(10);
        let field = vec![[0.6f32, 0.8, 0.0]; m.triangles.len()];
        let period = 0.13;
        let pattern = StripePattern::new(&m, &field, period, u64::MAX, u64::MAX)
            .unwrap()
            .unwrap();
        assert!(pattern.fine.subdivisions >= 1);
        // across the field: N × f with N = +z
        let across = DVec3::new(-0.8, 0.6, 0.0);
        let nu = std::f64::consts::TAU / period;
        let mut offset = None;
        for (f, p) in points_on(&m, 7, 400) {
            let d = crate::field::wrap_angle(pattern.phase(f, p.to_array()) - nu * across.dot(p));
            let o = *offset.get_or_insert(d);
            assert!(
                crate::field::wrap_angle(d - o).abs() < 1e-6,
                "face {f} at {p}: {d} against {o}"
            );
        }
    }

    /// A pattern rebuilt from its ψ stored in single precision (as a quilt
    /// stores it) is the solved one: the same ends, the phase within
    /// 1e-5 rad anywhere; ψ of another subdivision is refused.
    #[test]
    fn a_stored_pattern_is_the_solved_one() {
        let m = sphere(16, 32);
        let field = sphere_field(&m, false);
        let period = 0.4;
        let solved = StripePattern::new(&m, &field, period, u64::MAX, u64::MAX)
            .unwrap()
            .unwrap();
        let psi: Vec<f32> = solved.psi().iter().map(|&x| x as f32).collect();
        let stored = StripePattern::from_psi(&m, &field, period, &psi)
            .unwrap()
            .unwrap();
        assert!(solved.ends() > 10, "rows along the meridians end at the poles");
        assert_eq!(stored.ends(), solved.ends());
        assert_eq!(stored.period(), period);
        let mut worst = 0f64;
        for (f, p) in points_on(&m, 11, 2000) {
            let p = p.to_array();
            worst = worst.max(crate::field::wrap_angle(stored.phase(f, p) - solved.phase(f, p)).abs());
        }
        assert!(worst < 1e-5, "phase off by {worst} rad");
        // another period subdivides differently: its ψ does not fit
        let other = StripePattern::new(&m, &field, period / 3.0, u64::MAX, u64::MAX)
            .unwrap()
            .unwrap();
        let psi: Vec<f32> = other.psi().iter().map(|&x| x as f32).collect();
        assert_ne!(psi.len(), stored.psi().len());
        assert!(StripePattern::from_psi(&m, &field, period, &psi)
            .unwrap()
            .is_none());
    }

    /// The area share of `fine`'s faces (those holding no end) whose rows
    /// lie more than 15 % closer or wider than the period: |∇ arg ψ| / ν
    /// outside [1/1.18, 1.18].
    fn spacing_off(fine: &Subdivided, solved: &Solved, nu: f64) -> f64 {
        let arg = |v: u32| math::atan2(solved.psi[2 * v as usize + 1], solved.psi[2 * v as usize]);
        let (mut off, mut total) = (0.0, 0.0);
        for t in &fine.triangles {
            let c = t.map(|v| fine.positions[v as usize]);
            let (e1, e2) = (c[1] - c[0], c[2] - c[0]);
            let (d1, d2) = (
                crate::field::wrap_angle(arg(t[1]) - arg(t[0])),
                crate::field::wrap_angle(arg(t[2]) - arg(t[0])),
            );
            if (d1 + crate::field::wrap_angle(arg(t[2]) - arg(t[1])) - d2).abs() > std::f64::consts::PI {
                continue; // the phase winds around the face: it holds an end
            }
            let (g11, g12, g22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
            let det = g11 * g22 - g12 * g12;
            let grad = ((g22 * d1 * d1 - 2.0 * g12 * d1 * d2 + g11 * d2 * d2) / det).sqrt();
            let area = 0.5 * e1.cross(e2).length();
            total += area;
            if !(1.0 / 1.18..=1.18).contains(&(grad / nu)) {
                off += area;
            }
        }
        off / total
    }

    /// The pattern's energy over its phase alone, Σ_ij w_ij |u_j −
    /// e^{iω_ij} u_i|² with u = ψ / |ψ| (the cotangent weights clamped as
    /// the solve clamps them), over the total mass: what the rows see.
    fn phase_energy(solved: &Solved) -> f64 {
        let unit = |v: usize| {
            let (x, y) = (solved.psi[2 * v], solved.psi[2 * v + 1]);
            let m = math::hypot(x, y);
            (x / m, y / m)
        };
        let form = &solved.form;
        let mass: f64 = form.mass.iter().sum();
        let mut e = 0.0;
        for ((&(a, b), &w), &om) in form.edges.iter().zip(&form.weight).zip(&form.omega) {
            let ((xa, ya), (xb, yb)) = (unit(a as usize), unit(b as usize));
            let (c, s) = (math::cos(om), math::sin(om));
            e += w.max(1e-6) * ((xb - (c * xa - s * ya)).powi(2) + (yb - (s * xa + c * ya)).powi(2));
        }
        e / mass
    }

    /// Rows along the meridians converge towards the poles and must end
    /// there; away from the ends the eigenvector lets them bunch and
    /// spread where its modulus is small. The unit-modulus iterations
    /// lower the energy the phase alone has and hold more of the rows
    /// near the period, without adding ends.
    #[test]
    fn evened_rows_keep_nearer_the_period() {
        let m = sphere(24, 48);
        let field = sphere_field(&m, false);
        let period = 0.35;
        let fine = Subdivided::new(&m, &field, period, (u64::MAX, u64::MAX), "test").unwrap();
        let nu = std::f64::consts::TAU / period;
        let eigen = Solved::new(&fine, period, 0).unwrap();
        let even = Solved::new(&fine, period, EVEN_ITERATIONS).unwrap();
        let (before, after) = (spacing_off(&fine, &eigen, nu), spacing_off(&fine, &even, nu));
        let ends = (eigen.count_ends(&fine), even.count_ends(&fine));
        let energy = (phase_energy(&eigen), phase_energy(&even));
        eprintln!("spacing off: {before:.3} → {after:.3}; ends {ends:?}; phase energy {energy:?}");
        assert!(after < before, "{before} → {after}");
        assert!(energy.1 < 0.5 * energy.0, "{energy:?}");
        assert!(ends.1 <= ends.0, "{ends:?}");
    }

    #[test]
    fn bad_periods_are_refused() {
        let m = sphere(4, 8);
        let f = sphere_field(&m, true);
        for p in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(forced_ends(&m, &f, p, u64::MAX, u64::MAX).is_err());
        }
        assert!(forced_ends(&m, &f[1..], 0.5, u64::MAX, u64::MAX).is_err());
        // a step given 1 KiB of a 4 KiB --memory: four times what it needs
        let needed = match forced_ends(&m, &f, 0.5, u64::MAX, u64::MAX) {
            Ok(r) => r.vertices as u64 * BYTES_PER_VERTEX,
            Err(e) => panic!("{e}"),
        };
        let e = forced_ends(&m, &f, 0.5, 1 << 10, 4 << 10)
            .unwrap_err()
            .to_string();
        let enough = format!("give --memory {}MiB or more", (needed * 4).div_ceil(1 << 20));
        assert!(e.contains(&enough), "{e} (expected '{enough}')");
        for p in [0.0, -1.0, f64::NAN] {
            assert!(StripePattern::new(&m, &f, p, u64::MAX, u64::MAX).is_err());
        }
        let e = StripePattern::new(&m, &f, 0.5, 1 << 10, 1 << 20)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("locking the courses") && e.contains("--memory 1MiB: give --memory"),
            "{e}"
        );
    }
}
