use super::{visit_order, Synthesis};
use crate::artifact::gim::{Gim, TILE};
use crate::container::MemoryBudget;
use crate::progress::Silent;
use crate::quilt::ends::broken_around;
use crate::quilt::pager::TileGrid;
use crate::quilt::TileConfig;

/// A flat square atlased at 64² that shows a sample of horizontal
/// mortar lines (2 rows of every 8) as one patch, except where `other`
/// (x, y) holds, which shows it as another patch, moved down by
/// `offset` rows; and how many texels of column 31 there are.
fn halves(offset: f32, other: impl Fn(f32, f32) -> bool) -> (tempfile::TempDir, Synthesis, usize) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let obj = d.join("square.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n").unwrap();
    let gim_path = d.join("square.gim");
    let atlas = crate::atlas::AtlasConfig {
        resolution: 64,
        ..crate::atlas::AtlasConfig::default()
    };
    crate::atlas::build_gim(&obj, &gim_path, &atlas, &Silent).unwrap();
    let size = 96;
    let img = crate::io::imageio::RgbImage {
        width: size,
        height: size,
        data: (0..size * size)
            .flat_map(|i| [if (i / size) % 8 < 2 { 0.9f32 } else { 0.1 }; 3])
            .collect(),
    };
    let png = d.join("courses.png");
    crate::io::imageio::write_rgb(&png, &img).unwrap();
    let gim = Gim::open(&gim_path, MemoryBudget(1 << 20)).unwrap();
    let sized = super::super::sample::sample_as_is(&png, gim.texel_size);
    let cfg = TileConfig {
        refine_broken: 4,
        ..TileConfig::default()
    };
    let mut syn = Synthesis::open(&gim, &png, &sized, &d.join("out.quilt"), &cfg, true, None).unwrap();
    let r = syn.surface.r;
    let mut seam_rows = 0;
    for t in 0..(r * r) as u32 {
        if !syn.surface.covered(t) {
            continue;
        }
        let (x, y) = ((t as usize % r) as f32, (t as usize / r) as f32);
        let right = other(x, y);
        seam_rows += (x == 31.0) as usize;
        syn.state.texel_mut(t, |s, k| {
            s.synthesized[k] = true;
            s.coord[k] = [x + 8.0, y + 8.0 + if right { offset } else { 0.0 }];
            s.jacobian[k] = [1.0, 0.0, 0.0, 1.0];
            s.patch[k] = right as u32;
            s.source[k] = 0;
        });
    }
    syn.state.next_patch = 2;
    (dir, syn, seam_rows)
}

/// The seams [`Synthesis::seams_to_refine`] finds between [`halves`]
/// with and without looking for feature ends (step 1000: none by
/// colour step).
fn seams_between_halves(offset: f32) -> (Vec<u32>, usize, usize) {
    let (_dir, syn, seam_rows) = halves(offset, |x, _| x >= 32.0);
    let r = syn.surface.r;
    let (by_step, _) = syn.seams_to_refine(1000.0, false);
    let (seeds, broken) = syn.seams_to_refine(1000.0, true);
    assert!(by_step.is_empty(), "no colour step is that large");
    assert_eq!(seeds.iter().map(|s| s.1).collect::<Vec<_>>(), broken);
    (broken, seam_rows, r)
}

#[test]
fn refinement_finds_the_mortar_lines_that_end_at_a_seam() {
    // half a period down: every mortar line of the left half meets
    // brick on the right and the other way round, on the seam's column
    let (broken, seam_rows, r) = seams_between_halves(4.0);
    assert!(broken.iter().all(|&t| t as usize % r == 31), "on the seam only");
    // the sample runs in rows, so every row of the seam has its course
    // offset, mortar or brick alike (by colour alone, two mortar rows of
    // every 8 on each side)
    assert_eq!(broken.len(), seam_rows);
    // a quarter period down: offset too
    let (broken, seam_rows, _) = seams_between_halves(2.0);
    assert_eq!(broken.len(), seam_rows);
    // a whole period down, or none: the lines run on, nothing is broken
    for offset in [0.0, 8.0] {
        let (broken, _, _) = seams_between_halves(offset);
        assert!(broken.is_empty(), "offset {offset}: {broken:?}");
    }
}

/// Refinement where features end predicts, for the cut it chooses, the
/// features ending at the patch's seams once it is accepted: the count
/// over the changed surface is the one predicted, and it is lower than
/// before around an island of courses offset by half a period that the
/// patch can cover.
#[test]
fn refinement_counts_the_features_its_cut_would_end() {
    let island = |x: f32, y: f32| (x - 31.0).powi(2) + (y - 30.0).powi(2) < 25.0;
    let (_dir, mut syn, _) = halves(4.0, island);
    let r = syn.surface.r;
    let limit = crate::quilt::BROKEN_CONTINUATION * syn.reference;
    // on the island's edge, a patch that can cover the island
    let v = (30 * r + 36) as u32;
    let outcome = syn.worker().refinement(v, 12, (4, true), 3).unwrap();
    let (before, after) = outcome.fit.ends.expect("counted");
    let count = |syn: &Synthesis, patch| {
        broken_around(
            &syn.sample,
            &syn.state,
            &syn.surface,
            &syn.bfs,
            patch,
            None,
            limit,
        )
    };
    assert_eq!(count(&syn, &outcome.patch), before, "the surface as it is");
    assert!(before > 0 && after < before, "{before} → {after}");
    syn.accept(&outcome.patch, &outcome.fit, &Silent);
    assert_eq!(
        count(&syn, &outcome.patch),
        after,
        "the surface once the patch is accepted"
    );
}

#[test]
fn seams_are_visited_once_each_by_runs_that_walk_the_tiles() {
    let grid = TileGrid::new(4 * TILE);
    // as many seeds in every tile, steps in a scrambled order
    let seeds: Vec<(f64, u32)> = (0..grid.r * grid.r)
        .filter(|&t| grid.locate(t as u32).1 % 7 == 0)
        .map(|t| (((t * 7919) % 1000) as f64, t as u32))
        .collect();
    let order = visit_order(&grid, seeds.clone(), 4);
    let mut sorted = order.clone();
    sorted.sort_unstable();
    let mut expect: Vec<u32> = seeds.iter().map(|s| s.1).collect();
    expect.sort_unstable();
    assert_eq!(sorted, expect, "every seed once");
    let tile = |t: u32| grid.locate(t).0;
    // the four runs take turns: neighbours in the order are a quarter
    // of the atlas apart, each run is one quarter in Z order
    let quarter = |t: u32| {
        let (x, y) = grid.xy(t);
        (y / (2 * TILE)) * 2 + x / (2 * TILE)
    };
    for (i, w) in order.chunks(4).enumerate() {
        let q: Vec<usize> = w.iter().map(|&t| quarter(t)).collect();
        assert_eq!(q, vec![0, 1, 2, 3], "turn {i}");
    }
    // within a run, tiles change rarely and steps fall within a tile
    let run: Vec<u32> = order.iter().step_by(4).copied().collect();
    let changes = run.windows(2).filter(|w| tile(w[0]) != tile(w[1])).count();
    assert_eq!(changes, 3, "a run visits its four tiles one after another");
    let step = |t: u32| seeds.iter().find(|s| s.1 == t).expect("a seed").0;
    assert!(run
        .windows(2)
        .all(|w| tile(w[0]) != tile(w[1]) || step(w[0]) >= step(w[1])));
}
