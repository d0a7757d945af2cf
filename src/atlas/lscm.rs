//! Least-squares conformal maps (Lévy, Petitjean, Ray, Maillot 2002, "Least
//! Squares Conformal Maps for Automatic Texture Atlas Generation") and the
//! distortion measures used to judge a parameterisation (texture stretch of
//! Sander, Snyder, Gortler, Hoppe 2001, "Texture Mapping Progressive Meshes").

use crate::{Error, Result};
use faer::sparse::{SparseColMat, Triplet};
use glam::DVec3;

use crate::mesh::to_dvec3;
use crate::sparse::SpdFactor;

/// Above this many boundary vertices the farthest pair is found by repeated
/// double sweeps instead of all pairs.
const EXACT_PAIR_LIMIT: usize = 3000;

/// The triangle in its own orthonormal frame (first corner at the origin,
/// first edge along +x, counter-clockwise), and its area.
pub(crate) fn local_frame(p: [DVec3; 3]) -> ([[f64; 2]; 3], f64) {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let l1 = e1.length();
    let n = e1.cross(e2);
    let twice_area = n.length();
    if l1 == 0.0 || twice_area == 0.0 {
        return ([[0.0; 2]; 3], 0.0);
    }
    let x = e1 / l1;
    let y = (n / twice_area).cross(x);
    ([[0.0, 0.0], [l1, 0.0], [e2.dot(x), e2.dot(y)]], 0.5 * twice_area)
}

/// Whether a triangle is too thin to carry a conformality constraint
/// (area below 1e-12 of its longest edge squared).
pub(crate) fn degenerate(p: [DVec3; 3], area: f64) -> bool {
    let l = p[0]
        .distance_squared(p[1])
        .max(p[1].distance_squared(p[2]))
        .max(p[2].distance_squared(p[0]));
    !positive(area - 1e-12 * l)
}

/// `x > 0`, false for NaN.
fn positive(x: f64) -> bool {
    x > 0.0
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let g = parent[parent[x as usize] as usize];
        parent[x as usize] = g;
        x = g;
    }
    x
}

/// Least-squares conformal map (Lévy et al. 2002) of a triangulated disk:
/// minimises Σ_T A_T |∇u − rot90(∇v)|² with two pinned vertices (the pair of
/// boundary vertices farthest apart in 3D, pinned at (0,0) and (d,0), d their
/// 3D distance), solved as sparse normal equations with faer's sparse
/// Cholesky (LLT, sequential). `positions` are the patch's vertices,
/// `triangles` local indices. Works for any edge-connected manifold patch with
/// at least one boundary loop (no boundary is an error). Returns per-vertex
/// uv. Triangles with (near) zero area carry no constraint; vertices used by
/// no triangle get (0, 0). Errors (Error::Config with a reason) on degenerate
/// input or a failed factorisation.
pub fn lscm(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Vec<[f64; 2]>> {
    let nv = positions.len();
    if triangles.is_empty() {
        return Err(Error::Config("lscm: patch has no triangles".into()));
    }
    for t in triangles {
        if t.iter().any(|&v| v as usize >= nv) {
            return Err(Error::Config(format!(
                "lscm: triangle {t:?} indexes past {nv} vertices"
            )));
        }
        if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
            return Err(Error::Config(format!("lscm: triangle {t:?} repeats a vertex")));
        }
    }
    if positions.iter().any(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(Error::Config("lscm: non-finite vertex position".into()));
    }

    // Boundary edges: undirected edges used by exactly one triangle.
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(triangles.len() * 3);
    for t in triangles {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            edges.push((a.min(b), a.max(b)));
        }
    }
    edges.sort_unstable();
    let mut on_boundary = vec![false; nv];
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j] == edges[i] {
            j += 1;
        }
        if j - i == 1 {
            on_boundary[edges[i].0 as usize] = true;
            on_boundary[edges[i].1 as usize] = true;
        }
        i = j;
    }
    let boundary: Vec<u32> = (0..nv as u32).filter(|&v| on_boundary[v as usize]).collect();
    if boundary.is_empty() {
        return Err(Error::Config(
            "lscm: patch has no boundary (closed surface)".into(),
        ));
    }

    // Local frames; connectivity through the shared edges of usable triangles.
    let pos: Vec<DVec3> = positions.iter().map(|&p| to_dvec3(p)).collect();
    let mut frames = Vec::with_capacity(triangles.len());
    let mut used = vec![false; nv];
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    for t in triangles {
        let p = [pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]];
        let (q, area) = local_frame(p);
        if degenerate(p, area) {
            frames.push(None);
            continue;
        }
        frames.push(Some((q, area)));
        for &v in t {
            used[v as usize] = true;
        }
        let r = find(&mut parent, t[0]);
        for &v in &t[1..] {
            let s = find(&mut parent, v);
            if s != r {
                parent[s as usize] = r;
            }
        }
    }
    let mut root = None;
    for t in triangles {
        for &v in t {
            if !used[v as usize] {
                return Err(Error::Config(format!(
                    "lscm: vertex {v} lies only on degenerate (zero-area) triangles"
                )));
            }
            let r = find(&mut parent, v);
            if *root.get_or_insert(r) != r {
                return Err(Error::Config("lscm: patch is not connected".into()));
            }
        }
    }

    // Pins: the pair of boundary vertices farthest apart in 3D.
    let (pa, pb) = farthest_pair(&pos, &boundary);
    let d = pos[pa as usize].distance(pos[pb as usize]);
    if !positive(d) {
        return Err(Error::Config("lscm: boundary has zero extent".into()));
    }
    let mut pinned: Vec<Option<[f64; 2]>> = vec![None; nv];
    pinned[pa as usize] = Some([0.0, 0.0]);
    pinned[pb as usize] = Some([d, 0.0]);

    // Free unknowns: u of free vertex k at 2k, v at 2k + 1.
    let mut index = vec![u32::MAX; nv];
    let mut nfree = 0u32;
    for v in 0..nv {
        if used[v] && pinned[v].is_none() {
            index[v] = nfree;
            nfree += 1;
        }
    }
    let n = 2 * nfree as usize;
    let mut uv = vec![[0.0f64; 2]; nv];
    uv[pa as usize] = [0.0, 0.0];
    uv[pb as usize] = [d, 0.0];
    if n == 0 {
        return Ok(uv);
    }

    // Normal equations Hx = g, H = MᵀM over the free columns of the
    // conformality residual rows (two per triangle).
    let mut trip: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(triangles.len() * 42);
    let mut rhs = vec![0.0f64; n];
    for (t, fr) in triangles.iter().zip(&frames) {
        let Some((q, area)) = fr else { continue };
        let s = 0.5 / area.sqrt();
        // e_j: edge opposite corner j, counter-clockwise in the local frame.
        let mut rows = [[0.0f64; 6]; 2];
        for j in 0..3 {
            let a = q[(j + 1) % 3];
            let b = q[(j + 2) % 3];
            let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
            // r = ∇u + rot90(∇v) = (1 / 2A) Σ_j (u_j rot90(e_j) − v_j e_j)
            rows[0][2 * j] = -ey * s;
            rows[0][2 * j + 1] = -ex * s;
            rows[1][2 * j] = ex * s;
            rows[1][2 * j + 1] = -ey * s;
        }
        for row in &rows {
            for a in 0..6 {
                let va = t[a / 2] as usize;
                if pinned[va].is_some() {
                    continue;
                }
                let ia = 2 * index[va] as usize + a % 2;
                for b in 0..6 {
                    let vb = t[b / 2] as usize;
                    if let Some(p) = pinned[vb] {
                        rhs[ia] -= row[a] * row[b] * p[b % 2];
                        continue;
                    }
                    let ib = 2 * index[vb] as usize + b % 2;
                    if ia <= ib {
                        trip.push(Triplet::new(ia, ib, row[a] * row[b]));
                    }
                }
            }
        }
    }
    let h = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &trip)
        .map_err(|e| Error::Config(format!("lscm: cannot assemble the system: {e:?}")))?;
    let x = solve_spd(&h, rhs).map_err(|e| Error::Config(format!("lscm: {e}")))?;
    for v in 0..nv {
        if index[v] != u32::MAX {
            let k = 2 * index[v] as usize;
            uv[v] = [x[k], x[k + 1]];
        }
    }
    if uv.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
        return Err(Error::Config("lscm: solution is not finite".into()));
    }
    Ok(uv)
}

/// Solves H x = b for symmetric positive definite H given by its upper
/// triangle, with sequential sparse Cholesky (AMD ordering).
fn solve_spd(h: &SparseColMat<usize, f64>, b: Vec<f64>) -> std::result::Result<Vec<f64>, String> {
    Ok(SpdFactor::new(h)?.solve(b))
}

/// The pair of `candidates` farthest apart (exact for up to
/// [`EXACT_PAIR_LIMIT`] candidates, else by double sweeps). Ties keep the
/// first pair found, so the result is deterministic.
fn farthest_pair(pos: &[DVec3], candidates: &[u32]) -> (u32, u32) {
    let mut best = (candidates[0], candidates[0], -1.0f64);
    if candidates.len() <= EXACT_PAIR_LIMIT {
        for (i, &a) in candidates.iter().enumerate() {
            for &b in &candidates[i + 1..] {
                let d = pos[a as usize].distance_squared(pos[b as usize]);
                if d > best.2 {
                    best = (a, b, d);
                }
            }
        }
    } else {
        let farthest = |from: u32| {
            let mut f = (from, -1.0f64);
            for &c in candidates {
                let d = pos[from as usize].distance_squared(pos[c as usize]);
                if d > f.1 {
                    f = (c, d);
                }
            }
            f
        };
        let mut a = candidates[0];
        for _ in 0..4 {
            let (b, d) = farthest(a);
            if d > best.2 {
                best = (a, b, d);
            }
            a = b;
        }
    }
    (best.0, best.1)
}

/// Signed uv area of a triangle (positive = counter-clockwise in uv).
fn uv_area(uv: &[[f64; 2]], t: [u32; 3]) -> f64 {
    let (a, b, c) = (uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]);
    0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]))
}

fn area3(positions: &[[f32; 3]], t: [u32; 3]) -> f64 {
    let p = t.map(|v| to_dvec3(positions[v as usize]));
    0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length()
}

/// Per-triangle signed area in uv (positive = same orientation as in 3D given
/// the triangle winding); used to detect flips.
pub fn signed_uv_areas(uv: &[[f64; 2]], triangles: &[[u32; 3]]) -> Vec<f64> {
    triangles.iter().map(|&t| uv_area(uv, t)).collect()
}

/// Texture stretch (Sander et al. 2001) of a parameterisation after scaling
/// the uv so the total uv area equals the total 3D area: returns (L2, L∞)
/// where per triangle Γ, γ are the singular values of the Jacobian of the map
/// uv → 3D, L2 = sqrt(Σ A3 (Γ²+γ²)/2 / Σ A3), L∞ = max Γ over the triangles
/// of positive 3D area. Flipped or
/// degenerate uv triangles give +∞ (both measures for zero uv area under
/// positive 3D area, L∞ for a flip); triangles with zero area in both 3D and uv
/// are ignored. The total uv area is the sum of absolute triangle areas.
pub fn stretch(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> (f64, f64) {
    let mut a3_sum = 0.0;
    let mut auv_sum = 0.0;
    for &t in triangles {
        a3_sum += area3(positions, t);
        auv_sum += uv_area(uv, t).abs();
    }
    if !positive(a3_sum) || !positive(auv_sum) {
        return (f64::INFINITY, f64::INFINITY);
    }
    let mut l2_num = 0.0;
    let mut linf = 0.0f64;
    for &t in triangles {
        let a3 = area3(positions, t);
        let auv = uv_area(uv, t);
        if auv == 0.0 {
            if a3 > 0.0 {
                return (f64::INFINITY, f64::INFINITY);
            }
            continue;
        }
        if auv < 0.0 {
            linf = f64::INFINITY;
        }
        let p = t.map(|v| to_dvec3(positions[v as usize]));
        let q = [uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]];
        let ss = (p[0] * (q[1][1] - q[2][1]) + p[1] * (q[2][1] - q[0][1]) + p[2] * (q[0][1] - q[1][1]))
            / (2.0 * auv);
        let st = (p[0] * (q[2][0] - q[1][0]) + p[1] * (q[0][0] - q[2][0]) + p[2] * (q[1][0] - q[0][0]))
            / (2.0 * auv);
        let (a, b, c) = (ss.dot(ss), ss.dot(st), st.dot(st));
        l2_num += a3 * 0.5 * (a + c);
        if a3 == 0.0 {
            continue; // no surface to stretch (it weighs nothing in L2 either)
        }
        let big = (0.5 * ((a + c) + ((a - c) * (a - c) + 4.0 * b * b).sqrt())).sqrt();
        linf = linf.max(big);
    }
    // Scaling uv by s divides the Jacobian of uv → 3D by s; s² = a3 / auv.
    let k = auv_sum / a3_sum;
    ((l2_num / a3_sum * k).sqrt(), linf * k.sqrt())
}

/// Per triangle of positive 3D area, its area distortion max(r, 1/r) with
/// r = (uv area / 3D area) / (total uv area / total 3D area), and its 3D
/// area. A flipped or zero-area uv triangle gives +∞. `None` if either total
/// area is not positive.
fn area_distortions(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: &[[f64; 2]],
) -> Option<Vec<(f64, f64)>> {
    let a3: Vec<f64> = triangles.iter().map(|&t| area3(positions, t)).collect();
    let auv = signed_uv_areas(uv, triangles);
    let a3_sum: f64 = a3.iter().sum();
    let auv_sum: f64 = auv.iter().map(|a| a.abs()).sum();
    if !positive(a3_sum) || !positive(auv_sum) {
        return None;
    }
    let norm = auv_sum / a3_sum;
    Some(
        a3.iter()
            .zip(&auv)
            .filter(|(&a, _)| a > 0.0)
            .map(|(&a, &u)| {
                if u <= 0.0 {
                    return (f64::INFINITY, a);
                }
                let r = u / a / norm;
                (r.max(1.0 / r), a)
            })
            .collect(),
    )
}

/// Area distortion used for work patches: max over triangles of max(r, 1/r)
/// with r = (uv area / 3D area) / (total uv area / total 3D area). A flipped
/// or zero-area uv triangle (with positive 3D area) gives +∞; triangles with
/// zero 3D area are ignored.
pub fn area_distortion(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> f64 {
    match area_distortions(positions, triangles, uv) {
        None => f64::INFINITY,
        Some(d) => d.iter().fold(1.0f64, |w, &(v, _)| w.max(v)),
    }
}

/// The area-weighted `q`-quantile of the same per-triangle area distortion:
/// the smallest value that triangles of at least a fraction `q` of the 3D
/// area do not exceed (used to split charts).
pub(crate) fn area_distortion_quantile(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: &[[f64; 2]],
    q: f64,
) -> f64 {
    let Some(mut d) = area_distortions(positions, triangles, uv) else {
        return f64::INFINITY;
    };
    let total: f64 = d.iter().map(|&(_, a)| a).sum();
    d.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut acc = 0.0;
    for &(v, a) in &d {
        acc += a;
        if acc >= q * total {
            return v;
        }
    }
    d.last().map_or(1.0, |x| x.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut p = Vec::new();
        let mut t = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                p.push([i as f32, j as f32, 0.0]);
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (p, t)
    }

    #[test]
    fn flat_grid_is_isometric() {
        let (p, t) = grid(6);
        let uv = lscm(&p, &t).unwrap();
        let (l2, linf) = stretch(&p, &t, &uv);
        assert!(
            (l2 - 1.0).abs() < 1e-9 && (linf - 1.0).abs() < 1e-9,
            "{l2} {linf}"
        );
        assert!(signed_uv_areas(&uv, &t).iter().all(|&a| a > 0.0));
        assert!((area_distortion(&p, &t, &uv) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn single_triangle_and_errors() {
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 2.0, 0.5]];
        let uv = lscm(&p, &[[0, 1, 2]]).unwrap();
        let (l2, linf) = stretch(&p, &[[0, 1, 2]], &uv);
        assert!((l2 - 1.0).abs() < 1e-9 && (linf - 1.0).abs() < 1e-9);
        assert!(lscm(&p, &[]).is_err());
        assert!(lscm(&p, &[[0, 1, 3]]).is_err());
        // closed tetrahedron
        let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let t = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        assert!(lscm(&p, &t).is_err());
        // two separate triangles
        let p = vec![
            [0.0; 3],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [5.0, 0.0, 0.0],
            [6.0, 0.0, 0.0],
            [5.0, 1.0, 0.0],
        ];
        assert!(lscm(&p, &[[0, 1, 2], [3, 4, 5]]).is_err());
    }

    #[test]
    fn mirrored_map_is_flagged() {
        let (p, t) = grid(3);
        let uv: Vec<[f64; 2]> = p.iter().map(|q| [q[0] as f64, -(q[1] as f64)]).collect();
        assert!(signed_uv_areas(&uv, &t).iter().all(|&a| a < 0.0));
        assert_eq!(stretch(&p, &t, &uv).1, f64::INFINITY);
        assert_eq!(area_distortion(&p, &t, &uv), f64::INFINITY);
    }
}
