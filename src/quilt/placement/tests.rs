use super::*;
use crate::artifact::svd::SvdArtifact;
use crate::container::MemoryBudget;
use crate::io::imageio::{self, RgbImage};
use crate::quilt::sample::RotatedCopy;

/// A 64² sample of running-bond bricks (courses 8 px high, bricks 16
/// long, mortar 2 px), factorized with its 72 rotated copies.
fn bricks(dir: &std::path::Path) -> (Sample, Option<tempfile::TempDir>) {
    let mut img = RgbImage::new(64, 64);
    for y in 0..64 {
        for x in 0..64 {
            let course = y / 8;
            let mortar = y % 8 < 2 || (x + 8 * (course % 2)) % 16 < 2;
            let v = if mortar {
                0.8
            } else {
                0.2 + 0.01 * (course % 3) as f32
            };
            img.data[(y * 64 + x) * 3..(y * 64 + x) * 3 + 3].copy_from_slice(&[v, v * 0.9, v * 0.8]);
        }
    }
    let png = dir.join("bricks.png");
    imageio::write_rgb(&png, &img).unwrap();
    let (svd, guard) =
        super::super::sample::sample_svd(&png, true, MemoryBudget::default(), &crate::progress::Silent)
            .unwrap();
    let svd = SvdArtifact::open(&svd, MemoryBudget::default()).unwrap();
    (Sample::from_svd(svd, MemoryBudget::default()).unwrap(), guard)
}

/// A copy too large for its cache is read by rectangles: the same
/// rectangles, coarse copies and coarse-to-fine placements as cut from
/// the whole copy, and no whole copy kept.
#[test]
fn rectangles_of_the_stored_copies_equal_the_whole_copy() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, _svd) = bricks(dir.path());
    let svd = SvdArtifact::open(whole.svd.container().path(), MemoryBudget::default()).unwrap();
    let mut by_rect = Sample::from_svd(svd, MemoryBudget(0)).unwrap();
    by_rect.read_by_rectangles();
    by_rect.spill_beside(&dir.path().join("out.quilt"));
    let spilled = || {
        std::fs::read_dir(dir.path()).unwrap().flatten().any(|e| {
            let f = e.file_name().to_string_lossy().into_owned();
            f.starts_with(".out.quilt.coarse.") && f.ends_with(".scratch")
        })
    };
    for (r, rect) in [(0, (0, 0, 64, 64)), (5, (3, 7, 20, 33)), (41, (60, 0, 4, 64))] {
        let copy = whole.rotation(r).unwrap();
        let got = by_rect.rotation_rect(r, rect).unwrap();
        assert_eq!(got, whole.rotation_rect(r, rect).unwrap());
        let (x0, y0, w, h) = rect;
        for y in 0..h {
            let at = (y0 + y) * 64 + x0;
            assert_eq!(&got.1[y * w..(y + 1) * w], &copy.1[at..at + w]);
            assert_eq!(
                &got.0[y * w * whole.n..(y + 1) * w * whole.n],
                &copy.0[at * whole.n..(at + w) * whole.n]
            );
        }
        // made from bands, then read back from the scratch store
        for _ in 0..2 {
            assert_eq!(
                by_rect.coarse_rotation(r, 3).unwrap(),
                whole.coarse_rotation(r, 3).unwrap()
            );
        }
    }
    assert!(spilled(), "the coarse copies are kept beside the output");
    let mut matcher = Matcher::new();
    for k in [0usize, 3, 70] {
        let work = work_showing(&whole, k);
        let known: f64 = work.known.iter().map(|&m| m as f64).sum();
        let a = match_at_rotation(&whole, &mut matcher, &work, 0.0, None, k, known, 3).unwrap();
        let b = match_at_rotation(&by_rect, &mut matcher, &work, 0.0, None, k, known, 3).unwrap();
        assert_eq!(a, b);
        assert!(!a.is_empty() && a[0].cost < 1e-9, "{:?}", a.first());
    }
    assert_eq!(by_rect.rotated_cache().1, 0, "nothing held by the reading sample");
    drop(by_rect);
    assert!(!spilled(), "the scratch store goes with the sample");
}

/// A 24² work image whose left half is known and shows rotated copy
/// `k` of the sample (from its centre), with the field along x.
fn work_showing(sample: &Sample, k: usize) -> WorkImage {
    let (w, h, n) = (24, 24, sample.n);
    let copy = sample.rotation(k).unwrap();
    let (ox, oy) = (20, 20);
    let mut features = vec![0f32; w * h * n];
    let mut known = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w / 2 {
            let s = (oy + y) * sample.width + ox + x;
            assert!(copy.1[s] > 0.0, "the work image lies inside the copy");
            known[y * w + x] = 1.0;
            features[(y * w + x) * n..(y * w + x + 1) * n].copy_from_slice(&copy.0[s * n..(s + 1) * n]);
        }
    }
    WorkImage {
        width: w,
        height: h,
        features,
        known,
        coords: Vec::new(),
        angle: 0.0,
        field_spread: 0.1,
        neighbour_angle: None,
        atlas_to_work: None,
        constraint: Vec::new(),
        course_phase: Vec::new(),
    }
}

/// The climb finds the copy the known texels show, from the field's
/// copy or from the neighbours' direction, and never turns further
/// than the limit; a constant field keeps the field's copy.
#[test]
fn the_rotation_climb_follows_what_is_already_there() {
    let dir = tempfile::tempdir().unwrap();
    let (sample, _svd) = bricks(dir.path());
    let step = std::f64::consts::TAU / sample.rotations as f64;
    let mut matcher = Matcher::new();
    for k in [0usize, 2, 3, 70] {
        let mut work = work_showing(&sample, k);
        let got = choose_rotation(&sample, &mut matcher, &work, None, 0, 4, 1).unwrap();
        assert_eq!(got, k, "climbing from the field's copy");
        work.neighbour_angle = Some(k as f64 * step);
        let got = choose_rotation(&sample, &mut matcher, &work, None, 0, 4, 1).unwrap();
        assert_eq!(got, k, "starting from the neighbours' direction");
    }
    // six steps off, beyond the limit: from the neighbours' direction
    // the climb starts at the limit and stays there
    let mut work = work_showing(&sample, 6);
    work.neighbour_angle = Some(6.0 * step);
    assert_eq!(
        choose_rotation(&sample, &mut matcher, &work, None, 0, 4, 1).unwrap(),
        4
    );
    let mut flat = work_showing(&sample, 3);
    flat.field_spread = 0.0;
    assert_eq!(turn_limit(&flat, 4), 0);
    assert_eq!(turn_limit(&work, 4), 4);
}

/// Σ M V ‖I − S‖² / Σ M V over the leading `k` channels of placement
/// (dx, dy) of whole copy `copy` (`n` channels, `sw` wide) over `work`:
/// the matching cost summed texel by texel.
fn brute_cost(work: &WorkImage, copy: &RotatedCopy, n: usize, k: usize, sw: usize, d: (i32, i32)) -> f64 {
    let sh = copy.1.len() / sw;
    let (mut ssd, mut overlap) = (0f64, 0f64);
    for y in 0..work.height {
        for x in 0..work.width {
            let (sx, sy) = (x as i32 - d.0, y as i32 - d.1);
            if sx < 0 || sy < 0 || sx as usize >= sw || sy as usize >= sh {
                continue;
            }
            let (p, s) = (y * work.width + x, sy as usize * sw + sx as usize);
            let mv = work.known[p] as f64 * copy.1[s] as f64;
            overlap += mv;
            for c in 0..k {
                let e = work.features[p * n + c] as f64 - copy.0[s * n + c] as f64;
                ssd += mv * e * e;
            }
        }
    }
    ssd / overlap
}

/// With fewer match terms, the copies matching reads hold the leading
/// terms of the stored ones (whole, by rectangles, coarse, and the f16
/// copy of a full match), and every path's costs are those of the
/// leading terms alone, summed texel by texel; every term is the default.
#[test]
fn matching_reads_only_the_leading_terms() {
    let dir = tempfile::tempdir().unwrap();
    let (full, _svd) = bricks(dir.path());
    let n = full.n;
    assert!(n >= 3, "a colour sample has three terms");
    let open = |budget| SvdArtifact::open(full.svd.container().path(), MemoryBudget(budget)).unwrap();
    let mut lead = Sample::from_svd(open(1 << 30), MemoryBudget::default()).unwrap();
    lead.set_match_terms(2);
    assert_eq!(lead.match_channels(), 2);
    let mut lead_f16 = Sample::from_svd(open(1 << 30), MemoryBudget(0)).unwrap();
    lead_f16.set_match_terms(2);
    let mut every = Sample::from_svd(open(1 << 30), MemoryBudget::default()).unwrap();
    every.set_match_terms(0);
    assert_eq!(every.match_channels(), n);
    let leading = |v: &[f32]| -> Vec<f32> { v.chunks_exact(n).flat_map(|p| p[..2].to_vec()).collect() };
    let mut matcher = Matcher::new();
    let mut differs = false;
    for r in [0usize, 5, 41] {
        let copy = full.rotation(r).unwrap();
        assert_eq!(every.rotation(r).unwrap(), copy);
        let got = lead.rotation(r).unwrap();
        assert_eq!((&got.0, &got.1), (&leading(&copy.0), &copy.1));
        let rect = (3, 7, 20, 33);
        let (m, v) = full.rotation_rect(r, rect).unwrap();
        assert_eq!(lead_f16.rotation_rect(r, rect).unwrap(), (leading(&m), v));
        assert_eq!(
            lead_f16.coarse_rotation(r, 3).unwrap(),
            lead.coarse_rotation(r, 3).unwrap()
        );
        match lead_f16.rotation_to_match(r).unwrap() {
            WholeCopy::F16(values, valid) => {
                let widened: Vec<f32> = values.iter().map(|v| v.to_f32()).collect();
                assert_eq!((&widened, &valid), (&got.0, &got.1));
            }
            WholeCopy::F32(_) => panic!("no room for an f32 copy: the f16 one"),
        }
        let work = work_showing(&full, r);
        let known: f64 = work.known.iter().map(|&m| m as f64).sum();
        for (sample, f) in [(&lead, 1), (&lead_f16, 1), (&lead, 3), (&lead_f16, 3)] {
            let placements = match_at_rotation(sample, &mut matcher, &work, 0.0, None, r, known, f).unwrap();
            assert!(!placements.is_empty());
            for p in &placements {
                let want = brute_cost(&work, &copy, n, 2, full.width, (p.dx, p.dy));
                assert!(
                    (p.cost - want).abs() <= 1e-6 * want.abs().max(1e-3),
                    "{p:?} against {want}"
                );
                let all = brute_cost(&work, &copy, n, n, full.width, (p.dx, p.dy));
                differs |= (all - want).abs() > 1e-4 * all.abs();
            }
        }
    }
    assert!(differs, "the last term changes some cost");
    // with the structure channel: the leading terms, then the channel
    let mut with_structure = Sample::from_svd(open(1 << 30), MemoryBudget::default()).unwrap();
    with_structure.add_structure(0.5);
    lead.set_match_terms(2);
    lead.add_structure(0.5);
    assert_eq!(lead.match_channels(), 3);
    let (m1, k) = (n + 1, [0usize, 1, n]);
    let pick = |v: &[f32]| -> Vec<f32> { v.chunks_exact(m1).flat_map(|p| k.map(|c| p[c])).collect() };
    let copy = with_structure.rotation(7).unwrap();
    assert_eq!(lead.rotation(7).unwrap().0, pick(&copy.0));
    let features: Vec<f32> = (0..4 * m1).map(|i| i as f32).collect();
    assert_eq!(lead.match_features(&features).as_ref(), &pick(&features)[..]);
}
