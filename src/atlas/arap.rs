//! As-rigid-as-possible relaxation of a chart's map (Liu, Zhang, Xu,
//! Gotsman, Gortler 2008, "A Local/Global Approach to Mesh
//! Parameterization"): starting from the conformal map, alternate a local
//! step (each triangle's nearest rotation to its Jacobian) and a global
//! step (the uv closest to those rotations in the area-weighted least-squares
//! sense, one sparse Cholesky factorization for every iteration). LSCM keeps
//! angles and lets area drift towards a chart's rim; ARAP trades a little
//! angle for area, which is what the chart checks (L2 stretch, the
//! area-distortion tail) measure.

use faer::sparse::{SparseColMat, Triplet};

use super::lscm::{degenerate, local_frame};
use crate::math;
use crate::mesh::to_dvec3;
use crate::sparse::SpdFactor;

/// Local/global iterations: a fixed count, so the result does not depend on
/// a tolerance met at a different step on another machine.
pub(crate) const ARAP_ITERATIONS: usize = 24;

/// The ARAP map reached from `uv` after `iterations` local/global steps, in
/// surface units; `None` if a vertex lies only on degenerate triangles, the
/// usable triangles are not connected, or the factorization fails. Flips and
/// folds are the caller's to check. The vertex of the first usable triangle's
/// first corner keeps its place (the energy only fixes uv up to a shift).
pub(crate) fn relax(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: &[[f64; 2]],
    iterations: usize,
) -> Option<Vec<[f64; 2]>> {
    let nv = uv.len();
    // Per usable triangle: its corners' barycentric gradients g_i in its own
    // frame (∇f = Σ f_i g_i) and its 3D area.
    let mut grads: Vec<([u32; 3], [[f64; 2]; 3], f64)> = Vec::with_capacity(triangles.len());
    let mut used = vec![false; nv];
    for t in triangles {
        let p = t.map(|v| to_dvec3(positions[v as usize]));
        let (q, area) = local_frame(p);
        if degenerate(p, area) {
            continue;
        }
        let mut g = [[0.0; 2]; 3];
        for (i, gi) in g.iter_mut().enumerate() {
            let (a, b) = (q[(i + 1) % 3], q[(i + 2) % 3]);
            // rot90 of the opposite edge, over twice the area
            *gi = [-(b[1] - a[1]) / (2.0 * area), (b[0] - a[0]) / (2.0 * area)];
        }
        for &v in t {
            used[v as usize] = true;
        }
        grads.push((*t, g, area));
    }
    let pin = grads.first()?.0[0] as usize;
    if triangles.iter().flatten().any(|&v| !used[v as usize]) {
        return None;
    }
    // Unknowns: every used vertex but the pin.
    let mut index = vec![u32::MAX; nv];
    let mut n = 0usize;
    for v in 0..nv {
        if used[v] && v != pin {
            index[v] = n as u32;
            n += 1;
        }
    }
    let mut uv = uv.to_vec();
    if n == 0 {
        return Some(uv);
    }
    // L = Σ A gᵢ·gⱼ, the cotangent Laplacian, positive definite with the pin
    // when the usable triangles are connected.
    let mut trip = Vec::with_capacity(grads.len() * 6);
    for (t, g, area) in &grads {
        for i in 0..3 {
            let a = index[t[i] as usize];
            for j in 0..3 {
                let b = index[t[j] as usize];
                if a != u32::MAX && b != u32::MAX && a <= b {
                    let w = area * (g[i][0] * g[j][0] + g[i][1] * g[j][1]);
                    trip.push(Triplet::new(a as usize, b as usize, w));
                }
            }
        }
    }
    let l = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &trip).ok()?;
    let factor = SpdFactor::new(&l).ok()?;
    let fixed = uv[pin];
    for _ in 0..iterations {
        let mut rhs = [vec![0.0f64; n], vec![0.0f64; n]];
        for (t, g, area) in &grads {
            // Jacobian J (row k = ∇ of uv coordinate k) and its nearest
            // rotation [[c, −s], [s, c]].
            let mut j = [[0.0f64; 2]; 2];
            for i in 0..3 {
                let p = uv[t[i] as usize];
                for k in 0..2 {
                    j[k][0] += p[k] * g[i][0];
                    j[k][1] += p[k] * g[i][1];
                }
            }
            let theta = math::atan2(j[1][0] - j[0][1], j[0][0] + j[1][1]);
            let (s, c) = math::sin_cos(theta);
            let r = [[c, -s], [s, c]];
            for i in 0..3 {
                let v = t[i] as usize;
                for k in 0..2 {
                    let target = area * (g[i][0] * r[k][0] + g[i][1] * r[k][1]);
                    if index[v] != u32::MAX {
                        rhs[k][index[v] as usize] += target;
                    }
                }
            }
            // the pin's column moves to the right-hand side
            for i in 0..3 {
                let a = index[t[i] as usize];
                if a == u32::MAX {
                    continue;
                }
                for jj in 0..3 {
                    if t[jj] as usize == pin {
                        let w = area * (g[i][0] * g[jj][0] + g[i][1] * g[jj][1]);
                        rhs[0][a as usize] -= w * fixed[0];
                        rhs[1][a as usize] -= w * fixed[1];
                    }
                }
            }
        }
        let [ru, rv] = rhs;
        let (xu, xv) = (factor.solve(ru), factor.solve(rv));
        for v in 0..nv {
            if index[v] != u32::MAX {
                let k = index[v] as usize;
                uv[v] = [xu[k], xv[k]];
            }
        }
        if uv.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return None;
        }
    }
    Some(uv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::lscm::{area_distortion_quantile, lscm, stretch};

    /// A planar patch is flattened isometrically whatever the start.
    #[test]
    fn a_planar_patch_relaxes_to_an_isometry() {
        let n = 8;
        let mut positions = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                positions.push([x as f32 * 0.3, y as f32 * 0.2, 0.0]);
            }
        }
        let mut triangles = Vec::new();
        let id = |x: usize, y: usize| (y * (n + 1) + x) as u32;
        for y in 0..n {
            for x in 0..n {
                triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        // start from a sheared, scaled, rotated map
        let start: Vec<[f64; 2]> = positions
            .iter()
            .map(|p| {
                let (x, y) = (p[0] as f64, p[1] as f64);
                [0.7 * x + 0.4 * y, -0.2 * x + 1.6 * y]
            })
            .collect();
        let uv = relax(&positions, &triangles, &start, 30).unwrap();
        for a in 0..positions.len() {
            for b in [0, n, positions.len() - 1] {
                let d3 = math::hypot(
                    (positions[a][0] - positions[b][0]) as f64,
                    (positions[a][1] - positions[b][1]) as f64,
                );
                let duv = math::hypot(uv[a][0] - uv[b][0], uv[a][1] - uv[b][1]);
                assert!((d3 - duv).abs() < 1e-6, "distance {a}-{b}: 3D {d3}, uv {duv}");
            }
        }
    }

    /// On a deep cap LSCM shrinks the rim; ARAP evens the texel density out.
    #[test]
    fn relaxation_lowers_the_area_distortion_of_a_cap() {
        let cap = crate::atlas::charts::tests::dome(10, 75.0);
        let (positions, triangles) = (cap.positions, cap.triangles);
        let conformal = lscm(&positions, &triangles).unwrap();
        let relaxed = relax(&positions, &triangles, &conformal, ARAP_ITERATIONS).unwrap();
        let tail = |uv: &[[f64; 2]]| area_distortion_quantile(&positions, &triangles, uv, 0.95);
        let (l2_lscm, _) = stretch(&positions, &triangles, &conformal);
        let (l2_arap, _) = stretch(&positions, &triangles, &relaxed);
        assert!(
            tail(&conformal) > 1.5,
            "the cap should be hard for LSCM: {}",
            tail(&conformal)
        );
        assert!(tail(&relaxed) < 1.3, "{} vs {}", tail(&relaxed), tail(&conformal));
        assert!(l2_arap < l2_lscm, "L2 {l2_arap} vs {l2_lscm}");
    }
}
