//! Dense matrix arithmetic in a fixed order: the products, QR and SVD of
//! the randomized SVD (`factorize`) and the window products of `compare`.
//!
//! Every value here is a sequence of separate IEEE-754 multiplies, adds,
//! divides and square roots in one order that depends only on the matrix
//! shapes, never on the CPU, the vector width or the thread count. IEEE-754
//! rounds each of those operations exactly, and Rust never fuses a multiply
//! and an add by itself, so a factorization gives the same bits on x86 with
//! or without AVX2 and FMA, on ARM, and under any `--threads`.
//!
//! Loops are vectorised across independent outputs only (the columns of a
//! product, the lanes of a fixed 8-lane partial sum). `pulp` compiles them
//! for the widest instruction set the CPU has; the arithmetic of each output
//! is the same at every width.

use pulp::{Arch, Simd, WithSimd};

mod panel;
pub(crate) use panel::{qr_by_panels, qr_in_rows, Columns};

/// A computation to compile for each instruction set: `run` is marked
/// `#[inline(always)]`, so its body is compiled into each of pulp's
/// per-instruction-set copies (a closure's body would stay one baseline
/// function, as a closure cannot carry that attribute).
trait Kernel {
    type Output;
    fn run(self) -> Self::Output;
}

struct Vectorized<K>(K);

impl<K: Kernel> WithSimd for Vectorized<K> {
    type Output = K::Output;
    #[inline(always)]
    fn with_simd<S: Simd>(self, _: S) -> K::Output {
        self.0.run()
    }
}

/// Runs `kernel` compiled for the widest vector instructions of this CPU.
fn vectorized<K: Kernel>(kernel: K) -> K::Output {
    Arch::new().dispatch(Vectorized(kernel))
}

/// A dense row-major matrix of `f32`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Matrix {
    pub(crate) rows: usize,
    pub(crate) cols: usize,
    pub(crate) data: Vec<f32>,
}

impl Matrix {
    pub(crate) fn zeros(rows: usize, cols: usize) -> Self {
        Matrix {
            rows,
            cols,
            data: vec![0.0; rows * cols],
        }
    }

    pub(crate) fn from_fn(rows: usize, cols: usize, mut f: impl FnMut(usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            data.extend((0..cols).map(|c| f(r, c)));
        }
        Matrix { rows, cols, data }
    }

    /// Rows `r0..r0 + n`, row-major.
    pub(crate) fn rows_from(&self, r0: usize, n: usize) -> &[f32] {
        &self.data[r0 * self.cols..(r0 + n) * self.cols]
    }

    pub(crate) fn row(&self, r: usize) -> &[f32] {
        self.rows_from(r, 1)
    }

    /// A column-major f64 copy (the layout of [`qr`] and [`thin_svd`]).
    pub(crate) fn column_major(&self) -> Vec<f64> {
        let mut out = vec![0f64; self.rows * self.cols];
        for (r, row) in self.data.chunks_exact(self.cols.max(1)).enumerate() {
            for (c, &v) in row.iter().enumerate() {
                out[c * self.rows + r] = v as f64;
            }
        }
        out
    }
}

/// `out += A·B` for A (`rows` × `inner`, row `r` at `a[r·lda..]`), B
/// (`inner` × `cols`, row `i` at `b[i·ldb..]`) and out (`rows` × `cols`,
/// row `r` at `out[r·ldo..]`).
/// Each output is `((out + A(r,0)B(0,j)) + A(r,1)B(1,j)) + …` in the order
/// of `i`, whatever the blocking.
pub(crate) fn mul_add(
    out: &mut [f32],
    ldo: usize,
    (a, lda): (&[f32], usize),
    (b, ldb): (&[f32], usize),
    (rows, inner, cols): (usize, usize, usize),
) {
    vectorized(MulAdd {
        out,
        ldo,
        a: (a, lda),
        b: (b, ldb),
        shape: (rows, inner, cols),
    })
}

/// The arguments of [`mul_add`].
struct MulAdd<'o, 'a, 'b> {
    out: &'o mut [f32],
    ldo: usize,
    a: (&'a [f32], usize),
    b: (&'b [f32], usize),
    shape: (usize, usize, usize),
}

impl Kernel for MulAdd<'_, '_, '_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let MulAdd {
            out,
            ldo,
            a: (a, lda),
            b: (b, ldb),
            shape: (rows, inner, cols),
        } = self;
        let mut j0 = 0;
        while j0 < cols {
            let jb = match cols - j0 {
                16.. => 16,
                8.. => 8,
                4.. => 4,
                2.. => 2,
                _ => 1,
            };
            let mut r0 = 0;
            while r0 < rows {
                let rb = match rows - r0 {
                    6.. => 6,
                    4.. => 4,
                    _ => 1,
                };
                let p = Panel {
                    ldo,
                    a,
                    lda,
                    b,
                    ldb,
                    inner,
                    r0,
                    j0,
                };
                match (rb, jb) {
                    (6, 16) => p.run::<6, 16>(out),
                    (6, 8) => p.run::<6, 8>(out),
                    (6, 4) => p.run::<6, 4>(out),
                    (6, 2) => p.run::<6, 2>(out),
                    (6, _) => p.run::<6, 1>(out),
                    (4, 16) => p.run::<4, 16>(out),
                    (4, 8) => p.run::<4, 8>(out),
                    (4, 4) => p.run::<4, 4>(out),
                    (4, 2) => p.run::<4, 2>(out),
                    (4, _) => p.run::<4, 1>(out),
                    (_, 16) => p.run::<1, 16>(out),
                    (_, 8) => p.run::<1, 8>(out),
                    (_, 4) => p.run::<1, 4>(out),
                    (_, 2) => p.run::<1, 2>(out),
                    _ => p.run::<1, 1>(out),
                }
                r0 += rb;
            }
            j0 += jb;
        }
    }
}

/// One block of [`mul_add`]: rows `r0..r0+R`, columns `j0..j0+J`, held in
/// registers across the whole inner dimension.
struct Panel<'a, 'b> {
    ldo: usize,
    a: &'a [f32],
    lda: usize,
    b: &'b [f32],
    ldb: usize,
    inner: usize,
    r0: usize,
    j0: usize,
}

impl Panel<'_, '_> {
    #[inline(always)]
    fn run<const R: usize, const J: usize>(&self, out: &mut [f32]) {
        let mut acc = [[0f32; J]; R];
        for (r, acc) in acc.iter_mut().enumerate() {
            let o = (self.r0 + r) * self.ldo + self.j0;
            acc.copy_from_slice(&out[o..o + J]);
        }
        let a: [&[f32]; R] = std::array::from_fn(|r| &self.a[(self.r0 + r) * self.lda..][..self.inner]);
        let b = &self.b[self.j0..];
        for i in 0..self.inner {
            let b: &[f32; J] = b[i * self.ldb..][..J].try_into().expect("a row of J values");
            for (acc, a) in acc.iter_mut().zip(&a) {
                let av = a[i];
                for (acc, &bv) in acc.iter_mut().zip(b) {
                    *acc += av * bv;
                }
            }
        }
        for (r, acc) in acc.iter().enumerate() {
            let o = (self.r0 + r) * self.ldo + self.j0;
            out[o..o + J].copy_from_slice(acc);
        }
    }
}

/// `a` (`rows` × `cols`, row-major) transposed into `out`.
pub(crate) fn transpose_into(a: &[f32], rows: usize, cols: usize, out: &mut Vec<f32>) {
    const B: usize = 16;
    out.clear();
    out.resize(rows * cols, 0.0);
    for r0 in (0..rows).step_by(B) {
        for c0 in (0..cols).step_by(B) {
            for r in r0..(r0 + B).min(rows) {
                for c in c0..(c0 + B).min(cols) {
                    out[c * rows + r] = a[r * cols + c];
                }
            }
        }
    }
}

/// Σ over rows, per column, of squared values (an f32 sum down each column
/// in row order), then the columns' sums added in f64 in column order.
pub(crate) fn sum_squares(m: &[f32], cols: usize) -> f64 {
    vectorized(SumSquares(m, cols))
}

struct SumSquares<'a>(&'a [f32], usize);

impl Kernel for SumSquares<'_> {
    type Output = f64;

    #[inline(always)]
    fn run(self) -> f64 {
        let SumSquares(m, cols) = self;
        let mut per_column = vec![0f32; cols];
        for row in m.chunks_exact(cols) {
            for (s, &v) in per_column.iter_mut().zip(row) {
                *s += v * v;
            }
        }
        per_column.iter().map(|&s| s as f64).sum()
    }
}

/// `x · y` as eight interleaved partial sums added pairwise, then the tail.
#[inline(always)]
fn dot(x: &[f64], y: &[f64]) -> f64 {
    let mut lanes = [0f64; 8];
    let (xc, yc) = (x.chunks_exact(8), y.chunks_exact(8));
    let (xt, yt) = (xc.remainder(), yc.remainder());
    for (x, y) in xc.zip(yc) {
        for l in 0..8 {
            lanes[l] += x[l] * y[l];
        }
    }
    let mut s =
        ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]));
    for (x, y) in xt.iter().zip(yt) {
        s += x * y;
    }
    s
}

/// `y -= f·x`.
#[inline(always)]
fn sub_scaled(y: &mut [f64], f: f64, x: &[f64]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y -= f * x;
    }
}

/// A thin QR factorization: Q (`rows` × `k`, orthonormal columns) and R
/// (`k` × `k`, upper triangular), both column-major.
pub(crate) struct Qr {
    pub(crate) q: Vec<f64>,
    pub(crate) r: Vec<f64>,
}

/// Householder QR of the column-major `a` (`rows` × `k`, `rows ≥ k`).
/// A zero column gives a zero row of R and the unit vector of Q that
/// completes the others.
pub(crate) fn qr(a: Vec<f64>, rows: usize, k: usize) -> Qr {
    assert!(rows >= k && a.len() == rows * k, "qr of a {rows} × {k} matrix");
    vectorized(Householder(a, rows, k))
}

struct Householder(Vec<f64>, usize, usize);

impl Kernel for Householder {
    type Output = Qr;

    /// The whole matrix as one panel of [`panel::qr_by_panels`]: the same
    /// steps, so the panels' QR has these bits by construction.
    #[inline(always)]
    fn run(self) -> Qr {
        let Householder(mut a, rows, k) = self;
        let mut r = vec![0f64; k * k];
        // reflector j: H = I − β v vᵀ, v stored in column j from row j
        let mut beta = vec![0f64; k];
        panel::Factor {
            cols: &mut a,
            rows,
            c0: 0,
            k,
            r: &mut r,
            beta: &mut beta,
        }
        .run();
        // Q = H_0 ⋯ H_{k−1} applied to the first k columns of the identity,
        // formed in place of the reflectors
        let mut v = vec![0f64; rows];
        panel::Form {
            cols: &mut a,
            rows,
            c0: 0,
            beta: &beta,
            v: &mut v,
        }
        .run();
        Qr { q: a, r }
    }
}

/// A thin SVD M = U Σ Vᵀ: U (`rows` × `k`, column-major), σ non-increasing,
/// V (`k` × `k`, column-major).
pub(crate) struct Svd {
    pub(crate) u: Vec<f64>,
    pub(crate) sigma: Vec<f64>,
    pub(crate) v: Vec<f64>,
}

/// Most sweeps of the Jacobi iteration (it converges quadratically; a
/// 50 × 50 triangle takes under ten).
const MAX_SWEEPS: usize = 64;

/// Thin SVD of the column-major `m` (`rows` × `k`, `rows ≥ k`): M = QR,
/// then one-sided Jacobi (Hestenes) on R: rotations V turn R's columns
/// orthogonal, R V = Û Σ, so M = (Q Û) Σ Vᵀ (Demmel & Veselić 1992).
pub(crate) fn thin_svd(m: Vec<f64>, rows: usize, k: usize) -> Svd {
    let qr = qr(m, rows, k);
    vectorized(Jacobi(qr, rows, k))
}

struct Jacobi(Qr, usize, usize);

impl Kernel for Jacobi {
    type Output = Svd;

    #[inline(always)]
    fn run(self) -> Svd {
        let Jacobi(Qr { q, r: mut x }, rows, k) = self;
        let mut v = vec![0f64; k * k];
        for i in 0..k {
            v[i * k + i] = 1.0;
        }
        for _ in 0..MAX_SWEEPS {
            let mut rotated = false;
            for i in 0..k {
                for j in i + 1..k {
                    let (xi, xj) = (&x[i * k..(i + 1) * k], &x[j * k..(j + 1) * k]);
                    let (a, b, g) = (dot(xi, xi), dot(xj, xj), dot(xi, xj));
                    if g == 0.0 || g.abs() <= f64::EPSILON * (a * b).sqrt() {
                        continue;
                    }
                    rotated = true;
                    let zeta = (b - a) / (2.0 * g);
                    let t = zeta.signum() / (zeta.abs() + (1.0 + zeta * zeta).sqrt());
                    let c = 1.0 / (1.0 + t * t).sqrt();
                    let s = c * t;
                    rotate(&mut x, k, i, j, c, s);
                    rotate(&mut v, k, i, j, c, s);
                }
            }
            if !rotated {
                break;
            }
        }
        let norms: Vec<f64> = x.chunks_exact(k).map(|c| dot(c, c).sqrt()).collect();
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| norms[b].total_cmp(&norms[a]).then(a.cmp(&b)));
        // Û's columns: R's rotated columns over their norms; a zero column
        // becomes the unit vector completing the others
        let mut u_hat = vec![0f64; k * k];
        let mut filled: Vec<usize> = Vec::with_capacity(k);
        let mut zero = Vec::new();
        for (to, &from) in order.iter().enumerate() {
            if norms[from] > 0.0 {
                let col = &mut u_hat[to * k..(to + 1) * k];
                for (u, &x) in col.iter_mut().zip(&x[from * k..(from + 1) * k]) {
                    *u = x / norms[from];
                }
                filled.push(to);
            } else {
                zero.push(to);
            }
        }
        for to in zero {
            complete(&mut u_hat, k, &mut filled, to);
        }
        // U = Q Û, each entry summed over Q's columns in order
        let mut u = vec![0f64; rows * k];
        for (c, u) in u.chunks_exact_mut(rows).enumerate() {
            for l in 0..k {
                let f = u_hat[c * k + l];
                for (u, &q) in u.iter_mut().zip(&q[l * rows..(l + 1) * rows]) {
                    *u += q * f;
                }
            }
        }
        let mut v_sorted = vec![0f64; k * k];
        for (to, &from) in order.iter().enumerate() {
            v_sorted[to * k..(to + 1) * k].copy_from_slice(&v[from * k..(from + 1) * k]);
        }
        Svd {
            u,
            sigma: order.iter().map(|&i| norms[i]).collect(),
            v: v_sorted,
        }
    }
}

/// Columns i, j of the column-major `m` (`n` rows) ← (c·mᵢ − s·mⱼ, s·mᵢ + c·mⱼ).
#[inline(always)]
fn rotate(m: &mut [f64], n: usize, i: usize, j: usize, c: f64, s: f64) {
    let (lo, hi) = m.split_at_mut(j * n);
    let (mi, mj) = (&mut lo[i * n..(i + 1) * n], &mut hi[..n]);
    for (a, b) in mi.iter_mut().zip(mj.iter_mut()) {
        let (x, y) = (*a, *b);
        *a = c * x - s * y;
        *b = s * x + c * y;
    }
}

/// Column `to` of the column-major `u` (`k` × `k`) ← the first unit vector
/// e_i that keeps a clear component after two Gram-Schmidt passes against
/// the `filled` columns, normalised; `to` joins `filled`.
fn complete(u: &mut [f64], k: usize, filled: &mut Vec<usize>, to: usize) {
    for i in 0..k {
        let mut e = vec![0f64; k];
        e[i] = 1.0;
        for _ in 0..2 {
            for &f in filled.iter() {
                let col = &u[f * k..(f + 1) * k];
                let d = dot(col, &e);
                sub_scaled(&mut e, d, col);
            }
        }
        let n = dot(&e, &e).sqrt();
        if n > 0.5 {
            for (u, e) in u[to * k..(to + 1) * k].iter_mut().zip(&e) {
                *u = e / n;
            }
            filled.push(to);
            return;
        }
    }
}

#[cfg(test)]
mod tests;
