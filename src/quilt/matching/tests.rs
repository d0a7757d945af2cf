use super::*;

#[test]
fn fast_sizes() {
    for (n, want) in [
        (1, 1),
        (7, 8),
        (11, 12),
        (17, 18),
        (97, 100),
        (193, 200),
        (255, 256),
        (383, 384),
    ] {
        assert_eq!(fast_size(n), want, "{n}");
    }
    for n in 1..2000 {
        let f = fast_size(n);
        assert!(f >= n);
        let mut r = f;
        for p in [2, 3, 5] {
            while r % p == 0 {
                r /= p;
            }
        }
        assert_eq!(r, 1, "{n} → {f}");
        assert!((n..f).all(|m| {
            let mut r = m;
            for p in [2, 3, 5] {
                while r % p == 0 {
                    r /= p;
                }
            }
            r != 1
        }));
    }
}

#[test]
fn axis_ranges() {
    assert_eq!(axis(64, 192, Span::Contained), ((-128, 0), 192));
    assert_eq!(axis(20, 12, Span::Contained), ((0, 8), 20));
    assert_eq!(axis(9, 9, Span::Contained), ((0, 0), 9));
    assert_eq!(axis(5, 7, Span::Overlapping), ((-6, 4), 11));
}

#[test]
fn unpack_recovers_lane_spectra() {
    let (nx, ny) = (6, 5);
    let mut planner = FftPlanner::new();
    let plans = Plans {
        nx,
        ny,
        fx: planner.plan_fft_forward(nx),
        fy: planner.plan_fft_forward(ny),
        ix: planner.plan_fft_inverse(nx),
        iy: planner.plan_fft_inverse(ny),
    };
    let a: Vec<f64> = (0..12).map(|i| (i as f64 * 0.7).sin()).collect();
    let b: Vec<f64> = (0..12).map(|i| (i as f64 * 1.3).cos()).collect();
    let spectrum = |f: &dyn Fn(usize) -> C64| {
        let mut rows = vec![ZERO; 3 * nx];
        for y in 0..3 {
            for x in 0..4 {
                rows[y * nx + x] = f(y * 4 + x);
            }
        }
        let mut spec = vec![ZERO; nx * ny];
        forward_2d(&plans, &mut rows, 3, &mut spec, None);
        spec
    };
    let z = spectrum(&|i| C64::new(a[i], b[i]));
    let (fa, fb) = (
        spectrum(&|i| C64::new(a[i], 0.0)),
        spectrum(&|i| C64::new(b[i], 0.0)),
    );
    let mut out = vec![ZERO; nx * ny];
    for (part, want) in [(0, &fa), (1, &fb)] {
        unpack_lane(nx, ny, &z, part, &mut out);
        for (o, w) in out.iter().zip(want.iter()) {
            assert!((o - w).norm() < 1e-12, "{o} {w}");
        }
    }
}
