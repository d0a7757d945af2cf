//! Container and generator throughput on generated BTFs (issue: foundation).
//!
//! `cargo bench --bench container` prints, per group, the time of one pass
//! and criterion's throughput in bytes of raw f16 per second; the compression
//! ratio of each zstd level is printed once before the write benchmarks.

use std::path::Path;

use btfquilt::artifact::btf::{Btf, BtfWriter};
use btfquilt::container::{codec, MemoryBudget};
use btfquilt::generate::{self, Family, GenerateConfig};
use btfquilt::progress::Silent;
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use half::f16;

const SIZE: usize = 32;

fn config(family: Family) -> GenerateConfig {
    GenerateConfig {
        family,
        width: SIZE,
        height: SIZE,
        ..GenerateConfig::default()
    }
}

/// All `rgb` chunks of a BTF, decoded, in (tile, band) order.
fn load_chunks(path: &Path) -> (Btf, Vec<(usize, usize, usize, Vec<f16>)>) {
    let btf = Btf::open(path, MemoryBudget::default()).unwrap();
    let l = btf.layout().clone();
    let c = btf.container();
    let rgb = c.array("rgb").unwrap();
    let (ntx, nty) = l.tiles();
    let mut chunks = Vec::new();
    for ty in 0..nty {
        for tx in 0..ntx {
            for band in 0..l.bands() {
                let data = c.read_chunk::<f16>(rgb, l.chunk(tx, ty, band)).unwrap();
                chunks.push((tx, ty, band, data.to_vec()));
            }
        }
    }
    (btf, chunks)
}

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("src.btf");
    let cfg = config(Family::Bricks);
    generate::generate_btf(&cfg, &src, &Silent).unwrap();
    let (btf, chunks) = load_chunks(&src);
    let layout = btf.layout().clone();
    let raw = layout.raw_bytes();

    let mut g = c.benchmark_group("generate");
    g.sample_size(10).throughput(Throughput::Bytes(raw));
    for family in Family::ALL {
        let out = dir.path().join(format!("gen-{}.btf", family.name()));
        g.bench_function(format!("{}_{SIZE}x{SIZE}_12x8x12x8", family.name()), |b| {
            b.iter(|| generate::generate_btf(&config(family), &out, &Silent).unwrap())
        });
    }
    g.finish();

    // the renderer alone: one 64×64 block, one view, the 96 grid lights
    let meso = generate::Mesostructure::generate(&generate::MaterialParams {
        family: Family::Bricks,
        imperfection: generate::Imperfection::Cracks,
        width: 128,
        height: 128,
        seed: 1,
    });
    let lights: Vec<[f32; 3]> = btfquilt::artifact::btf::default_grid()
        .iter()
        .map(|a| generate::direction(a.theta, a.phi))
        .collect();
    let renderer = generate::BlockRenderer::new(&meso, 32, 32, 64, 64, &lights);
    let mut out = vec![0f32; 64 * 64 * lights.len() * 3];
    let mut g = c.benchmark_group("render");
    g.sample_size(20)
        .throughput(Throughput::Elements((64 * 64 * lights.len()) as u64));
    g.bench_function("block64_one_view_96_lights", |b| {
        b.iter(|| renderer.render_view(generate::direction(45.0, 30.0), &mut out))
    });
    g.finish();

    let mut g = c.benchmark_group("container_write");
    g.sample_size(10).throughput(Throughput::Bytes(raw));
    for level in [1, 3] {
        let stored: usize = chunks
            .iter()
            .map(|ch| codec::encode(&ch.3, level).stored_len())
            .sum();
        eprintln!(
            "zstd level {level}: raw {raw} B, stored {stored} B, ratio {:.3}",
            raw as f64 / stored as f64
        );
        let out = dir.path().join(format!("w{level}.btf"));
        g.bench_function(format!("level{level}"), |b| {
            b.iter(|| {
                let mut w = BtfWriter::create(&out, layout.clone()).unwrap();
                w.container().set_level(level);
                for (tx, ty, band, v) in &chunks {
                    w.write_tile_band(*tx, *ty, *band, v).unwrap();
                }
                w.finish().unwrap();
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("container_read");
    g.sample_size(10).throughput(Throughput::Bytes(raw));
    g.bench_function("every_chunk_decoded_and_checked", |b| {
        b.iter(|| {
            // a small budget: every chunk is decoded (and its checksum verified)
            let btf = Btf::open(&src, MemoryBudget(1 << 20)).unwrap();
            let c = btf.container();
            let rgb = c.array("rgb").unwrap();
            let mut sum = 0f32;
            for k in 0..c.spec(rgb).chunk_count() {
                sum += c.read_chunk::<f16>(rgb, k).unwrap()[0].to_f32();
            }
            sum
        })
    });
    g.finish();

    // one (view, light) image from a freshly opened BTF: decodes one band of
    // every texel tile
    let mut g = c.benchmark_group("direction_image");
    g.sample_size(20)
        .throughput(Throughput::Bytes((SIZE * SIZE * 3 * 2) as u64));
    g.bench_function(format!("cold_{SIZE}x{SIZE}"), |b| {
        let p = layout.pairs() / 2;
        b.iter(|| {
            let btf = Btf::open(&src, MemoryBudget(64 << 20)).unwrap();
            btf.read_pair_images(p..p + 1).unwrap()
        })
    });
    g.finish();
    drop(btf);
}

criterion_group!(container, benches);
criterion_main!(container);
