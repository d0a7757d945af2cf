//! BTF rendering of a decorated mesh (`btfquilt render`).
//!
//! Spot on a 1024² atlas tiled with a generated 128² bricks BTF (12φ×8θ views
//! × lights, 40 terms), rendered at 1024×768 from the default camera under
//! the default light:
//! - `frame_1024x768`: one frame from an opened [`Scene`] (G-buffer +
//!   parallel BTF shading);
//! - `render_png_1024x768`: the whole command, from the artifacts on disk
//!   to a PNG (opening the quilt, geometry image and sample included).
//!
//! The inputs are built once and cached under `target/bench-data/render`
//! (atlas, BTF generation, factorization, tiling: a few minutes the first
//! time); `BTFQUILT_BENCH_QUILT=path.quilt` uses another quilt instead.

use std::path::{Path, PathBuf};
use std::time::Instant;

use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::generate::{self, Family, GenerateConfig, Imperfection};
use btfquilt::output::render::{self, RenderConfig, Scene};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use criterion::{criterion_group, criterion_main, Criterion};

/// The cached Spot quilt, built on first use.
fn quilt() -> PathBuf {
    if let Some(p) = std::env::var_os("BTFQUILT_BENCH_QUILT") {
        return PathBuf::from(p);
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target/bench-data/render");
    let out = dir.join("spot1024_bricks128.quilt");
    if out.exists() {
        return out;
    }
    std::fs::create_dir_all(&dir).unwrap();
    let step =
        |what: &str, t: Instant| eprintln!("bench setup: {what} in {:.1} s", t.elapsed().as_secs_f64());
    let gim_path = dir.join("spot1024.gim");
    if !gim_path.exists() {
        let t = Instant::now();
        let cfg = AtlasConfig {
            resolution: 1024,
            ..AtlasConfig::default()
        };
        atlas::build_gim(&root.join("data/spot_5.8k.obj"), &gim_path, &cfg, &Silent).unwrap();
        step("atlas 1024²", t);
    }
    let svd = dir.join("bricks128.svd");
    if !svd.exists() {
        let t = Instant::now();
        let btf = dir.join("bricks128.btf");
        let g = GenerateConfig {
            family: Family::Bricks,
            imperfection: Imperfection::Cracks,
            width: 128,
            height: 128,
            ..GenerateConfig::default()
        };
        generate::generate_btf(&g, &btf, &Silent).unwrap();
        step("128² BTF on the 12×8×12×8 grid", t);
        let t = Instant::now();
        factorize::factorize(&btf, &svd, &FactorizeConfig::default(), &Silent).unwrap();
        step("factorization (40 terms, 72 rotations)", t);
        // the .svd is all the quilt needs; the raw BTF is half a gigabyte
        let _ = std::fs::remove_file(&btf);
        let _ = std::fs::remove_file(generate::mask_path(&btf));
    }
    let t = Instant::now();
    quilt::tile(&gim_path, &svd, &out, &TileConfig::default(), &Silent).unwrap();
    step("tiling", t);
    out
}

fn benches(c: &mut Criterion) {
    let quilt = quilt();
    let budget = MemoryBudget::default();
    let cfg = RenderConfig {
        width: 1024,
        height: 768,
        ..RenderConfig::default()
    };
    let scene = Scene::open(&quilt, budget).unwrap();
    assert!(scene.is_btf(), "{}: not a BTF quilt", quilt.display());
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("frame.png");

    let mut g = c.benchmark_group("render");
    g.sample_size(10);
    g.bench_function("frame_1024x768", |b| b.iter(|| scene.render_image(&cfg).unwrap()));
    g.bench_function("render_png_1024x768", |b| {
        b.iter(|| render::render(&quilt, &cfg, &png, budget).unwrap())
    });
    g.finish();
}

criterion_group!(rendering, benches);
criterion_main!(rendering);
