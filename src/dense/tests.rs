use super::*;

/// Deterministic values in [−1, 1).
fn values(n: usize, seed: u64) -> Vec<f64> {
    (0..n as u64)
        .map(|i| crate::rng::unit(seed, i) * 2.0 - 1.0)
        .collect()
}

/// A naive triple loop in the order `mul_add` promises.
fn naive(
    out: &mut [f32],
    ldo: usize,
    (a, lda): (&[f32], usize),
    (b, ldb): (&[f32], usize),
    (rows, inner, cols): (usize, usize, usize),
) {
    for r in 0..rows {
        for j in 0..cols {
            let mut s = out[r * ldo + j];
            for i in 0..inner {
                s += a[r * lda + i] * b[i * ldb + j];
            }
            out[r * ldo + j] = s;
        }
    }
}

#[test]
fn blocked_product_has_the_bits_of_the_plain_loop_for_every_shape() {
    for (rows, inner, cols) in [
        (1, 1, 1),
        (3, 5, 2),
        (4, 7, 16),
        (9, 13, 50),
        (17, 40, 33),
        (6, 288, 3),
    ] {
        // A and B with wider rows than they use, and B from an offset column
        let lda = inner + 2;
        let a: Vec<f32> = values(rows * lda, 1).iter().map(|&v| v as f32).collect();
        let ldb = cols + 3;
        let b: Vec<f32> = values(inner * ldb, 2).iter().map(|&v| v as f32).collect();
        let start: Vec<f32> = values(rows * cols, 3).iter().map(|&v| v as f32).collect();
        let (mut fast, mut slow) = (start.clone(), start);
        mul_add(&mut fast, cols, (&a, lda), (&b[1..], ldb), (rows, inner, cols));
        naive(&mut slow, cols, (&a, lda), (&b[1..], ldb), (rows, inner, cols));
        assert_eq!(
            fast.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            slow.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{rows}×{inner}×{cols}"
        );
    }
}

#[test]
fn transpose_swaps_rows_and_columns() {
    for (rows, cols) in [(1, 1), (5, 3), (16, 16), (33, 17)] {
        let a: Vec<f32> = (0..rows * cols).map(|i| i as f32).collect();
        let mut t = Vec::new();
        transpose_into(&a, rows, cols, &mut t);
        for r in 0..rows {
            for c in 0..cols {
                assert_eq!(t[c * rows + r], a[r * cols + c], "({r}, {c}) of {rows}×{cols}");
            }
        }
    }
}

#[test]
fn sum_of_squares_matches_a_double_precision_sum() {
    let m: Vec<f32> = values(37 * 11, 4).iter().map(|&v| v as f32).collect();
    let exact: f64 = m.iter().map(|&v| (v as f64) * (v as f64)).sum();
    let s = sum_squares(&m, 11);
    assert!((s - exact).abs() <= 1e-5 * exact, "{s} against {exact}");
}

/// Column-major product of (n × k) and (k × k).
fn times(a: &[f64], n: usize, b: &[f64], k: usize) -> Vec<f64> {
    let mut out = vec![0f64; n * k];
    for c in 0..k {
        for l in 0..k {
            for r in 0..n {
                out[c * n + r] += a[l * n + r] * b[c * k + l];
            }
        }
    }
    out
}

/// Largest |a − b| over the entries.
fn largest_difference(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0f64, f64::max)
}

/// Largest |QᵀQ − I| over the columns of the column-major `q` (n × k).
fn orthonormality_error(q: &[f64], n: usize, k: usize) -> f64 {
    let mut worst = 0f64;
    for i in 0..k {
        for j in 0..k {
            let d: f64 = (0..n).map(|r| q[i * n + r] * q[j * n + r]).sum();
            worst = worst.max((d - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    worst
}

#[test]
fn qr_reconstructs_with_orthonormal_q_and_triangular_r() {
    let (n, k) = (301, 12);
    let mut a = values(n * k, 5);
    // a zero column and a repeated one: Q still orthonormal, QR still A
    a[3 * n..4 * n].iter_mut().for_each(|v| *v = 0.0);
    let copy = a[..n].to_vec();
    a[7 * n..8 * n].copy_from_slice(&copy);
    let Qr { q, r } = qr(a.clone(), n, k);
    assert!(orthonormality_error(&q, n, k) < 1e-13);
    for c in 0..k {
        for row in c + 1..k {
            assert_eq!(r[c * k + row], 0.0, "R({row}, {c})");
        }
    }
    let worst = largest_difference(&times(&q, n, &r, k), &a);
    assert!(worst < 1e-13, "{worst}");
}

/// Columns in memory that count their reads and writes.
struct Held {
    cols: Vec<Vec<f64>>,
    reads: usize,
    writes: usize,
}

impl Columns for Held {
    type Error = std::convert::Infallible;
    fn read(&mut self, col: usize, r0: usize, out: &mut [f64]) -> Result<(), Self::Error> {
        self.reads += 1;
        out.copy_from_slice(&self.cols[col][r0..r0 + out.len()]);
        Ok(())
    }
    fn write(&mut self, col: usize, r0: usize, data: &[f64]) -> Result<(), Self::Error> {
        self.writes += 1;
        self.cols[col][r0..r0 + data.len()].copy_from_slice(data);
        Ok(())
    }
}

#[test]
fn qr_by_panels_has_the_bits_of_the_whole_qr() {
    // rows not a multiple of the dot's eight lanes, k = rows, a zero column,
    // a repeated one, and every panel width from one column to all of them
    for (n, k, seed) in [(301, 12, 5), (64, 7, 6), (9, 9, 7), (1, 1, 8), (100, 1, 9)] {
        let mut a = values(n * k, seed);
        if k > 4 {
            a[3 * n..4 * n].iter_mut().for_each(|v| *v = 0.0);
            let copy = a[..n].to_vec();
            a[(k - 1) * n..k * n].copy_from_slice(&copy);
        }
        let whole = qr(a.clone(), n, k);
        let held = || Held {
            cols: a.chunks_exact(n).map(|c| c.to_vec()).collect(),
            reads: 0,
            writes: 0,
        };
        // Q (left in the columns) and R bit for bit
        let same = |held: &Held, r: &[f64]| {
            let bits = |x: &[f64], y: &[f64]| x.iter().zip(y).all(|(x, y)| x.to_bits() == y.to_bits());
            bits(&held.cols.concat(), &whole.q) && bits(r, &whole.r)
        };
        for panel in 1..=k + 1 {
            let mut held = held();
            let r = qr_by_panels(&mut held, n, k, panel).unwrap();
            assert!(same(&held, &r), "{n} × {k} in panels of {panel}");
            // each column written twice (factored, then Q); read twice, plus
            // once for each later panel in each of the two sweeps
            let p = panel.min(k);
            let panels = k.div_ceil(p);
            assert_eq!(held.writes, 2 * k);
            let earlier: usize = (0..panels).map(|i| i * p).sum();
            assert_eq!(held.reads, 2 * k + 2 * earlier, "{n} × {k} in panels of {panel}");
        }
        // no whole column held: blocks of one row, of fewer rows than the
        // dot's eight lanes, of a number not dividing them, and of them all
        for block in [1, 3, 8, 13, n] {
            let mut held = held();
            let r = qr_in_rows(&mut held, n, k, block).unwrap();
            assert!(same(&held, &r), "{n} × {k} in blocks of {block} rows");
        }
    }
}

/// U diag(σ) Vᵀ for column-major U (n × k) and V (k × k).
fn compose(u: &[f64], n: usize, sigma: &[f64], v: &[f64]) -> Vec<f64> {
    let k = sigma.len();
    let mut us = u.to_vec();
    for (c, &s) in sigma.iter().enumerate() {
        us[c * n..(c + 1) * n].iter_mut().for_each(|x| *x *= s);
    }
    let mut vt = vec![0f64; k * k];
    for c in 0..k {
        for r in 0..k {
            vt[c * k + r] = v[r * k + c];
        }
    }
    times(&us, n, &vt, k)
}

#[test]
fn svd_recovers_known_singular_values_and_vectors() {
    let (n, k) = (200, 9);
    // M = U₀ diag(s₀) V₀ᵀ with orthonormal U₀, V₀ and known s₀, including a
    // repeated pair and two zeros
    let u0 = qr(values(n * k, 6), n, k).q;
    let v0 = qr(values(k * k, 7), k, k).q;
    let s0 = [7.0, 5.0, 3.0, 3.0, 1.0, 0.5, 1e-3, 0.0, 0.0];
    let m = compose(&u0, n, &s0, &v0);
    let Svd { u, sigma, v } = thin_svd(m.clone(), n, k);
    for (s, e) in sigma.iter().zip(s0) {
        assert!((s - e).abs() < 1e-12, "σ {sigma:?} against {s0:?}");
    }
    assert!(orthonormality_error(&u, n, k) < 1e-12);
    assert!(orthonormality_error(&v, k, k) < 1e-12);
    // U Σ Vᵀ = M
    let worst = largest_difference(&compose(&u, n, &sigma, &v), &m);
    assert!(worst < 1e-12, "{worst}");
    // distinct singular values: the vectors agree with U₀ up to sign
    for c in [0, 1, 4, 5, 6] {
        let d: f64 = (0..n).map(|r| u[c * n + r] * u0[c * n + r]).sum();
        assert!((d.abs() - 1.0).abs() < 1e-9, "column {c}: |u·u₀| = {}", d.abs());
    }
}
