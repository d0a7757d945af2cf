use std::path::Path;

use crate::atlas::AtlasConfig;
use crate::progress::Silent;
use crate::quilt::synthesis::REFINE_ROUND;
use crate::quilt::{tile_refining_by, TileConfig, TileReport};

/// The surface of [`spot_256`] (16 MiB for its tiles).
fn spot_256_surface(dir: &Path) -> crate::quilt::state::Surface {
    use crate::artifact::gim::Gim;
    use crate::container::MemoryBudget;
    let gim = Gim::open(&spot_256(dir), MemoryBudget(1 << 24)).unwrap();
    crate::quilt::state::Surface::open(&gim, MemoryBudget(1 << 24), None).unwrap()
}

/// Spot atlased at 256² as `dir/spot.gim`.
fn spot_256(dir: &Path) -> std::path::PathBuf {
    let gim = dir.join("spot.gim");
    let atlas = AtlasConfig {
        resolution: 256,
        ..AtlasConfig::default()
    };
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    crate::atlas::build_gim(&mesh, &gim, &atlas, &Silent).unwrap();
    gim
}

/// A patch cut from a deeper traversal at the same seed equals the
/// traversal stopped at its radius, index included, inside charts and
/// across zippers.
#[test]
fn a_prefix_of_a_deeper_traversal_is_the_work_patch() {
    use crate::quilt::state::Bfs;
    let dir = tempfile::tempdir().unwrap();
    let surface = spot_256_surface(dir.path());
    let (mut deep, mut direct) = (Bfs::default(), Bfs::default());
    let (mut seeds, mut crossing) = (0, 0);
    for v in (0..256 * 256u32).step_by(997).filter(|&v| surface.covered(v)) {
        let ball = deep.patch(&surface, v, 14);
        seeds += 1;
        crossing += ball.crosses_charts as usize;
        for r in [0, 1, 5, 11, 12, 14] {
            let want = direct.patch(&surface, v, r);
            let got = deep.prefix(&surface, &ball, r);
            assert_eq!(
                (&got.texels, &got.depth),
                (&want.texels, &want.depth),
                "seed {v} radius {r}"
            );
            assert_eq!(
                (got.crosses_charts, got.first_zipper),
                (want.crosses_charts, want.first_zipper),
                "seed {v} radius {r}"
            );
            for (i, &t) in ball.texels.iter().enumerate() {
                let expect = (i < want.texels.len()).then_some(i);
                assert_eq!(deep.contains(t), expect, "seed {v} radius {r} texel {t}");
                assert_eq!(direct.contains(t), expect, "seed {v} radius {r} texel {t}");
            }
        }
    }
    assert!(
        seeds > 20 && crossing > 3,
        "{seeds} seeds, {crossing} crossing charts"
    );
}

/// A traversal given up at the first texel of a used tile rejects
/// exactly the seeds whose whole reach would meet a used tile, and
/// otherwise is that reach (tiles and traversal); the traversal after
/// a rejected one is whole again.
#[test]
fn a_reach_given_up_at_a_used_tile_rejects_what_the_whole_reach_would() {
    use super::{reach, reach_unless_used};
    use crate::quilt::state::Bfs;
    let dir = tempfile::tempdir().unwrap();
    let surface = spot_256_surface(dir.path());
    let tiles = surface.grid().tiles();
    let across = surface.grid().across;
    // a stripe, a checkerboard, and each tile alone (whose reach may
    // take it for a box's margin without a texel in it)
    let mut masks: Vec<Vec<bool>> = vec![
        (0..tiles).map(|k| k % across == 1).collect(),
        (0..tiles).map(|k| (k % across + k / across) % 2 == 0).collect(),
    ];
    masks.extend((0..tiles).map(|one| (0..tiles).map(|k| k == one).collect()));
    let (mut whole, mut given_up) = (Bfs::default(), Bfs::default());
    let (mut kept, mut rejected) = (0, 0);
    for used in &masks {
        for v in (0..256 * 256u32).step_by(997).filter(|&v| surface.covered(v)) {
            for radius in [3, 9] {
                let (want_tiles, want_ball) = reach(&mut whole, &surface, v, radius);
                let meets = want_tiles.iter().any(|&k| used[k]);
                match reach_unless_used(&mut given_up, &surface, v, radius, used) {
                    Some((got_tiles, got_ball)) => {
                        assert!(
                            !meets,
                            "seed {v} radius {radius}: kept though its reach meets a used tile"
                        );
                        assert_eq!(got_tiles, want_tiles, "seed {v} radius {radius}");
                        assert_eq!(
                            (&got_ball.texels, &got_ball.depth, got_ball.first_zipper),
                            (&want_ball.texels, &want_ball.depth, want_ball.first_zipper),
                            "seed {v} radius {radius}"
                        );
                        kept += 1;
                    }
                    None => {
                        assert!(
                            meets,
                            "seed {v} radius {radius}: rejected though its reach is free"
                        );
                        rejected += 1;
                    }
                }
            }
        }
    }
    assert!(kept > 10 && rejected > 10, "{kept} kept, {rejected} rejected");
}

/// The verbatim preview's work coordinates without the work image are
/// those of the work image, inside charts and across them.
#[test]
fn work_coordinates_alone_equal_the_work_image_s() {
    use crate::artifact::gim::Gim;
    use crate::container::MemoryBudget;
    use crate::quilt::flatten::work_coords;
    use crate::quilt::sample::sample_as_is;
    use crate::quilt::synthesis::Synthesis;
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let gim = Gim::open(&spot_256(dir.path()), MemoryBudget(1 << 24)).unwrap();
    let sample = root.join("data/brick_wall.png");
    let cfg = TileConfig::default();
    let sized = sample_as_is(&sample, gim.texel_size);
    let out = dir.path().join("never.quilt");
    let mut syn = Synthesis::open(&gim, &sample, &sized, &out, &cfg, true, None).unwrap();
    let (mut inside, mut across) = (0, 0);
    let seeds: Vec<u32> = (0..256 * 256u32)
        .step_by(307)
        .filter(|&v| syn.surface.covered(v))
        .collect();
    for v in seeds {
        let patch = syn.bfs.patch(&syn.surface, v, 12);
        let (work, _) = syn.worker().work_image(&patch, &mut None);
        let (coords, angle) = work_coords(
            &syn.surface,
            &patch,
            &syn.bfs,
            &syn.zipper_triangles,
            cfg.max_distortion,
        );
        assert_eq!((coords, angle), (work.coords, work.angle), "seed {v}");
        inside += !patch.crosses_charts as usize;
        across += patch.crosses_charts as usize;
    }
    assert!(
        inside > 5 && across > 5,
        "{inside} inside charts, {across} across"
    );
}

/// The quilting loop streamed from outside the pool gives the quilt of
/// its rounds computed inside a pool of one thread, whatever the
/// memory: at 1 MiB one work patch is in flight at a time and the
/// atlas tiles are evicted and read again.
#[test]
fn streamed_rounds_give_the_quilt_of_rounds_inside_the_pool() {
    use crate::container::MemoryBudget;
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let gim = spot_256(dir.path());
    let sample = root.join("data/brick_wall.png");
    let run = |name: &str, memory: u64, pool: Option<usize>| -> (Vec<u8>, TileReport) {
        let out = dir.path().join(format!("{name}.quilt"));
        let cfg = TileConfig {
            seed: 7,
            memory: MemoryBudget(memory),
            ..TileConfig::default()
        };
        let report = match pool {
            None => {
                assert!(rayon::current_thread_index().is_none());
                crate::quilt::tile(&gim, &sample, &out, &cfg, &Silent).unwrap()
            }
            Some(threads) => rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| crate::quilt::tile(&gim, &sample, &out, &cfg, &Silent))
                .unwrap(),
        };
        (std::fs::read(&out).unwrap(), report)
    };
    let (inside, alone) = run("inside", 1 << 30, Some(1));
    let (streamed, report) = run("streamed", 1 << 30, None);
    let (small, tight) = run("small", 1 << 20, None);
    assert!(
        report.concurrent_patches > 0,
        "no round held several patches: {report}"
    );
    assert!(report.refined > 2 && report.refined == alone.refined, "{report}");
    assert!(
        tight.tiles_read > alone.tiles_read,
        "1 MiB evicted nothing: {tight}"
    );
    assert!(inside == streamed, "streamed rounds changed the quilt");
    assert!(inside == small, "streamed rounds at 1 MiB changed the quilt");
}

/// Seam refinement a round at a time visits the same seeds and keeps
/// the same patches as one at a time (the loop itself one at a time
/// here, so only refinement runs in rounds), also with more placements
/// where features end (`refine_broken`) and more passes there.
#[test]
fn refinement_in_rounds_gives_the_quilt_of_one_patch_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let gim = spot_256(dir.path());
    let sample = root.join("data/brick_wall.png");
    let mut quilts = Vec::new();
    for (refine_broken, refine_passes) in [(0, 1), (4, 3)] {
        let cfg = TileConfig {
            round: 1,
            seed: 3,
            refine_broken,
            refine_passes,
            ..TileConfig::default()
        };
        let run = |refine_round: usize, threads: usize| -> (Vec<u8>, TileReport) {
            let out = dir
                .path()
                .join(format!("r{refine_round}-t{threads}-b{refine_broken}.quilt"));
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let report = pool
                .install(|| tile_refining_by(&gim, &sample, &out, &cfg, refine_round, &Silent))
                .unwrap();
            (std::fs::read(&out).unwrap(), report)
        };
        let (one, alone) = run(1, 1);
        let (many, rounds) = run(REFINE_ROUND, 2);
        assert!(alone.refined > 2, "{alone}");
        assert_eq!(alone.concurrent_patches, 0, "{alone}");
        assert!(
            rounds.concurrent_patches > 0,
            "no refinement round held several patches: {rounds}"
        );
        assert_eq!((alone.refined, alone.patches), (rounds.refined, rounds.patches));
        assert!(one == many, "refinement in rounds changed the quilt");
        quilts.push(one);
    }
    assert!(
        quilts[0] != quilts[1],
        "refining where features end changed nothing"
    );
}

/// The loop's budget is `--memory` less the program and the sample's maps;
/// once matching has sized the work patches, their share shrinks to what
/// the patches running at once need and the two caches take the rest,
/// the loop's stores within its budget and each cache within its own.
#[test]
fn the_loop_settles_its_memory_within_the_budget() {
    use crate::artifact::gim::Gim;
    use crate::container::MemoryBudget;
    use crate::quilt::sample::sample_as_is;
    use crate::quilt::synthesis::{Synthesis, LOOP_SHARES, PROGRAM_BYTES};
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let gim = Gim::open(&spot_256(dir.path()), MemoryBudget(1 << 24)).unwrap();
    let sample = root.join("data/brick_wall.png");
    let memory = 128u64 << 20;
    let cfg = TileConfig {
        memory: MemoryBudget(memory),
        ..TileConfig::default()
    };
    let sized = sample_as_is(&sample, gim.texel_size);
    let out = dir.path().join("settled.quilt");
    let mut syn = Synthesis::open(&gim, &sample, &sized, &out, &cfg, true, None).unwrap();
    let maps = 4 * syn.sample.maps.len() as u64;
    assert_eq!(syn.loop_budget.bytes(), memory - PROGRAM_BYTES - maps);
    let [rotated, spectra, atlas, patches] = syn.loop_budget.split(LOOP_SHARES);
    assert_eq!(
        syn.patch_budget,
        patches.bytes(),
        "the whole share before matching"
    );
    let first = syn.surface.nth_vertex(0);
    let radius0 = syn.radius0();
    syn.synthesize(first, radius0, &Silent).unwrap();
    let one = syn.patch_bytes()(syn.bfs.patch(&syn.surface, first, radius0 + 2).texels.len());
    assert!(
        syn.patch_budget < patches.bytes() && syn.patch_budget >= one,
        "settled {} of {} (one patch {one})",
        syn.patch_budget,
        patches.bytes()
    );
    let (rotated_budget, rotated_held) = syn.sample.rotated_cache();
    let spectra_budget = syn.matcher.cache_budget() as u64;
    assert!(rotated_budget > rotated.bytes() && spectra_budget > spectra.bytes());
    assert!(rotated_budget + spectra_budget + atlas.bytes() + syn.patch_budget <= syn.loop_budget.bytes());
    assert!(rotated_held <= rotated_budget && syn.matcher.cache_bytes() as u64 <= spectra_budget);
    // a small --memory keeps at least half of it for the loop
    let small = TileConfig {
        memory: MemoryBudget(8 << 20),
        ..TileConfig::default()
    };
    let syn = Synthesis::open(&gim, &sample, &sized, &out, &small, true, None).unwrap();
    assert_eq!(syn.loop_budget.bytes(), 4 << 20);
}
