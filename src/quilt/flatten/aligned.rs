//! A work patch across charts: each chart's atlas layout moved by the
//! least-squares similarity that closes the zipper links (a weak prior
//! towards the field-based unfolding), then the gaps left closed by a
//! membrane.

use super::*;

/// Weight of the prior that keeps a chart piece's alignment near the field-
/// based unfolding (texels² per unit of similarity change): a link's
/// residual counts as much as a change of the piece's rotation seen at
/// this distance.
pub(in crate::quilt) const ALIGN_PRIOR: f64 = 4.0;

/// `1/z` as `conj(z)/|z|²`: `(re/|z|², −im/|z|²)`, in this operation order.
/// (num-complex's `Complex::inv` computes the same today, but its `a / b`
/// does not — it divides `a·conj(b)` by `|b|²` at the end, which rounds
/// differently — and the flattening must not move by a bit, so the
/// expression is spelled out here.)
pub(super) fn recip(z: c64) -> c64 {
    let d = z.norm_sqr();
    c64::new(z.re / d, -z.im / d)
}

/// Solves the small dense complex system `a x = b` (`a` square, `b` of its
/// size) by Gaussian elimination with partial pivoting on |a_ik|²; `None`
/// if singular.
///
/// Why not faer's `partial_piv_lu` (or `llt`, the matrix being the
/// Hermitian normal equations): it pivots on |re| + |im| (the first maximum
/// wins where this loop takes the last) and updates through faer's matrix
/// product kernels, SIMD with FMA chosen at run time, so its solutions
/// differ in the last bits and may differ between CPUs: measured over 14 131
/// systems (n ≤ 20) on ten meshes, 93% differed, by up to 2·10⁻¹⁰ (Cholesky:
/// up to 7·10⁻¹¹). The quilts happened to stay byte-identical, but only
/// because the work images are resampled in f32 and matched by discrete
/// choices; this elimination keeps the pivot order and every rounding of
/// the original solver, so the flattening cannot move.
pub(in crate::quilt) fn solve_complex(mut a: Mat<c64>, mut b: Vec<c64>) -> Option<Vec<c64>> {
    let n = b.len();
    debug_assert!(a.nrows() == n && a.ncols() == n);
    for k in 0..n {
        let p = (k..n).max_by(|&i, &j| a[(i, k)].norm_sqr().total_cmp(&a[(j, k)].norm_sqr()))?;
        if !(a[(p, k)].norm_sqr() > 1e-300) {
            return None;
        }
        if p != k {
            for j in 0..n {
                let t = a[(p, j)];
                a[(p, j)] = a[(k, j)];
                a[(k, j)] = t;
            }
            b.swap(p, k);
        }
        let inv = recip(a[(k, k)]);
        for i in k + 1..n {
            let f = a[(i, k)] * inv;
            if f == c64::ZERO {
                continue;
            }
            for j in k..n {
                let v = f * a[(k, j)];
                a[(i, j)] -= v;
            }
            let v = f * b[k];
            b[i] -= v;
        }
    }
    let mut x = vec![c64::ZERO; n];
    for k in (0..n).rev() {
        let mut s = b[k];
        for j in k + 1..n {
            s -= a[(k, j)] * x[j];
        }
        x[k] = s * recip(a[(k, k)]);
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
pub(in crate::quilt) fn aligned_unfolding(surface: &Surface, patch: &WorkPatch, bfs: &Bfs) -> Vec<[f64; 2]> {
    let (u, _) = unfold(surface, patch, bfs);
    let patch_charts: Vec<u32> = patch.texels.iter().map(|&t| surface.chart(t)).collect();
    let mut charts = patch_charts.clone();
    charts.sort_unstable();
    charts.dedup();
    let piece_of = |c: u32| charts.binary_search(&c).expect("patch chart");
    let seed = piece_of(patch_charts[0]);
    // unknowns: (γ, δ) of every piece but the seed's
    let unknown = |p: usize| if p < seed { p } else { p - 1 };
    let n = 2 * (charts.len() - 1);
    if n == 0 {
        return u;
    }
    let mut a = Mat::<c64>::zeros(n, n);
    let mut b = vec![c64::ZERO; n];
    // adds the weighted row Σ coeff·x = c to the normal equations
    let mut add_row = |coeffs: &[(usize, c64)], c: c64, w: f64| {
        for &(i, ci) in coeffs {
            let ci_h = ci.conj();
            for &(j, cj) in coeffs {
                a[(i, j)] += (ci_h * cj).scale(w);
            }
            b[i] += (ci_h * c).scale(w);
        }
    };
    let mut row: Vec<(usize, c64)> = Vec::with_capacity(4);
    for (i, &t) in patch.texels.iter().enumerate() {
        let p = piece_of(patch_charts[i]);
        surface.for_each_neighbour(t, |nb, zipper| {
            if !zipper {
                return;
            }
            let Some(j) = bfs.contains(nb) else { return };
            let q = piece_of(patch_charts[j]);
            if j <= i || q == p {
                return;
            }
            // γ_p u_i + δ_p − γ_q u_j − δ_q = 0
            row.clear();
            let mut c = c64::ZERO;
            for (piece_k, coord, sign) in [(p, u[i], 1.0), (q, u[j], -1.0)] {
                if piece_k == seed {
                    c -= c64::new(sign * coord[0], sign * coord[1]);
                } else {
                    let k = unknown(piece_k);
                    row.push((2 * k, c64::new(sign * coord[0], sign * coord[1])));
                    row.push((2 * k + 1, c64::new(sign, 0.0)));
                }
            }
            add_row(&row, c, 1.0);
        });
    }
    for p in (0..charts.len()).filter(|&p| p != seed) {
        let k = unknown(p);
        add_row(&[(2 * k, c64::ONE)], c64::ONE, ALIGN_PRIOR);
        add_row(&[(2 * k + 1, c64::ONE)], c64::ZERO, 1e-6);
    }
    let Some(x) = solve_complex(a, b) else { return u };
    patch
        .texels
        .iter()
        .zip(&u)
        .zip(&patch_charts)
        .map(|((_, &ui), &c)| {
            let p = piece_of(c);
            if p == seed {
                ui
            } else {
                let k = unknown(p);
                let w = x[2 * k] * c64::new(ui[0], ui[1]) + x[2 * k + 1];
                [w.re, w.im]
            }
        })
        .collect()
}

/// Root-mean-square distance in the work frame across the patch's zipper
/// links (texels).
pub(in crate::quilt) fn zipper_gap(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    coords: &[[f64; 2]],
) -> f64 {
    let (mut gap, mut links) = (0.0, 0usize);
    for (i, &t) in patch.texels.iter().enumerate() {
        surface.for_each_neighbour(t, |nb, zipper| {
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
pub(in crate::quilt) const LINK_WEIGHT: f64 = 4.0;

/// Closes the gaps an [`aligned_unfolding`] leaves across zipper links (the
/// charts' own flattenings disagree along a seam on a curved surface) by
/// the smoothest displacement field d: minimises Σ_grid |d_i − d_j|² +
/// μ Σ_links |x_i + d_i − x_j − d_j|² (+ a tiny ε|d|²), a membrane that
/// spreads the misfit over the patch like the distortion LSCM would
/// distribute. Solved per coordinate by Jacobi-preconditioned conjugate
/// gradients (at most `iterations`) from the solution of a [`Coarse`] copy
/// of the system, the operator held as a faer sparse matrix.
///
/// The iteration is this loop rather than
/// `faer::matrix_free::conjugate_gradient`: given the very same operator,
/// Jacobi preconditioner (r/d) and stopping rule (‖r‖ < 10⁻³‖b‖), faer's
/// displacements differed from these in 94% of the coordinates, by up to
/// 1.6·10⁻¹³ texel (27 680 solves on ten meshes), because its block
/// formulation takes α through a pivoted Cholesky factor of pᵀAp and sums
/// its dot products and norms in SIMD (FMA) kernels chosen at run time —
/// the last bits would depend on the CPU. The quilts of those runs stayed
/// byte-identical only because the work images are resampled in f32 and
/// matched by discrete choices, which does not hold for every input. (With
/// `InitialGuessStatus::Zero`, faer 0.24.4 also leaves the residual
/// uninitialised and returned garbage.) The vectors stay plain slices so
/// every dot product is summed in index order; [`Membrane::apply`] is exact
/// against the former hand-written product, as p never holds −0 (r starts
/// at b, whose entries are +0 or non-zero, and a difference never rounds to
/// −0).
pub(in crate::quilt) fn close_gaps(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    coords: &mut [[f64; 2]],
    iterations: usize,
) {
    let m = patch.texels.len();
    let mut start = Vec::with_capacity(m + 1);
    let mut nbr: Vec<(u32, f64)> = Vec::with_capacity(m * 4);
    let mut rhs = vec![[0.0f64; 2]; m];
    let mut any_link = false;
    start.push(0);
    for (i, &t) in patch.texels.iter().enumerate() {
        surface.for_each_neighbour(t, |nb, zipper| {
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
    let op = membrane_operator(&start, &nbr, &diag);
    let coarse = Coarse::new(surface, patch, &start, &nbr, &diag);
    // the two coordinates are independent systems with one operator:
    // solved side by side (each exactly as alone)
    let b = |c: usize| -> Vec<f64> { rhs.iter().map(|r| r[c]).collect() };
    let (bx, by) = (b(0), b(1));
    let solve = |b: &[f64]| {
        let x0 = coarse.as_ref().and_then(|c| c.guess(b, iterations));
        jacobi_cg(&op, &diag, b, x0, iterations)
    };
    let (x, y) = rayon::join(|| solve(&bx), || solve(&by));
    for (c, solution) in [(0, x), (1, y)] {
        if let Some(x) = solution {
            for k in 0..m {
                coords[k][c] += x[k];
            }
        }
    }
}
