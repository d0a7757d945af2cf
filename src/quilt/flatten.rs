//! Work images I(v) (section III-B, step 3): a chart's own sub-image, or the
//! work patch flattened across charts (charts' LSCM layouts aligned over the
//! zipper links and their gaps closed, else the rigid field-based unfolding)
//! and resampled at one texel per pixel.

use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::sparse::{SparseRowMat, SymbolicSparseRowMat};
use faer::{c64, Accum, ColMut, ColRef, Mat, Par};
use glam::Vec3;

use super::sample::Sample;
use super::state::{Bfs, State, Surface, WorkPatch};

/// The work image of a patch and where each patch vertex sits in it.
pub(super) struct WorkImage {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) features: Vec<f32>,
    pub(super) known: Vec<f32>,
    /// Work-image coordinates of each patch vertex (pixel indices, continuous).
    pub(super) coords: Vec<[f64; 2]>,
    /// Mean field direction in the work image (radians, y down).
    pub(super) angle: f64,
    /// How far the field's direction varies over the patch (radians, a
    /// circular standard deviation; 0 for a constant field): matching may
    /// turn the sample this far from `angle`.
    pub(super) field_spread: f64,
    /// The direction the sample already has in the patch's synthesized
    /// texels, in the work image (radians), when known.
    pub(super) neighbour_angle: Option<f64>,
    /// Local linear map from atlas steps (+x, +y) to work-image offsets, for
    /// in-chart work images (identity) — used for the Jacobian.
    pub(super) atlas_to_work: Option<[f64; 4]>,
    /// m0 per work pixel (empty when unconstrained).
    pub(super) constraint: Vec<f32>,
}

impl WorkImage {
    /// A `width`×`height` work image with nothing known yet: `n` feature
    /// channels, and an m0 channel when the synthesis is constrained.
    pub(super) fn blank(
        width: usize,
        height: usize,
        state: &State,
        coords: Vec<[f64; 2]>,
        angle: f64,
    ) -> WorkImage {
        WorkImage {
            width,
            height,
            features: vec![0f32; width * height * state.n],
            known: vec![0f32; width * height],
            coords,
            angle,
            field_spread: 0.0,
            neighbour_angle: None,
            atlas_to_work: None,
            constraint: vec![0f32; if state.constrained { width * height } else { 0 }],
        }
    }
}

pub(super) fn mean_angle(angles: impl Iterator<Item = f64>) -> f64 {
    let (mut c, mut s) = (0.0, 0.0);
    for a in angles {
        c += a.cos();
        s += a.sin();
    }
    s.atan2(c)
}

/// In-chart work coordinates: the patch's atlas positions from the corner
/// of its atlas box, and the mean field angle.
fn chart_coords(surface: &Surface, patch: &WorkPatch) -> (Vec<[f64; 2]>, f64) {
    let r = surface.r;
    let (x0, y0, _, _) = patch.atlas_box(r);
    let coords = patch
        .texels
        .iter()
        .map(|&t| [(t as usize % r - x0) as f64, (t as usize / r - y0) as f64])
        .collect();
    let angle = mean_angle(patch.texels.iter().map(|&t| surface.texel_angle(t)));
    (coords, angle)
}

/// In-chart work image: the chart's sub-image around the patch.
pub(super) fn chart_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
) -> WorkImage {
    let r = surface.r;
    let chart = surface.chart(patch.texels[0]);
    let (x0, y0, w, h) = patch.atlas_box(r);
    let n = state.n;
    let (coords, angle) = chart_coords(surface, patch);
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    work.atlas_to_work = Some([1.0, 0.0, 0.0, 1.0]);
    for y in 0..h {
        for x in 0..w {
            let (t, p) = (((y0 + y) * r + x0 + x) as u32, y * w + x);
            if surface.chart(t) == chart && state.synthesized(t) {
                work.known[p] = 1.0;
                state.feature_into(sample, t, &mut work.features[p * n..(p + 1) * n]);
            }
            if let Some(m0) = state.target(t) {
                work.constraint[p] = m0;
            }
        }
    }
    work
}

/// The patch's triangles (local indices): grid blocks inside charts, then
/// zipper triangles, all wound like the surface; and how many are grid ones.
pub(super) fn patch_triangles(
    surface: &Surface,
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
            for tri in crate::artifact::gim::block_triangles_by(|t| surface.chart(t), r, x, y) {
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
    let positions: Vec<[f32; 3]> = patch.texels.iter().map(|&t| surface.position(t)).collect();
    // wind every triangle like the surface (its 3D normal along the texels'
    // normals): zipper triangles are stored unoriented, and the distortion
    // check reads flips from the orientation
    for tri in &mut tris {
        let p = tri.map(|i| Vec3::from(positions[i as usize]));
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        let mut avg = Vec3::ZERO;
        for &i in tri.iter() {
            avg += Vec3::from(surface.normal(patch.texels[i as usize]));
        }
        if n.dot(avg) < 0.0 {
            tri.swap(1, 2);
        }
    }
    (tris, positions, grid_count)
}

/// Weight of the prior that keeps a chart piece's alignment near the field-
/// based unfolding (texels² per unit of similarity change): a link's
/// residual counts as much as a change of the piece's rotation seen at
/// this distance.
pub(super) const ALIGN_PRIOR: f64 = 4.0;

/// `1/z` as `conj(z)/|z|²`: `(re/|z|², −im/|z|²)`, in this operation order.
/// (num-complex's `Complex::inv` computes the same today, but its `a / b`
/// does not — it divides `a·conj(b)` by `|b|²` at the end, which rounds
/// differently — and the flattening must not move by a bit, so the
/// expression is spelled out here.)
fn recip(z: c64) -> c64 {
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
pub(super) fn solve_complex(mut a: Mat<c64>, mut b: Vec<c64>) -> Option<Vec<c64>> {
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
pub(super) fn aligned_unfolding(surface: &Surface, patch: &WorkPatch, bfs: &Bfs) -> Vec<[f64; 2]> {
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
pub(super) fn zipper_gap(surface: &Surface, patch: &WorkPatch, bfs: &Bfs, coords: &[[f64; 2]]) -> f64 {
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
pub(super) const LINK_WEIGHT: f64 = 4.0;

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
/// every dot product is summed in index order; [`apply_membrane`] is exact
/// against the former hand-written product, as p never holds −0 (r starts
/// at b, whose entries are +0 or non-zero, and a difference never rounds to
/// −0).
pub(super) fn close_gaps(
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

/// Jacobi-preconditioned conjugate gradients on `op · x = b` from `x0`
/// (or 0), at most `iterations` steps, until the residual is below
/// 10⁻³ ‖b‖; `None` when b = 0.
fn jacobi_cg(
    op: &SparseRowMat<usize, f64>,
    diag: &[f64],
    b: &[f64],
    x0: Option<Vec<f64>>,
    iterations: usize,
) -> Option<Vec<f64>> {
    let m = diag.len();
    let bnorm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    if bnorm == 0.0 {
        return None;
    }
    let converged = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>().sqrt() < 1e-3 * bnorm;
    let (mut x, mut r) = match x0 {
        Some(x0) => {
            let mut ax = vec![0.0f64; m];
            apply_membrane(op, &x0, &mut ax);
            let r = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
            (x0, r)
        }
        None => (vec![0.0f64; m], b.to_vec()),
    };
    if converged(&r) {
        return Some(x);
    }
    let mut z: Vec<f64> = r.iter().zip(diag).map(|(r, d)| r / d).collect();
    let mut p = z.clone();
    let mut ap = vec![0.0f64; m];
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    for _ in 0..iterations {
        apply_membrane(op, &p, &mut ap);
        let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
        if !(pap > 0.0) {
            break;
        }
        let alpha = rz / pap;
        for k in 0..m {
            x[k] += alpha * p[k];
            r[k] -= alpha * ap[k];
        }
        if converged(&r) {
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
    Some(x)
}

/// Side of the atlas blocks whose texels (of one chart) [`Coarse`] merges.
const COARSE_BLOCK: usize = 4;

/// A coarse copy of the gap-closing membrane: the patch's texels merged by
/// chart and [`COARSE_BLOCK`]² atlas block (piecewise-constant
/// prolongation P, Galerkin operator PᵀAP). Its solution, spread back over
/// the texels, is the fine solve's first guess: the smooth part of the
/// displacement field is found on 1/16 of the unknowns, and the fine
/// iteration only has to mend what varies within a block.
struct Coarse {
    /// Aggregate of each texel.
    of: Vec<u32>,
    op: SparseRowMat<usize, f64>,
    diag: Vec<f64>,
}

impl Coarse {
    /// `None` when merging would not shrink the system much.
    fn new(
        surface: &Surface,
        patch: &WorkPatch,
        start: &[usize],
        nbr: &[(u32, f64)],
        diag: &[f64],
    ) -> Option<Coarse> {
        let m = patch.texels.len();
        if m < 256 {
            return None;
        }
        let grid = surface.grid();
        let mut ids: std::collections::HashMap<u64, u32> = std::collections::HashMap::with_capacity(m / 8);
        let of: Vec<u32> = patch
            .texels
            .iter()
            .map(|&t| {
                let (x, y) = grid.xy(t);
                let key = (surface.chart(t) as u64) << 40
                    | ((y / COARSE_BLOCK) as u64) << 20
                    | (x / COARSE_BLOCK) as u64;
                let next = ids.len() as u32;
                *ids.entry(key).or_insert(next)
            })
            .collect();
        let n = ids.len();
        if n * 4 > m {
            return None;
        }
        // rows of PᵀAP: (column, value), summed in fine-row order
        let mut rows: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        for i in 0..m {
            let a = of[i] as usize;
            rows[a].push((a as u32, diag[i]));
            for &(j, w) in &nbr[start[i]..start[i + 1]] {
                rows[a].push((of[j as usize], -w));
            }
        }
        let mut row_ptr = Vec::with_capacity(n + 1);
        let mut col_idx = Vec::new();
        let mut values = Vec::new();
        let mut cdiag = vec![0.0f64; n];
        row_ptr.push(0);
        for (a, row) in rows.iter_mut().enumerate() {
            // stable: equal columns keep their summation order
            row.sort_by_key(|e| e.0);
            let mut k = 0;
            while k < row.len() {
                let c = row[k].0;
                let mut v = 0.0;
                while k < row.len() && row[k].0 == c {
                    v += row[k].1;
                    k += 1;
                }
                if c as usize == a {
                    cdiag[a] = v;
                }
                col_idx.push(c as usize);
                values.push(v);
            }
            row_ptr.push(col_idx.len());
        }
        if cdiag.iter().any(|&d| !(d > 0.0)) {
            return None;
        }
        let op = SparseRowMat::new(
            SymbolicSparseRowMat::new_unsorted_checked(n, n, row_ptr, None, col_idx),
            values,
        );
        Some(Coarse { of, op, diag: cdiag })
    }

    /// P (PᵀAP)⁻¹ Pᵀ b, by the same Jacobi-preconditioned iteration.
    fn guess(&self, b: &[f64], iterations: usize) -> Option<Vec<f64>> {
        let mut bc = vec![0.0f64; self.diag.len()];
        for (i, &v) in b.iter().enumerate() {
            bc[self.of[i] as usize] += v;
        }
        let xc = jacobi_cg(&self.op, &self.diag, &bc, None, iterations)?;
        Some(self.of.iter().map(|&a| xc[a as usize]).collect())
    }
}

/// The operator diag − W of [`close_gaps`] as a sparse matrix: row i holds
/// its diagonal first, then −w per neighbour in `nbr[start[i]..start[i+1]]`
/// order (unsorted, repeats kept).
pub(super) fn membrane_operator(
    start: &[usize],
    nbr: &[(u32, f64)],
    diag: &[f64],
) -> SparseRowMat<usize, f64> {
    let m = diag.len();
    let mut row_ptr = Vec::with_capacity(m + 1);
    let mut col_idx = Vec::with_capacity(m + nbr.len());
    let mut values = Vec::with_capacity(m + nbr.len());
    row_ptr.push(0);
    for i in 0..m {
        col_idx.push(i);
        values.push(diag[i]);
        for &(j, w) in &nbr[start[i]..start[i + 1]] {
            col_idx.push(j as usize);
            values.push(-w);
        }
        row_ptr.push(col_idx.len());
    }
    SparseRowMat::new(
        SymbolicSparseRowMat::new_unsorted_checked(m, m, row_ptr, None, col_idx),
        values,
    )
}

/// `out = op · x` by faer's sparse × dense product, which (0.24) sums a
/// row's entries in storage order from +0 with plain multiplies and adds:
/// for a [`membrane_operator`] that rounds exactly like
/// `(diag_i·x_i − w_1·x_j1) − w_2·x_j2 …` unless `x_i` is −0.
pub(super) fn apply_membrane(op: &SparseRowMat<usize, f64>, x: &[f64], out: &mut [f64]) {
    sparse_dense_matmul(
        ColMut::from_slice_mut(out).as_mat_mut(),
        Accum::Replace,
        op.as_ref(),
        ColRef::from_slice(x).as_mat(),
        1.0,
        Par::Seq,
    );
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
pub(super) fn flatten(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    grid_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<(Vec<[f64; 2]>, f64)> {
    let r = surface.r;
    let local = |t: u32| bfs.contains(t);
    let mut uv = aligned_unfolding(surface, patch, bfs);
    close_gaps(surface, patch, bfs, &mut uv, 300);
    let gap = zipper_gap(surface, patch, bfs, &uv);
    // grid triangles have atlas area ½; those touching a chart border are
    // left out (conservative coverage overlaps the charts there by up to a
    // texel, which closing the gaps squeezes out)
    let on_border: Vec<bool> = patch
        .texels
        .iter()
        .map(|&t| {
            let mut on = false;
            surface.for_each_neighbour(t, |_, zipper| on |= zipper);
            on
        })
        .collect();
    let border = |i: u32| on_border[i as usize];
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
        if (t as usize % r) + 1 < r && surface.chart(t + 1) == surface.chart(t) {
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
pub(super) fn shift_to_origin(coords: &mut [[f64; 2]]) -> (usize, usize) {
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

/// [`shift_to_origin`], and the work image's size, unless the patch
/// flattened implausibly large (a side over four atlas sides).
fn shift_within_bound(coords: &mut [[f64; 2]], r: usize) -> Option<(usize, usize)> {
    let (w, h) = shift_to_origin(coords);
    (w <= 4 * r && h <= 4 * r).then_some((w, h))
}

/// The work image of a flattened patch: coordinates shifted to start at 0,
/// a pixel known where a triangle of three synthesized vertices covers it
/// (features interpolated). `None` if the patch flattened implausibly large.
pub(super) fn raster_work_image(
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    tris: &[[u32; 3]],
    mut coords: Vec<[f64; 2]>,
    angle: f64,
    r: usize,
) -> Option<WorkImage> {
    let (w, h) = shift_within_bound(&mut coords, r)?;
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    // each patch vertex's values once (a vertex is a corner of up to six
    // triangles): whether it is synthesized, its features and its m0
    let (synthesized, features) = state.features_of(sample, &patch.texels);
    let m0: Vec<f32> = if state.constrained {
        patch
            .texels
            .iter()
            .map(|&t| state.target(t).unwrap_or(0.0))
            .collect()
    } else {
        Vec::new()
    };
    for tri in tris {
        if !tri.iter().all(|&i| synthesized[i as usize]) {
            continue;
        }
        let corner_m0 = state.constrained.then(|| tri.map(|i| m0[i as usize]));
        let corner = tri.map(|i| &features[i as usize * n..(i as usize + 1) * n]);
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
                if let Some(m0) = corner_m0 {
                    work.constraint[i] = (l0 as f32) * m0[0] + (l1 as f32) * m0[1] + (l2 as f32) * m0[2];
                }
                for c in 0..n {
                    work.features[i * n + c] =
                        (l0 as f32) * corner[0][c] + (l1 as f32) * corner[1][c] + (l2 as f32) * corner[2][c];
                }
            }
        }
    }
    Some(work)
}

/// Cross-chart work image: the patch flattened by [`flatten()`] and resampled.
/// `None` if it cannot be flattened within the distortion bound.
#[allow(clippy::too_many_arguments)]
pub(super) fn flattened_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<(WorkImage, Vec<[f64; 2]>)> {
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, zipper_triangles);
    let (coords, angle) = flatten(surface, patch, bfs, &tris[..grid_count], max_distortion)?;
    let work = raster_work_image(sample, state, patch, &tris, coords.clone(), angle, surface.r)?;
    Some((work, coords))
}

/// The work coordinates (per patch vertex) and field angle the work image
/// of a patch has, without the image: the same choice between the chart's
/// own layout, the flattening and the rigid unfolding, for readers of the
/// coordinates alone (the verbatim preview).
pub(super) fn work_coords(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> (Vec<[f64; 2]>, f64) {
    if !patch.crosses_charts {
        return chart_coords(surface, patch);
    }
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, zipper_triangles);
    if let Some((mut coords, angle)) = flatten(surface, patch, bfs, &tris[..grid_count], max_distortion) {
        if shift_within_bound(&mut coords, surface.r).is_some() {
            return (coords, angle);
        }
    }
    let (mut coords, angle) = unfold(surface, patch, bfs);
    shift_to_origin(&mut coords);
    (coords, angle)
}

/// A seed's flattening, reused when its patch shrinks: a smaller BFS
/// ball from the same seed is part of the larger one.
pub(super) struct Flattening {
    /// (texel, coordinate), sorted by texel.
    pub(super) coords: Vec<(u32, [f64; 2])>,
    pub(super) angle: f64,
}

impl Flattening {
    /// The work image of a smaller patch from the cached coordinates.
    pub(super) fn work_image(
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
        let (tris, _, _) = patch_triangles(surface, patch, bfs, zipper_triangles);
        raster_work_image(sample, state, patch, &tris, coords, self.angle, surface.r)
    }
}

/// Cross-chart work image without flattening: each chart's part of the patch keeps
/// its atlas layout (no resampling inside a chart) and is turned rigidly so
/// that the vector field agrees across the zipper it was entered through.
/// Used when the patch's triangulation cannot be flattened within T_d.
pub(super) fn unfolded_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
) -> WorkImage {
    let (mut coords, angle) = unfold(surface, patch, bfs);
    let (w, h) = shift_to_origin(&mut coords);
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    for (i, &t) in patch.texels.iter().enumerate() {
        if state.synthesized(t) {
            let c = work.coords[i];
            let (x, y) = (c[0].round() as usize, c[1].round() as usize);
            let p = (y.min(h - 1)) * w + x.min(w - 1);
            if work.known[p] == 0.0 {
                work.known[p] = 1.0;
                state.feature_into(sample, t, &mut work.features[p * n..(p + 1) * n]);
                if let Some(m0) = state.target(t) {
                    work.constraint[p] = m0;
                }
            }
        }
    }
    work
}

/// The rigid unfolding of a patch: each chart's part keeps its atlas layout,
/// turned so the vector field agrees across the zipper it was entered
/// through. Work coordinates per patch vertex and the mean field angle.
pub(super) fn unfold(surface: &Surface, patch: &WorkPatch, bfs: &Bfs) -> (Vec<[f64; 2]>, f64) {
    let r = surface.r;
    let m = patch.texels.len();
    let atlas = |t: u32| [(t as usize % r) as f64, (t as usize / r) as f64];
    // per chart: (rotation φ, work origin, atlas origin)
    let mut frames: std::collections::BTreeMap<u32, (f64, [f64; 2], [f64; 2])> = Default::default();
    let v = patch.texels[0];
    let charts: Vec<u32> = patch.texels.iter().map(|&t| surface.chart(t)).collect();
    frames.insert(charts[0], (0.0, [0.0, 0.0], atlas(v)));
    let mut coords = vec![[0f64; 2]; m];
    for i in 0..m {
        let t = patch.texels[i];
        let c = charts[i];
        if !frames.contains_key(&c) {
            // entered through a zipper from an earlier texel of a known chart
            let mut entry = None;
            surface.for_each_neighbour(t, |nb, zipper| {
                if entry.is_none() && zipper {
                    if let Some(k) = bfs.contains(nb) {
                        if k < i && frames.contains_key(&charts[k]) {
                            entry = Some((nb, k));
                        }
                    }
                }
            });
            let (phi, origin) = match entry {
                Some((p, k)) => {
                    let pf = frames[&charts[k]].0;
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
            .zip(&charts)
            .map(|(&t, c)| surface.texel_angle(t) + frames[c].0),
    );
    (coords, angle)
}

/// Rotation index (5° steps for 72 copies) closest to an angle.
pub(super) fn rotation_index(angle: f64, rotations: usize) -> usize {
    let step = std::f64::consts::TAU / rotations as f64;
    ((angle.rem_euclid(std::f64::consts::TAU) / step).round() as usize) % rotations
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift64*: uniform in [-1, 1)
    fn rng(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed.max(1);
        move || {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            let v = s.wrapping_mul(0x2545_F491_4F6C_DD1D);
            (v >> 11) as f64 / (1u64 << 52) as f64 - 1.0
        }
    }

    #[test]
    fn solve_complex_solves_well_conditioned_systems() {
        for (seed, n) in [(1, 1), (2, 2), (3, 5), (4, 12), (5, 20)] {
            let mut r = rng(seed);
            // random, made diagonally dominant only in half the cases so
            // pivoting matters too
            let a = Mat::<c64>::from_fn(n, n, |i, j| {
                let z = c64::new(r(), r());
                if i == j && seed % 2 == 1 {
                    z + c64::new(2.0 * n as f64, 0.0)
                } else {
                    z
                }
            });
            let b: Vec<c64> = (0..n).map(|_| c64::new(r(), r())).collect();
            let x = solve_complex(a.clone(), b.clone()).expect("regular");
            let mut worst = 0.0f64;
            for i in 0..n {
                let ax: c64 = (0..n).map(|j| a[(i, j)] * x[j]).sum();
                worst = worst.max((ax - b[i]).norm());
            }
            assert!(worst < 1e-12, "n {n}: residual {worst:e}");
        }
    }

    #[test]
    fn solve_complex_reports_singular_systems() {
        assert!(solve_complex(Mat::<c64>::zeros(3, 3), vec![c64::ONE; 3]).is_none());
        // two equal rows: the elimination cancels one exactly
        let rows = [[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [0.0, 1.0, 5.0]];
        let a = Mat::<c64>::from_fn(3, 3, |i, j| c64::new(rows[i][j], 0.5 * rows[i][j]));
        assert!(solve_complex(a, vec![c64::ONE; 3]).is_none());
        assert!(solve_complex(Mat::<c64>::zeros(0, 0), vec![]).is_some_and(|x| x.is_empty()));
    }

    #[test]
    fn recip_is_conj_over_norm() {
        let mut r = rng(7);
        for _ in 0..100 {
            let z = c64::new(r(), r());
            let d = z.re * z.re + z.im * z.im;
            let w = recip(z);
            assert_eq!(
                (w.re.to_bits(), w.im.to_bits()),
                ((z.re / d).to_bits(), (-z.im / d).to_bits())
            );
            assert!((w * z - c64::ONE).norm() < 1e-14);
        }
    }

    /// The sparse product must round exactly like the sequential row sums
    /// close_gaps was written with (a faer update changing its summation
    /// would move every flattening).
    #[test]
    fn membrane_operator_matches_sequential_row_sums_bitwise() {
        let mut r = rng(11);
        let m = 300;
        let (mut start, mut nbr) = (vec![0usize], Vec::new());
        for _ in 0..m {
            let k = ((r() + 1.0) * 4.0) as usize; // 0..=7 neighbours, repeats allowed
            for _ in 0..k {
                let j = (((r() + 1.0) * 0.5 * m as f64) as usize).min(m - 1);
                nbr.push((j as u32, if r() > 0.5 { LINK_WEIGHT } else { 1.0 }));
            }
            start.push(nbr.len());
        }
        let diag: Vec<f64> = (0..m)
            .map(|i| {
                1e-4 + nbr[start[i]..start[i + 1]]
                    .iter()
                    .map(|e: &(u32, f64)| e.1)
                    .sum::<f64>()
            })
            .collect();
        let op = membrane_operator(&start, &nbr, &diag);
        for round in 0..5 {
            let x: Vec<f64> = (0..m)
                .map(|i| if round == 0 && i % 3 == 0 { 0.0 } else { r() * 1e3 })
                .collect();
            let mut out = vec![f64::NAN; m];
            apply_membrane(&op, &x, &mut out);
            for i in 0..m {
                let mut v = diag[i] * x[i];
                for &(j, w) in &nbr[start[i]..start[i + 1]] {
                    v -= w * x[j as usize];
                }
                assert_eq!(out[i].to_bits(), v.to_bits(), "row {i}");
            }
        }
    }
}
