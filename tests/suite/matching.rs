//! Entire-patch matching: FFT costs against direct sums, planted offsets,
//! the constraint term, the spectrum cache and the seeded choice.

use btfquilt::factorize::rotate_maps;
use btfquilt::quilt::matching::{
    brute_force_cost, brute_force_map, choose, direct_costs, direct_costs_in, footprint, known_box,
    placement_range, valid_to_f32, CostMap, Image, MatchConfig, Matcher, Placement, Sample, Span, Work,
};

/// splitmix64 stream → uniform [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    fn vec(&mut self, len: usize) -> Vec<f32> {
        (0..len).map(|_| self.unit()).collect()
    }
    /// 0/1 mask with probability `p` of 1.
    fn mask(&mut self, len: usize, p: f32) -> Vec<f32> {
        (0..len)
            .map(|_| if self.unit() < p { 1.0 } else { 0.0 })
            .collect()
    }
}

fn img(width: usize, height: usize, channels: usize, data: &[f32]) -> Image<'_> {
    Image::new(width, height, channels, data).unwrap()
}

/// Every placement: same acceptance, overlap to 1e-9 and cost to 1e-6
/// relative (relative to the cost's own scale where the cost is tiny).
fn assert_maps_close(fft: &CostMap, bf: &CostMap, scale: f64, what: &str) {
    assert_eq!(
        (fft.dx0, fft.dy0, fft.columns, fft.rows),
        (bf.dx0, bf.dy0, bf.columns, bf.rows),
        "{what}"
    );
    let mut finite = 0;
    for i in 0..fft.cost.len() {
        let (a, b) = (fft.overlap[i], bf.overlap[i]);
        assert!(
            (a - b).abs() <= 1e-9 * (1.0 + b.abs()),
            "{what}: overlap {i}: {a} vs {b}"
        );
        let (a, b) = (fft.cost[i], bf.cost[i]);
        assert_eq!(a.is_finite(), b.is_finite(), "{what}: acceptance {i}: {a} vs {b}");
        if b.is_finite() {
            finite += 1;
            assert!(
                (a - b).abs() <= 1e-6 * b.abs() + 1e-9 * scale,
                "{what}: cost {i}: {a} vs {b}"
            );
        }
    }
    assert!(finite > 0, "{what}: no placement accepted");
}

/// Validity with a rectangular hole and a few random holes.
fn holey_valid(rng: &mut Rng, w: usize, h: usize) -> Vec<f32> {
    let mut v = rng.mask(w * h, 0.9);
    for y in h / 3..h / 2 {
        for x in w / 4..w / 2 {
            v[y * w + x] = 0.0;
        }
    }
    v
}

#[test]
fn fft_costs_equal_brute_force() {
    // (sample w, h), (work w, h), channels, span, real-valued weights
    let cases = [
        ((17, 13), (9, 6), 1, Span::Contained, false),
        ((30, 24), (30, 10), 3, Span::Contained, false),
        ((12, 20), (16, 9), 3, Span::Contained, true),
        ((25, 25), (7, 11), 40, Span::Contained, false),
        ((19, 14), (11, 5), 40, Span::Contained, true),
        ((9, 7), (6, 10), 3, Span::Overlapping, false),
        ((13, 11), (8, 8), 1, Span::Overlapping, true),
        ((21, 16), (5, 5), 40, Span::Overlapping, false),
        ((1, 8), (1, 3), 2, Span::Contained, false),
    ];
    let mut rng = Rng(1);
    let mut matcher = Matcher::new();
    for (k, &((sw, sh), (ww, wh), n, span, weights)) in cases.iter().enumerate() {
        let sdata = rng.vec(sw * sh * n);
        let wdata = rng.vec(ww * wh * n);
        let known: Vec<f32> = if weights {
            rng.vec(ww * wh)
                .iter()
                .map(|&u| if u < 0.3 { 0.0 } else { u })
                .collect()
        } else {
            rng.mask(ww * wh, 0.6)
        };
        let valid = holey_valid(&mut rng, sw, sh);
        let work = Work {
            image: img(ww, wh, n, &wdata),
            known: &known,
            constraint: None,
        };
        let sample = Sample {
            image: img(sw, sh, n, &sdata),
            valid: &valid,
            constraint: None,
            key: k as u64,
        };
        let cfg = MatchConfig {
            min_overlap: 1.0,
            span,
            ..MatchConfig::default()
        };
        let fft = matcher.cost_map(&work, &sample, &cfg).unwrap();
        let bf = brute_force_map(&work, &sample, &cfg).unwrap();
        assert_maps_close(&fft, &bf, n as f64, &format!("case {k}"));
        // spot-check the single-placement reference too
        let p = brute_force_cost(&work, &sample, &cfg, bf.dx0, bf.dy0).unwrap();
        assert_eq!((p.cost, p.overlap), (bf.cost[0], bf.overlap[0]));
        // match_patch agrees with the brute-force ranking
        let best = matcher.match_patch(&work, &sample, &cfg).unwrap();
        let bf_best = bf.best(cfg.candidates, cfg.tolerance);
        assert_eq!(
            (best[0].dx, best[0].dy),
            (bf_best[0].dx, bf_best[0].dy),
            "case {k}"
        );
    }
}

/// The direct sums of coarse-to-fine matching's fine step give the
/// brute-force reference's costs bit for bit (the same sums, skipping only
/// zero terms), with and without constraint channels, at placements in any
/// order, repeated, and outside the map (no overlap: rejected); and the
/// placement range is the map's.
#[test]
fn direct_costs_equal_brute_force() {
    let mut rng = Rng(11);
    for (k, &((sw, sh), (ww, wh), n, nc, span)) in [
        ((17, 13), (9, 6), 3, 0, Span::Contained),
        ((12, 20), (16, 9), 40, 0, Span::Contained),
        ((23, 18), (10, 7), 3, 2, Span::Overlapping),
    ]
    .iter()
    .enumerate()
    {
        let sdata = rng.vec(sw * sh * n);
        let wdata = rng.vec(ww * wh * n);
        let (sc, wc) = (rng.vec(sw * sh * nc), rng.vec(ww * wh * nc));
        let known: Vec<f32> = rng
            .vec(ww * wh)
            .iter()
            .map(|&u| if u < 0.3 { 0.0 } else { u })
            .collect();
        let valid = holey_valid(&mut rng, sw, sh);
        let work = Work {
            image: img(ww, wh, n, &wdata),
            known: &known,
            constraint: (nc > 0).then(|| img(ww, wh, nc, &wc)),
        };
        let sample = Sample {
            image: img(sw, sh, n, &sdata),
            valid: &valid,
            constraint: (nc > 0).then(|| img(sw, sh, nc, &sc)),
            key: k as u64,
        };
        let cfg = MatchConfig {
            min_overlap: 2.0,
            constraint_weight: 0.7,
            span,
            ..MatchConfig::default()
        };
        let bf = brute_force_map(&work, &sample, &cfg).unwrap();
        let [(x0, x1), (y0, y1)] = placement_range([ww, wh], [sw, sh], span);
        assert_eq!((x0, y0), (bf.dx0, bf.dy0), "case {k}");
        assert_eq!(
            ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize),
            (bf.columns, bf.rows)
        );
        let mut at: Vec<(i32, i32)> = (y0..=y1)
            .rev()
            .flat_map(|y| (x0..=x1).map(move |x| (x, y)))
            .collect();
        at.push(at[0]);
        at.push((x1 + sw as i32 + 1, y0));
        let got = direct_costs(&work, &sample, &cfg, &at).unwrap();
        assert_eq!(got.len(), at.len());
        for (p, &(dx, dy)) in got.iter().zip(&at) {
            assert_eq!((p.dx, p.dy), (dx, dy));
            match bf.get(dx, dy) {
                Some((cost, overlap)) => {
                    assert_eq!((p.cost, p.overlap), (cost, overlap), "case {k} at {dx},{dy}")
                }
                None => assert!(p.cost.is_infinite() && p.overlap == 0.0, "{p:?}"),
            }
        }
        assert!(bf.cost.iter().any(|c| c.is_finite()), "case {k}");
        // against only the sample pixels a run of placements reads (their
        // footprint, cut out with its constraint): the same costs bit for bit
        let known_box = known_box(&work);
        let max_valid = valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
        for run in at.chunks(7) {
            let (fx, fy, fw, fh) = footprint(known_box, run, [sw, sh]);
            let cut = |data: &[f32], c: usize| -> Vec<f32> {
                (fy..fy + fh)
                    .flat_map(|y| &data[(y * sw + fx) * c..(y * sw + fx + fw) * c])
                    .copied()
                    .collect()
            };
            let (wmaps, wvalid, wcons) = (cut(&sdata, n), cut(&valid, 1), cut(&sc, nc));
            let window = Sample {
                image: img(fw, fh, n, &wmaps),
                valid: &wvalid,
                constraint: (nc > 0).then(|| img(fw, fh, nc, &wcons)),
                key: 99,
            };
            let windowed = direct_costs_in(&work, &window, [fx, fy], max_valid, &cfg, run).unwrap();
            let whole = direct_costs(&work, &sample, &cfg, run).unwrap();
            assert_eq!(windowed, whole, "case {k}, window {fx},{fy} {fw}×{fh}");
        }
    }
}

#[test]
fn rotated_sample_with_invalid_corners_matches_brute_force() {
    let (w, h, n) = (40, 32, 3);
    let mut rng = Rng(2);
    let maps = rng.vec(w * h * n);
    let (rot, valid8) = rotate_maps(&maps, w, h, n, 45.0, false);
    let valid = valid_to_f32(&valid8);
    assert!(valid.contains(&0.0));
    let wdata = rng.vec(16 * 12 * n);
    let known = rng.mask(16 * 12, 0.5);
    let work = Work {
        image: img(16, 12, n, &wdata),
        known: &known,
        constraint: None,
    };
    let sample = Sample {
        image: img(w, h, n, &rot),
        valid: &valid,
        constraint: None,
        key: 30,
    };
    let cfg = MatchConfig {
        min_overlap: 0.9 * known.iter().sum::<f32>() as f64,
        ..MatchConfig::default()
    };
    let fft = Matcher::new().cost_map(&work, &sample, &cfg).unwrap();
    let bf = brute_force_map(&work, &sample, &cfg).unwrap();
    assert_maps_close(&fft, &bf, n as f64, "rotated");
    assert!(
        bf.cost.iter().any(|c| c.is_infinite()),
        "some placements must fall below min_overlap"
    );
}

#[test]
fn planted_offset_is_found_with_zero_cost() {
    for (n, seed) in [(3, 3), (40, 4)] {
        let (sw, sh, ww, wh) = (48, 40, 16, 12);
        let (ox, oy) = (13usize, 7usize);
        let mut rng = Rng(seed);
        let sdata = rng.vec(sw * sh * n);
        let mut wdata = vec![0f32; ww * wh * n];
        for y in 0..wh {
            for x in 0..ww {
                let s = ((y + oy) * sw + x + ox) * n;
                wdata[(y * ww + x) * n..(y * ww + x + 1) * n].copy_from_slice(&sdata[s..s + n]);
            }
        }
        // partially known: an L-shaped band as in synthesis, plus noise where unknown
        let mut known = vec![0f32; ww * wh];
        for y in 0..wh {
            for x in 0..ww {
                if y < 4 || x < 5 {
                    known[y * ww + x] = 1.0;
                } else {
                    for c in 0..n {
                        wdata[(y * ww + x) * n + c] = rng.unit() * 5.0;
                    }
                }
            }
        }
        let valid = vec![1f32; sw * sh];
        let work = Work {
            image: img(ww, wh, n, &wdata),
            known: &known,
            constraint: None,
        };
        let sample = Sample {
            image: img(sw, sh, n, &sdata),
            valid: &valid,
            constraint: None,
            key: 0,
        };
        let cfg = MatchConfig {
            min_overlap: 0.1 * known.iter().sum::<f32>() as f64,
            candidates: 5,
            tolerance: f64::INFINITY,
            ..MatchConfig::default()
        };
        let best = Matcher::new().match_patch(&work, &sample, &cfg).unwrap();
        assert_eq!(best.len(), 5);
        assert_eq!(
            (best[0].dx, best[0].dy),
            (-(ox as i32), -(oy as i32)),
            "n = {n}: {best:?}"
        );
        assert!(best[0].cost < 1e-9, "{:?}", best[0]);
        assert!(best[1].cost > 0.01 * n as f64, "{:?}", best[1]);
        assert_eq!(best[0].overlap.round(), known.iter().sum::<f32>() as f64);
        assert!(best.windows(2).all(|w| w[0].cost <= w[1].cost));
    }
}

#[test]
fn constraint_term_adds_weighted() {
    let (sw, sh, ww, wh, n, nc) = (23, 18, 10, 7, 3, 2);
    let mut rng = Rng(5);
    let sdata = rng.vec(sw * sh * n);
    let wdata = rng.vec(ww * wh * n);
    let sc = rng.vec(sw * sh * nc);
    let wc = rng.vec(ww * wh * nc);
    let known = rng.mask(ww * wh, 0.7);
    let valid = holey_valid(&mut rng, sw, sh);
    let weight = 0.7;
    let cfg = MatchConfig {
        constraint_weight: weight,
        ..MatchConfig::default()
    };
    let both = (
        Work {
            image: img(ww, wh, n, &wdata),
            known: &known,
            constraint: Some(img(ww, wh, nc, &wc)),
        },
        Sample {
            image: img(sw, sh, n, &sdata),
            valid: &valid,
            constraint: Some(img(sw, sh, nc, &sc)),
            key: 1,
        },
    );
    let features = (
        Work {
            constraint: None,
            ..both.0
        },
        Sample {
            constraint: None,
            key: 2,
            ..both.1
        },
    );
    let constraint = (
        Work {
            image: img(ww, wh, nc, &wc),
            ..features.0
        },
        Sample {
            image: img(sw, sh, nc, &sc),
            key: 3,
            ..features.1
        },
    );
    let mut m = Matcher::new();
    let total = m.cost_map(&both.0, &both.1, &cfg).unwrap();
    let f = m.cost_map(&features.0, &features.1, &cfg).unwrap();
    let c = m.cost_map(&constraint.0, &constraint.1, &cfg).unwrap();
    assert_maps_close(
        &total,
        &brute_force_map(&both.0, &both.1, &cfg).unwrap(),
        3.0,
        "total",
    );
    for i in 0..total.cost.len() {
        if total.cost[i].is_finite() {
            let want = f.cost[i] + weight * c.cost[i];
            assert!((total.cost[i] - want).abs() < 1e-9 * (1.0 + want), "{i}");
        }
    }
    // the weight really matters
    let cfg0 = MatchConfig {
        constraint_weight: 0.0,
        ..cfg
    };
    let t0 = m.cost_map(&both.0, &both.1, &cfg0).unwrap();
    for i in 0..t0.cost.len() {
        if t0.cost[i].is_finite() {
            assert!((t0.cost[i] - f.cost[i]).abs() < 1e-9 * (1.0 + f.cost[i]));
        }
    }
    // constraint given on one side only is an error
    assert!(m.cost_map(&both.0, &features.1, &cfg).is_err());
}

#[test]
fn spectrum_cache_is_reused() {
    let (sw, sh, ww, wh, n) = (32, 30, 12, 9, 5);
    let mut rng = Rng(6);
    let sdata = rng.vec(sw * sh * n);
    let valid = holey_valid(&mut rng, sw, sh);
    let w1 = rng.vec(ww * wh * n);
    let w2 = rng.vec(ww * wh * n);
    let known = rng.mask(ww * wh, 0.5);
    let sample = Sample {
        image: img(sw, sh, n, &sdata),
        valid: &valid,
        constraint: None,
        key: 77,
    };
    fn work<'a>(d: &'a [f32], known: &'a [f32]) -> Work<'a> {
        Work {
            image: Image::new(12, 9, 5, d).unwrap(),
            known,
            constraint: None,
        }
    }
    let cfg = MatchConfig::default();
    let mut m = Matcher::new();
    let a = m.match_patch(&work(&w1, &known), &sample, &cfg).unwrap();
    assert_eq!((m.spectra_computed(), m.spectra_reused()), (1, 0));
    let map_a = m.cost_map(&work(&w1, &known), &sample, &cfg).unwrap();
    let b = m.match_patch(&work(&w1, &known), &sample, &cfg).unwrap();
    assert_eq!((m.spectra_computed(), m.spectra_reused()), (1, 2));
    assert_eq!(a, b);
    // another work image against the cached sample
    let c = m.cost_map(&work(&w2, &known), &sample, &cfg).unwrap();
    assert_eq!(m.spectra_computed(), 1);
    assert_maps_close(
        &c,
        &brute_force_map(&work(&w2, &known), &sample, &cfg).unwrap(),
        n as f64,
        "cached",
    );
    // a fresh matcher computes the same map bit for bit
    let mut fresh = Matcher::new();
    assert_eq!(fresh.cost_map(&work(&w1, &known), &sample, &cfg).unwrap(), map_a);
    // another key (or span → FFT size) is another entry
    let other = Sample { key: 78, ..sample };
    m.cost_map(&work(&w1, &known), &other, &cfg).unwrap();
    assert_eq!(m.spectra_computed(), 2);
    let over = MatchConfig {
        span: Span::Overlapping,
        ..cfg
    };
    m.cost_map(&work(&w1, &known), &sample, &over).unwrap();
    assert_eq!(m.spectra_computed(), 3);
    assert!(m.cache_bytes() > 0);
    // a budget of one byte keeps none
    let mut tiny = Matcher::with_cache_budget(1);
    tiny.cost_map(&work(&w1, &known), &sample, &cfg).unwrap();
    tiny.cost_map(&work(&w1, &known), &other, &cfg).unwrap();
    tiny.cost_map(&work(&w1, &known), &sample, &cfg).unwrap();
    assert_eq!((tiny.spectra_computed(), tiny.spectra_reused()), (3, 0));
    tiny.clear_cache();
    assert_eq!(tiny.cache_bytes(), 0);
    // a match whose spectra its cache cannot keep transforms them a pair
    // at a time as the sum reaches them: two buffers more than a cached
    // match, far less than the spectra, and the same map bit for bit
    assert!(tiny.match_bytes() > fresh.match_bytes());
    assert!(tiny.match_bytes() < fresh.match_bytes() + fresh.cache_bytes() / 2);
    assert_eq!(tiny.cost_map(&work(&w1, &known), &sample, &cfg).unwrap(), map_a);
    // freed buffers: the figure is kept, the next match gives the same map
    let held = tiny.match_bytes();
    tiny.release_buffers();
    assert_eq!(tiny.match_bytes(), held);
    assert_eq!(tiny.cost_map(&work(&w1, &known), &sample, &cfg).unwrap(), map_a);
    assert_eq!(tiny.match_bytes(), held);
}

#[test]
fn ties_are_ordered_by_dy_then_dx() {
    let map = CostMap {
        dx0: -3,
        dy0: -2,
        columns: 4,
        rows: 3,
        cost: vec![
            1.0,
            0.5,
            0.5,
            2.0,
            0.5,
            f64::INFINITY,
            0.5,
            0.7,
            0.5,
            0.5,
            3.0,
            0.5,
        ],
        overlap: vec![4.0; 12],
    };
    let all = map.best(0, 0.0);
    let at: Vec<(i32, i32)> = all.iter().map(|p| (p.dx, p.dy)).collect();
    assert_eq!(
        at,
        [(-2, -2), (-1, -2), (-3, -1), (-1, -1), (-3, 0), (-2, 0), (0, 0)]
    );
    assert_eq!(map.best(3, 0.0).len(), 3);
    assert_eq!(map.best(3, 0.0)[..], all[..3]);
    // tolerance 0.5 admits cost 0.7 but not 1.0; candidates cap it
    assert_eq!(map.best(0, 0.5).len(), 8);
    assert_eq!(map.best(0, 0.5)[7].cost, 0.7);
    assert_eq!(map.get(-1, -1), Some((0.5, 4.0)));
    assert_eq!(map.get(1, 0), None);
    assert_eq!(map.placements().count(), 11);
}

#[test]
fn config_errors() {
    let d = vec![0f32; 12];
    assert!(Image::new(2, 2, 3, &d[..11]).is_err());
    let known = vec![1f32; 3];
    let valid = vec![1f32; 4];
    let work = Work {
        image: img(2, 2, 3, &d),
        known: &known,
        constraint: None,
    };
    let sample = Sample {
        image: img(2, 2, 3, &d),
        valid: &valid,
        constraint: None,
        key: 0,
    };
    assert!(Matcher::new()
        .cost_map(&work, &sample, &MatchConfig::default())
        .is_err());
    let sample1 = Sample {
        image: img(4, 1, 3, &d),
        ..sample
    };
    let known = vec![1f32; 4];
    let work = Work {
        known: &known,
        ..work
    };
    assert!(Matcher::new()
        .cost_map(&work, &sample1, &MatchConfig::default())
        .is_ok());
}

fn p(dx: i32, cost: f64) -> Placement {
    Placement {
        dx,
        dy: 0,
        cost,
        overlap: 1.0,
    }
}

#[test]
fn choose_is_deterministic_and_near_minimal() {
    let cands = [
        p(0, 1.0),
        p(1, 1.05),
        p(2, 2.0),
        p(3, 1.08),
        p(4, 1.0),
        p(5, f64::INFINITY),
    ];
    let mut hits = [0usize; 6];
    for counter in 0..400 {
        let a = choose(&cands, 0.1, 42, counter).unwrap();
        assert_eq!(Some(a), choose(&cands, 0.1, 42, counter));
        assert!(a.cost <= 1.1, "{a:?}");
        hits[a.dx as usize] += 1;
    }
    assert_eq!((hits[2], hits[5]), (0, 0));
    for i in [0, 1, 3, 4] {
        assert!((60..=140).contains(&hits[i]), "{hits:?}");
    }
    // the seed matters
    let s1: Vec<i32> = (0..32).map(|c| choose(&cands, 0.1, 1, c).unwrap().dx).collect();
    let s2: Vec<i32> = (0..32).map(|c| choose(&cands, 0.1, 2, c).unwrap().dx).collect();
    assert_ne!(s1, s2);
    // zero tolerance: only the exact minima; nothing finite → None
    for c in 0..50 {
        assert!([0, 4].contains(&choose(&cands, 0.0, 9, c).unwrap().dx));
    }
    assert_eq!(choose(&[], 0.1, 1, 1), None);
    assert_eq!(choose(&[p(0, f64::INFINITY)], 0.1, 1, 1), None);
}

/// A work image matched under a key against several samples of one size
/// (rotated copies), its spectra kept between them: every cost and overlap
/// bit-identical to matching it afresh, with and without a constraint; a
/// new key, another constraint weight or another work image under the old
/// key's layout is transformed again.
#[test]
fn kept_work_spectra_give_the_same_costs_bit_for_bit() {
    let (sw, sh, ww, wh, n, nc) = (29, 21, 11, 8, 3, 1);
    let mut rng = Rng(17);
    let wdata = rng.vec(ww * wh * n);
    let wc = rng.vec(ww * wh * nc);
    let known = rng.mask(ww * wh, 0.6);
    let samples: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = (0..3)
        .map(|_| {
            (
                rng.vec(sw * sh * n),
                holey_valid(&mut rng, sw, sh),
                rng.vec(sw * sh * nc),
            )
        })
        .collect();
    let other = rng.vec(ww * wh * n);
    for constrained in [false, true] {
        let work = Work {
            image: img(ww, wh, n, &wdata),
            known: &known,
            constraint: constrained.then(|| img(ww, wh, nc, &wc)),
        };
        let mut kept = Matcher::new();
        // spectra too large for their cache: streamed, a pair at a time,
        // with the work spectra kept (the samples after the first) and not
        let mut streamed = [Matcher::with_cache_budget(1), Matcher::with_cache_budget(1)];
        for weight in [0.5, 2.0] {
            let cfg = MatchConfig {
                constraint_weight: weight,
                ..MatchConfig::default()
            };
            for (k, (data, valid, sc)) in samples.iter().enumerate() {
                let sample = Sample {
                    image: img(sw, sh, n, data),
                    valid,
                    constraint: constrained.then(|| img(sw, sh, nc, sc)),
                    key: k as u64 + 10 * constrained as u64,
                };
                let a = kept.cost_map_for(&work, Some(7), &sample, &cfg).unwrap();
                let b = Matcher::new().cost_map(&work, &sample, &cfg).unwrap();
                let bits = |m: &CostMap| -> Vec<(u64, u64)> {
                    m.cost
                        .iter()
                        .zip(&m.overlap)
                        .map(|(c, o)| (c.to_bits(), o.to_bits()))
                        .collect()
                };
                assert_eq!(
                    bits(&a),
                    bits(&b),
                    "sample {k}, constrained {constrained}, weight {weight}"
                );
                for (m, key) in streamed.iter_mut().zip([Some(7), None]) {
                    let c = m.cost_map_for(&work, key, &sample, &cfg).unwrap();
                    assert_eq!(
                        bits(&c),
                        bits(&b),
                        "streamed spectra, work key {key:?}, sample {k}, constrained {constrained}, weight {weight}"
                    );
                }
                assert!(a.cost.iter().any(|c| c.is_finite()));
            }
        }
        // another work image under a fresh key is not mistaken for the kept one
        let moved = Work {
            image: img(ww, wh, n, &other),
            ..work
        };
        let sample = Sample {
            image: img(sw, sh, n, &samples[0].0),
            valid: &samples[0].1,
            constraint: constrained.then(|| img(sw, sh, nc, &samples[0].2)),
            key: 10 * constrained as u64,
        };
        let cfg = MatchConfig::default();
        let a = kept.cost_map_for(&moved, Some(8), &sample, &cfg).unwrap();
        let b = Matcher::new().cost_map(&moved, &sample, &cfg).unwrap();
        assert_eq!(a.cost, b.cost);
    }
}

#[test]
fn a_sample_matched_from_its_f16_values_gives_the_f32_costs_bit_for_bit() {
    // a rotated copy is stored in f16; matched from those values (half the
    // bytes) it must cost every placement as its f32 copy does, with its
    // spectra cached or streamed a pair at a time, and with the work
    // image's spectra kept between matches or not
    let (sw, sh, ww, wh, n) = (29, 31, 13, 10, 5);
    let mut rng = Rng(11);
    let half: Vec<half::f16> = rng
        .vec(sw * sh * n)
        .into_iter()
        .map(half::f16::from_f32)
        .collect();
    let widened: Vec<f32> = half.iter().map(|x| x.to_f32()).collect();
    assert!(widened.iter().any(|&x| x != 0.0));
    let valid = holey_valid(&mut rng, sw, sh);
    let wdata = rng.vec(ww * wh * n);
    let known = rng.mask(ww * wh, 0.6);
    let work = Work {
        image: img(ww, wh, n, &wdata),
        known: &known,
        constraint: None,
    };
    let f32_sample = Sample {
        image: img(sw, sh, n, &widened),
        valid: &valid,
        constraint: None,
        key: 5,
    };
    let f16_sample = Sample {
        image: Image {
            width: sw,
            height: sh,
            channels: n,
            data: &[],
        },
        ..f32_sample
    };
    for span in [Span::Contained, Span::Overlapping] {
        let cfg = MatchConfig {
            span,
            ..MatchConfig::default()
        };
        let want = Matcher::new().cost_map(&work, &f32_sample, &cfg).unwrap();
        for budget in [usize::MAX >> 1, 1] {
            let mut m = Matcher::with_cache_budget(budget);
            for work_key in [None, Some(3), Some(3)] {
                let got = m
                    .cost_map_half(&work, work_key, &f16_sample, &half, &cfg)
                    .unwrap();
                assert_eq!(got, want, "{span:?}, cache {budget}, work key {work_key:?}");
            }
        }
    }
    // the values must be the image's size
    let short = &half[..half.len() - 1];
    assert!(Matcher::new()
        .cost_map_half(&work, None, &f16_sample, short, &MatchConfig::default())
        .is_err());
}
