//! The membrane solve behind flattening: a sparse operator, conjugate
//! gradients with a Jacobi and a coarse-grid preconditioner.

use super::*;

/// Jacobi-preconditioned conjugate gradients on `op · x = b` from `x0`
/// (or 0), at most `iterations` steps, until the residual is below
/// 10⁻³ ‖b‖; `None` when b = 0. Every dot product is summed in index
/// order from −0 (as `Iterator::sum` sums), the updates that feed one
/// fused into one pass.
pub(super) fn jacobi_cg(
    op: &Membrane,
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
    let converged = |rr: f64| rr.sqrt() < 1e-3 * bnorm;
    let (mut x, mut r) = match x0 {
        Some(x0) => {
            let mut ax = vec![0.0f64; m];
            op.apply(&x0, &mut ax);
            let r = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
            (x0, r)
        }
        None => (vec![0.0f64; m], b.to_vec()),
    };
    if converged(r.iter().map(|v| v * v).sum::<f64>()) {
        return Some(x);
    }
    let mut z: Vec<f64> = r.iter().zip(diag).map(|(r, d)| r / d).collect();
    let mut p = z.clone();
    let mut ap = vec![0.0f64; m];
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    for _ in 0..iterations {
        let pap = op.apply_dot(&p, &mut ap);
        if !(pap > 0.0) {
            break;
        }
        let alpha = rz / pap;
        let (mut rr, mut rz_new) = (-0.0f64, -0.0f64);
        for k in 0..m {
            x[k] += alpha * p[k];
            r[k] -= alpha * ap[k];
            rr += r[k] * r[k];
            z[k] = r[k] / diag[k];
            rz_new += r[k] * z[k];
        }
        if converged(rr) {
            break;
        }
        let beta = rz_new / rz;
        rz = rz_new;
        for k in 0..m {
            p[k] = z[k] + beta * p[k];
        }
    }
    Some(x)
}

/// A sparse matrix by rows (compressed): row i's entries are
/// `val[row_ptr[i]..row_ptr[i + 1]]` at columns `col[..]`, in storage order.
pub(in crate::quilt) struct Membrane {
    row_ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl Membrane {
    fn rows(&self) -> usize {
        self.row_ptr.len() - 1
    }

    /// Row i of `op · x`: its entries' products summed in storage order
    /// from +0 with plain multiplies and adds (for a
    /// [`membrane_operator`] this rounds exactly like `(diag_i·x_i −
    /// w_1·x_j1) − w_2·x_j2 …`, unless `x_i` is −0).
    #[inline]
    fn row(&self, i: usize, x: &[f64]) -> f64 {
        let (a, b) = (self.row_ptr[i], self.row_ptr[i + 1]);
        let mut v = 0.0f64;
        for (&c, &w) in self.col[a..b].iter().zip(&self.val[a..b]) {
            v += w * x[c as usize];
        }
        v
    }

    /// `out = op · x`.
    pub(in crate::quilt) fn apply(&self, x: &[f64], out: &mut [f64]) {
        for (i, o) in out.iter_mut().enumerate().take(self.rows()) {
            *o = self.row(i, x);
        }
    }

    /// `out = op · x`, and x · out summed in index order from −0.
    fn apply_dot(&self, x: &[f64], out: &mut [f64]) -> f64 {
        let mut dot = -0.0f64;
        for i in 0..self.rows() {
            let v = self.row(i, x);
            out[i] = v;
            dot += x[i] * v;
        }
        dot
    }
}

/// Side of the atlas blocks whose texels (of one chart) [`Coarse`] merges.
const COARSE_BLOCK: usize = 4;

/// A coarse copy of the gap-closing membrane: the patch's texels merged by
/// chart and [`COARSE_BLOCK`]² atlas block (piecewise-constant
/// prolongation P, Galerkin operator PᵀAP). Its solution, spread back over
/// the texels, is the fine solve's first guess: the smooth part of the
/// displacement field is found on 1/16 of the unknowns, and the fine
/// iteration only has to mend what varies within a block.
pub(super) struct Coarse {
    /// Aggregate of each texel.
    of: Vec<u32>,
    op: Membrane,
    diag: Vec<f64>,
}

impl Coarse {
    /// `None` when merging would not shrink the system much.
    pub(super) fn new(
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
                col_idx.push(c);
                values.push(v);
            }
            row_ptr.push(col_idx.len());
        }
        if cdiag.iter().any(|&d| !(d > 0.0)) {
            return None;
        }
        let op = Membrane {
            row_ptr,
            col: col_idx,
            val: values,
        };
        Some(Coarse { of, op, diag: cdiag })
    }

    /// P (PᵀAP)⁻¹ Pᵀ b, by the same Jacobi-preconditioned iteration.
    pub(super) fn guess(&self, b: &[f64], iterations: usize) -> Option<Vec<f64>> {
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
pub(in crate::quilt) fn membrane_operator(start: &[usize], nbr: &[(u32, f64)], diag: &[f64]) -> Membrane {
    let m = diag.len();
    let mut row_ptr = Vec::with_capacity(m + 1);
    let mut col = Vec::with_capacity(m + nbr.len());
    let mut val = Vec::with_capacity(m + nbr.len());
    row_ptr.push(0);
    for i in 0..m {
        col.push(i as u32);
        val.push(diag[i]);
        for &(j, w) in &nbr[start[i]..start[i + 1]] {
            col.push(j);
            val.push(-w);
        }
        row_ptr.push(col.len());
    }
    Membrane { row_ptr, col, val }
}
