//! [`qr`](super::qr) of a tall matrix kept column by column outside memory
//! (the factorization's sketch in a scratch file), a panel of columns in
//! memory at a time.
//!
//! [`qr`](super::qr) is the whole matrix as one panel. With more, each
//! column meets the same reflectors in the same order, each applied by the
//! same `dot` and `sub_scaled`: reflector j is final once column j is
//! factored (no later step writes rows j.. of column j), so applying it to
//! a column later, when that column's panel is in memory, gives the same
//! bits. Q is formed the same way, panels taken from the last back (a
//! panel's columns become Q's only after every later panel has read the
//! reflectors they held).

use super::{dot, sub_scaled, vectorized, Kernel};

/// The columns of a `rows` × `k` matrix, read and written from row `r0`
/// (`out.len()` or `data.len()` rows).
pub(crate) trait Columns {
    type Error;
    fn read(&mut self, col: usize, r0: usize, out: &mut [f64]) -> Result<(), Self::Error>;
    fn write(&mut self, col: usize, r0: usize, data: &[f64]) -> Result<(), Self::Error>;
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
            store.read(c0 + i, 0, col)?;
        }
        for j in 0..c0 {
            store.read(j, 0, &mut v)?;
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
            store.write(c0 + i, 0, col)?;
        }
    }
    for &(c0, c1) in panels.iter().rev() {
        let cols = &mut buf[..(c1 - c0) * rows];
        for (i, col) in cols.chunks_exact_mut(rows).enumerate() {
            store.read(c0 + i, 0, col)?;
        }
        vectorized(Form {
            cols,
            rows,
            c0,
            beta: &beta,
            v: &mut v,
        });
        for j in (0..c0).rev() {
            store.read(j, 0, &mut v)?;
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
            store.write(c0 + i, 0, col)?;
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
pub(super) struct Factor<'a> {
    pub(super) cols: &'a mut [f64],
    pub(super) rows: usize,
    pub(super) c0: usize,
    pub(super) k: usize,
    pub(super) r: &'a mut [f64],
    pub(super) beta: &'a mut [f64],
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
pub(super) struct Form<'a> {
    pub(super) cols: &'a mut [f64],
    pub(super) rows: usize,
    pub(super) c0: usize,
    pub(super) beta: &'a [f64],
    pub(super) v: &'a mut [f64],
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

/// [`qr_by_panels`] holding no whole column: every step streams the
/// columns it reads from the store `block` rows at a time (at least one),
/// reading each reflector back for each column it is applied to. Each dot
/// product keeps `dot`'s eight lanes across the blocks ([`Lanes`]), so the
/// bits are those of [`qr`](super::qr).
pub(crate) fn qr_in_rows<C: Columns>(
    store: &mut C,
    rows: usize,
    k: usize,
    block: usize,
) -> Result<Vec<f64>, C::Error> {
    assert!(rows >= k, "qr of a {rows} × {k} matrix");
    let block = block.max(1);
    let mut r = vec![0f64; k * k];
    let mut beta = vec![0f64; k];
    let (mut v, mut y) = (vec![0f64; block], vec![0f64; block]);
    // reflector j (column j from row j) applied to column l from row j;
    // `e` stands for column j's unit vector instead of column l
    let mut reflect = |store: &mut C, j: usize, l: Option<usize>, beta: f64| -> Result<f64, C::Error> {
        let unit = |r0: usize, y: &mut [f64]| {
            y.fill(0.0);
            if (r0..r0 + y.len()).contains(&j) {
                y[j - r0] = 1.0;
            }
        };
        // rows r0.. of the reflector into `v` and of the column into `y`
        let load = |store: &mut C, r0: usize, v: &mut [f64], y: &mut [f64]| -> Result<(), C::Error> {
            store.read(j, r0, v)?;
            match l {
                Some(l) => store.read(l, r0, y),
                None => Ok(unit(r0, y)),
            }
        };
        let mut lanes = Lanes::new(rows - j);
        for r0 in (j..rows).step_by(block) {
            let n = block.min(rows - r0);
            load(store, r0, &mut v[..n], &mut y[..n])?;
            lanes.feed(&v[..n], &y[..n]);
        }
        let f = beta * lanes.sum();
        let mut first = 0.0;
        for r0 in (j..rows).step_by(block) {
            let n = block.min(rows - r0);
            load(store, r0, &mut v[..n], &mut y[..n])?;
            sub_scaled(&mut y[..n], f, &v[..n]);
            store.write(l.unwrap_or(j), r0, &y[..n])?;
            if r0 == j {
                first = y[0];
            }
        }
        Ok(first)
    };
    let mut buf = vec![0f64; block];
    for j in 0..k {
        // the reflector of column j: its norm below row j
        let mut tail = Lanes::new(rows - j - 1);
        let mut x0 = 0.0;
        for r0 in (j..rows).step_by(block) {
            let n = block.min(rows - r0);
            store.read(j, r0, &mut buf[..n])?;
            if r0 == j {
                x0 = buf[0];
                tail.feed(&buf[1..n], &buf[1..n]);
            } else {
                tail.feed(&buf[..n], &buf[..n]);
            }
        }
        let tail = tail.sum();
        let norm = (x0 * x0 + tail).sqrt();
        if norm > 0.0 {
            let alpha = if x0 >= 0.0 { -norm } else { norm };
            let v0 = x0 - alpha;
            beta[j] = 2.0 / (v0 * v0 + tail);
            r[j * k + j] = alpha;
            store.write(j, j, &[v0])?;
        }
        for l in j + 1..k {
            r[l * k + j] = if beta[j] != 0.0 {
                reflect(store, j, Some(l), beta[j])?
            } else {
                let mut y0 = [0.0];
                store.read(l, j, &mut y0)?;
                y0[0]
            };
        }
    }
    for j in (0..k).rev() {
        // the columns after j first, while column j still holds its reflector
        if beta[j] != 0.0 {
            for l in j + 1..k {
                reflect(store, j, Some(l), beta[j])?;
            }
        }
        // column j becomes e_j, then H_j e_j
        for r0 in (0..j).step_by(block) {
            let n = block.min(j - r0);
            buf[..n].fill(0.0);
            store.write(j, r0, &buf[..n])?;
        }
        if beta[j] != 0.0 {
            reflect(store, j, None, beta[j])?;
        } else {
            for r0 in (j..rows).step_by(block) {
                let n = block.min(rows - r0);
                buf[..n].fill(0.0);
                if r0 == j {
                    buf[0] = 1.0;
                }
                store.write(j, r0, &buf[..n])?;
            }
        }
    }
    Ok(r)
}

/// `dot`'s sum over a vector fed in pieces: element i goes to lane i mod 8
/// while a whole group of eight remains, the rest is added after the lanes.
struct Lanes {
    lanes: [f64; 8],
    i: usize,
    full: usize,
    tail: Option<f64>,
}

impl Lanes {
    fn new(len: usize) -> Lanes {
        Lanes {
            lanes: [0.0; 8],
            i: 0,
            full: len - len % 8,
            tail: None,
        }
    }

    fn feed(&mut self, x: &[f64], y: &[f64]) {
        for (x, y) in x.iter().zip(y) {
            if self.i < self.full {
                self.lanes[self.i % 8] += x * y;
            } else {
                let s = self.tail.get_or_insert_with(|| reduce(&self.lanes));
                *s += x * y;
            }
            self.i += 1;
        }
    }

    fn sum(&self) -> f64 {
        self.tail.unwrap_or_else(|| reduce(&self.lanes))
    }
}

/// `dot`'s sum of its lanes.
fn reduce(l: &[f64; 8]) -> f64 {
    ((l[0] + l[1]) + (l[2] + l[3])) + ((l[4] + l[5]) + (l[6] + l[7]))
}
