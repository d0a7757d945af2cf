//! [`qr`](super::qr) of a tall matrix kept column by column outside memory
//! (the factorization's sketch in a scratch file), a panel of columns in
//! memory at a time.
//!
//! Each column meets the same reflectors in the same order as in the
//! right-looking [`qr`](super::qr), and each reflector is applied by the
//! same `dot` and `sub_scaled`: reflector j is final once column j is
//! factored (no later step writes rows j.. of column j), so applying it to
//! a column later, when that column's panel is in memory, gives the same
//! bits. Q is formed the same way, panels taken from the last back (a
//! panel's columns become Q's only after every later panel has read the
//! reflectors they held).

use super::{dot, sub_scaled, vectorized, Kernel};

/// The columns of a `rows` × `k` matrix, read and written whole.
pub(crate) trait Columns {
    type Error;
    fn read(&mut self, col: usize, out: &mut [f64]) -> Result<(), Self::Error>;
    fn write(&mut self, col: usize, data: &[f64]) -> Result<(), Self::Error>;
}

/// Replaces the `k` columns in `store` (`rows` each, `rows ≥ k`) by the Q
/// of their Householder QR and returns R (`k` × `k`, column-major): the
/// same bits as [`qr`](super::qr) of the whole matrix. Holds `panel`
/// columns (at least one) and one more in memory.
pub(crate) fn qr_by_panels<C: Columns>(
    store: &mut C,
    rows: usize,
    k: usize,
    panel: usize,
) -> Result<Vec<f64>, C::Error> {
    assert!(rows >= k, "qr of a {rows} × {k} matrix");
    let p = panel.clamp(1, k.max(1));
    let mut r = vec![0f64; k * k];
    let mut beta = vec![0f64; k];
    let mut buf = vec![0f64; p * rows];
    let mut v = vec![0f64; rows];
    let panels: Vec<(usize, usize)> = (0..k).step_by(p).map(|c0| (c0, (c0 + p).min(k))).collect();
    for &(c0, c1) in &panels {
        let cols = &mut buf[..(c1 - c0) * rows];
        for (i, col) in cols.chunks_exact_mut(rows).enumerate() {
            store.read(c0 + i, col)?;
        }
        for j in 0..c0 {
            store.read(j, &mut v)?;
            vectorized(Reflect {
                beta: beta[j],
                v: &v[j..],
                cols,
                rows,
                j,
                r: Some((&mut r[c0 * k..], k)),
            });
        }
        vectorized(Factor {
            cols,
            rows,
            c0,
            k,
            r: &mut r,
            beta: &mut beta,
        });
        for (i, col) in cols.chunks_exact(rows).enumerate() {
            store.write(c0 + i, col)?;
        }
    }
    for &(c0, c1) in panels.iter().rev() {
        let cols = &mut buf[..(c1 - c0) * rows];
        for (i, col) in cols.chunks_exact_mut(rows).enumerate() {
            store.read(c0 + i, col)?;
        }
        vectorized(Form {
            cols,
            rows,
            c0,
            beta: &beta,
            v: &mut v,
        });
        for j in (0..c0).rev() {
            store.read(j, &mut v)?;
            vectorized(Reflect {
                beta: beta[j],
                v: &v[j..],
                cols,
                rows,
                j,
                r: None,
            });
        }
        for (i, col) in cols.chunks_exact(rows).enumerate() {
            store.write(c0 + i, col)?;
        }
    }
    Ok(r)
}

/// Reflector j (`v`: column j from row j, its `beta`) applied to each
/// column of `cols` from row j; with `r`, each column's row j then goes to
/// R (`r[l·k + j]` for the l-th column of `cols`).
struct Reflect<'a> {
    beta: f64,
    v: &'a [f64],
    cols: &'a mut [f64],
    rows: usize,
    j: usize,
    r: Option<(&'a mut [f64], usize)>,
}

impl Kernel for Reflect<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let Reflect {
            beta,
            v,
            cols,
            rows,
            j,
            mut r,
        } = self;
        for (l, col) in cols.chunks_exact_mut(rows).enumerate() {
            let y = &mut col[j..];
            if beta != 0.0 {
                let f = beta * dot(v, y);
                sub_scaled(y, f, v);
            }
            if let Some((r, k)) = r.as_mut() {
                r[l * *k + j] = y[0];
            }
        }
    }
}

/// The factoring steps of the panel's own columns (global `c0..`), each
/// reflector applied to the panel's columns after it.
struct Factor<'a> {
    cols: &'a mut [f64],
    rows: usize,
    c0: usize,
    k: usize,
    r: &'a mut [f64],
    beta: &'a mut [f64],
}

impl Kernel for Factor<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let Factor {
            cols,
            rows,
            c0,
            k,
            r,
            beta,
        } = self;
        for i in 0..cols.len() / rows {
            let j = c0 + i;
            let (done, rest) = cols.split_at_mut((i + 1) * rows);
            let v = &mut done[i * rows + j..];
            let tail = dot(&v[1..], &v[1..]);
            let x0 = v[0];
            let norm = (x0 * x0 + tail).sqrt();
            if norm > 0.0 {
                let alpha = if x0 >= 0.0 { -norm } else { norm };
                v[0] = x0 - alpha;
                beta[j] = 2.0 / (v[0] * v[0] + tail);
                r[j * k + j] = alpha;
            }
            for (l, col) in rest.chunks_exact_mut(rows).enumerate() {
                let y = &mut col[j..];
                if beta[j] != 0.0 {
                    let f = beta[j] * dot(v, y);
                    sub_scaled(y, f, v);
                }
                r[(j + 1 + l) * k + j] = y[0];
            }
        }
    }
}

/// The panel's columns (global `c0..`) made Q's but for the reflectors of
/// the earlier columns: from the panel's last column back, the column's
/// reflector taken out into `v`, the column set to e_j and the reflector
/// applied to it and the panel's columns after it.
struct Form<'a> {
    cols: &'a mut [f64],
    rows: usize,
    c0: usize,
    beta: &'a [f64],
    v: &'a mut [f64],
}

impl Kernel for Form<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let Form {
            cols,
            rows,
            c0,
            beta,
            v,
        } = self;
        for i in (0..cols.len() / rows).rev() {
            let j = c0 + i;
            let v = &mut v[..rows - j];
            let cols = &mut cols[i * rows..];
            v.copy_from_slice(&cols[j..rows]);
            cols[..rows].fill(0.0);
            cols[j] = 1.0;
            if beta[j] == 0.0 {
                continue;
            }
            for col in cols.chunks_exact_mut(rows) {
                let y = &mut col[j..];
                let f = beta[j] * dot(v, y);
                sub_scaled(y, f, v);
            }
        }
    }
}
