//! Factorization throughput (issue: out-of-core factorization).
//!
//! `factorize_passes`: the 7 streaming passes of a 40-term randomized SVD
//! (q = 2) of a 48² BTF on the 12×8×12×8 grid, throughput counted as raw f16
//! bytes × passes, so it reads as "bytes of BTF per second per pass";
//! `container_plain_read`: decoding every chunk once, for comparison;
//! `rotations72`: the 72 rotated copies of 40 geometry maps.

use btfquilt::artifact::btf::Btf;
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::generate::{self, Family, GenerateConfig};
use btfquilt::progress::Silent;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use half::f16;

const SIZE: usize = 48;

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("src.btf");
    let gen = GenerateConfig {
        family: Family::Bricks,
        width: SIZE,
        height: SIZE,
        ..GenerateConfig::default()
    };
    generate::generate_btf(&gen, &src, &Silent).unwrap();
    let raw = Btf::open(&src, MemoryBudget::default())
        .unwrap()
        .layout()
        .raw_bytes();
    let out = dir.path().join("out.svd");
    // no cache: every pass decodes every chunk, as for BTFs larger than memory
    let cfg = FactorizeConfig {
        rotations: 0,
        memory: MemoryBudget(1 << 20),
        ..FactorizeConfig::default()
    };
    let passes = 3 + 2 * cfg.power_iterations as u64;

    let mut g = c.benchmark_group("factorize");
    g.sample_size(10).throughput(Throughput::Bytes(raw * passes));
    g.bench_function(format!("factorize_passes_{SIZE}x{SIZE}_12x8x12x8_40terms"), |b| {
        b.iter(|| factorize::factorize(&src, &out, &cfg, &Silent).unwrap())
    });
    g.throughput(Throughput::Bytes(raw));
    g.bench_function("container_plain_read", |b| {
        b.iter(|| {
            let btf = Btf::open(&src, MemoryBudget(1 << 20)).unwrap();
            let c = btf.container();
            let rgb = c.array("rgb").unwrap();
            let n = c.spec(rgb).chunk_count();
            use rayon::prelude::*;
            (0..n)
                .into_par_iter()
                .map(|k| c.read_chunk::<f16>(rgb, k).unwrap()[0].to_f32())
                .sum::<f32>()
        })
    });
    g.finish();

    let mut g = c.benchmark_group("rotations");
    g.sample_size(10);
    let maps: Vec<f32> = (0..128 * 128 * 40).map(|i| (i as f32 * 0.01).sin()).collect();
    g.bench_function("rotate_128x128x40_one_copy", |b| {
        b.iter(|| factorize::rotate_maps(&maps, 128, 128, 40, 35.0, false))
    });
    g.finish();
}

criterion_group!(factorization, benches);
criterion_main!(factorization);
