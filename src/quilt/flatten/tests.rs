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
        op.apply(&x, &mut out);
        for i in 0..m {
            let mut v = diag[i] * x[i];
            for &(j, w) in &nbr[start[i]..start[i + 1]] {
                v -= w * x[j as usize];
            }
            assert_eq!(out[i].to_bits(), v.to_bits(), "row {i}");
        }
    }
}
