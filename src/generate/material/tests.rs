use super::*;

fn params(family: Family, imperfection: Imperfection, n: usize, seed: u64) -> MaterialParams {
    MaterialParams {
        family,
        imperfection,
        width: n,
        height: n,
        seed,
    }
}

fn bits(m: &Mesostructure) -> Vec<u32> {
    let mut v = Vec::new();
    for i in 0..m.width * m.height {
        v.push(m.height_field[i].to_bits());
        v.extend(m.albedo[i].iter().map(|c| c.to_bits()));
        v.push(m.specular[i].to_bits());
        v.push(m.roughness[i].to_bits());
        v.push(m.mask[i].to_bits());
    }
    v
}

#[test]
fn names_round_trip() {
    for f in Family::ALL {
        assert_eq!(Family::parse(f.name()), Some(f));
    }
    for i in Imperfection::ALL {
        assert_eq!(Imperfection::parse(i.name()), Some(i));
    }
    assert_eq!(Family::parse("Bricks"), Some(Family::Bricks));
    assert_eq!(Family::parse("marble"), None);
    assert_eq!(Imperfection::parse("dust"), None);
}

#[test]
fn deterministic_across_thread_counts() {
    for f in Family::ALL {
        let p = params(f, Imperfection::Stains, 64, 42);
        let a = Mesostructure::generate(&p);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let b = pool.install(|| Mesostructure::generate(&p));
        let pool3 = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let c = pool3.install(|| Mesostructure::generate(&p));
        assert_eq!(bits(&a), bits(&b), "{f:?}");
        assert_eq!(bits(&a), bits(&c), "{f:?}");
        // A different seed gives a different sample.
        let d = Mesostructure::generate(&params(f, Imperfection::Stains, 64, 43));
        assert_ne!(bits(&a), bits(&d), "{f:?}");
    }
}

#[test]
fn fields_in_range() {
    for f in Family::ALL {
        for imp in Imperfection::ALL {
            let m = Mesostructure::generate(&params(f, imp, 96, 7));
            let n = 96 * 96;
            assert_eq!(m.height_field.len(), n);
            assert!(m.min_height >= 0.0 && m.max_height <= 4.0, "{f:?} {imp:?}");
            assert!(m.max_height - m.min_height > 1.0, "{f:?} {imp:?} too flat");
            for i in 0..n {
                let h = m.height_field[i];
                assert!(h >= m.min_height && h <= m.max_height);
                assert!(m.albedo[i].iter().all(|c| (0.0..=1.0).contains(c)));
                assert!((0.0..=1.0).contains(&m.specular[i]));
                assert!((0.05..=1.0).contains(&m.roughness[i]));
                assert!((0.0..=1.0).contains(&m.mask[i]));
            }
        }
    }
}

#[test]
fn mask_coverage() {
    for f in Family::ALL {
        for seed in [1u64, 2, 3] {
            for n in [128usize, 256] {
                let m = Mesostructure::generate(&params(f, Imperfection::None, 64, seed));
                assert!(m.mask.iter().all(|&v| v == 0.0));
                for imp in [
                    Imperfection::Cracks,
                    Imperfection::Stains,
                    Imperfection::Scratches,
                ] {
                    let m = Mesostructure::generate(&params(f, imp, n, seed));
                    let cover = m.mask.iter().filter(|&&v| v > 0.5).count() as f32 / m.mask.len() as f32;
                    assert!(
                        (0.02..=0.40).contains(&cover),
                        "{f:?} {imp:?} seed {seed} n {n}: coverage {cover}"
                    );
                }
            }
        }
    }
}

#[test]
fn fields_are_periodic() {
    for f in Family::ALL {
        for imp in Imperfection::ALL {
            let (w, h) = (96usize, 80usize);
            let p = MaterialParams {
                family: f,
                imperfection: imp,
                width: w,
                height: h,
                seed: 5,
            };
            // The generating functions repeat with period (w, h), up to
            // float rounding of the shifted coordinates.
            let g = Gen::new(&p);
            let mut bad = 0;
            let mut total = 0;
            for y in (0..h).step_by(3) {
                for x in (0..w).step_by(3) {
                    let (xf, yf) = (x as f32, y as f32);
                    let a = g.texel(xf, yf);
                    for b in [g.texel(xf + w as f32, yf), g.texel(xf, yf - h as f32)] {
                        total += 1;
                        let da = (0..3).map(|c| (a.a[c] - b.a[c]).abs()).fold(0.0, f32::max);
                        if (a.h - b.h).abs() > 1e-3 || da > 1e-3 || (a.m - b.m).abs() > 1e-3 {
                            bad += 1;
                        }
                    }
                }
            }
            assert!(bad * 100 <= total, "{f:?} {imp:?}: {bad} of {total} differ");
            // height_at wraps and interpolates across the seam.
            let m = Mesostructure::generate(&p);
            for y in [0usize, 17, h - 1] {
                let a = m.height_field[y * w + w - 1];
                let b = m.height_field[y * w];
                let mid = m.height_at(-0.5, y as f32);
                assert!((mid - 0.5 * (a + b)).abs() < 1e-5);
                assert_eq!(m.height_at(w as f32, y as f32), b);
                assert_eq!(m.height_at(3.0, (y + h) as f32), m.height_field[y * w + 3]);
            }
        }
    }
}

#[test]
fn feature_size_is_in_texels() {
    // Bricks: the number of brick rows scales with the sample height.
    let a = Gen::new(&params(Family::Bricks, Imperfection::None, 128, 1));
    let b = Gen::new(&params(Family::Bricks, Imperfection::None, 512, 1));
    assert!((b.gy as f32 / (4 * a.gy) as f32 - 1.0).abs() < 0.1);
    assert!((a.gh - b.gh).abs() < 1.5 && (a.gw - b.gw).abs() < 1.5);
    assert!((12.0..=16.0).contains(&a.gh) && (28.0..=36.0).contains(&a.gw));
    assert!(a.gx >= 4 && a.gy >= 8);
    // Weave yarn spacing about 8 texels.
    let w = Gen::new(&params(Family::Weave, Imperfection::None, 128, 1));
    assert!((7.0..=9.0).contains(&w.gw));
}
