//! Graphcut quilting in 2D: a flat square atlased at 400² tiled from a 192²
//! centre crop of the shipped brick photo (`data/brick.png`).
//!
//! `tile/square400_from_brick192`: one whole `quilt::tile` run from the
//! sample's `.svd` (factorized once in setup: 3 terms, 72 rotated copies),
//! writing the `.quilt`. The geometry image and the `.svd` are built in
//! setup through the library, as `tests/suite/quilt.rs` does. Ten flat samples
//! of one run each: about 15 s.
//!
//! `paged/square400_{resident,evicting}`: the same run with `--memory 16GiB`
//! (every atlas tile stays resident) and with `--memory 2MiB` (a few of the
//! 49 atlas tiles resident: the loop evicts tiles to its scratch store and
//! reads them back), the cost of paging the atlas; both write the same bytes.

use std::time::Duration;

use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use criterion::{criterion_group, criterion_main, Criterion, SamplingMode};

#[path = "../tests/common/mod.rs"]
mod common;

fn bench_tile(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let gim_path = dir.path().join("square400.gim");
    atlas::build_gim(
        &common::square_obj(dir.path()),
        &gim_path,
        &AtlasConfig {
            resolution: 400,
            ..AtlasConfig::default()
        },
        &Silent,
    )
    .unwrap();
    let svd = dir.path().join("brick192.svd");
    factorize::factorize(
        &common::brick_crop(dir.path(), 192, None),
        &svd,
        &FactorizeConfig::default(),
        &Silent,
    )
    .unwrap();
    let out = dir.path().join("square.quilt");
    let cfg = TileConfig::default();

    let mut group = c.benchmark_group("tile");
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(15));
    group.bench_function("square400_from_brick192", |b| {
        b.iter(|| quilt::tile(&gim_path, &svd, &out, &cfg, &Silent).unwrap())
    });
    group.finish();

    let mut group = c.benchmark_group("paged");
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(15));
    for (name, memory) in [("resident", 16u64 << 30), ("evicting", 2 << 20)] {
        let cfg = TileConfig {
            memory: MemoryBudget(memory),
            ..TileConfig::default()
        };
        group.bench_function(format!("square400_{name}"), |b| {
            b.iter(|| quilt::tile(&gim_path, &svd, &out, &cfg, &Silent).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench_tile);
criterion_main!(benches);
