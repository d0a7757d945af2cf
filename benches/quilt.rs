//! Graphcut quilting in 2D: a flat square atlased at 400² tiled from a 192²
//! centre crop of the shipped brick photo (`data/brick.png`).
//!
//! `tile/square400_from_brick192`: one whole `quilt::tile` run from the
//! sample's `.svd` (factorized once in setup: 3 terms, 72 rotated copies),
//! writing the `.quilt`. The geometry image and the `.svd` are built in
//! setup through the library, as `tests/quilt.rs` does. Ten flat samples
//! of one run each: about 15 s.

use std::path::{Path, PathBuf};
use std::time::Duration;

use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::gim::{self, AtlasConfig};
use btfquilt::imageio::{self, PngDepth, RgbImage};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use criterion::{criterion_group, criterion_main, Criterion, SamplingMode};

/// A flat unit square, 8×8 quads (two triangles each).
fn square(dir: &Path) -> PathBuf {
    let p = dir.join("square.obj");
    let n = 8;
    let mut s = String::new();
    for y in 0..=n {
        for x in 0..=n {
            s += &format!("v {} {} 0\n", x as f32 / n as f32, y as f32 / n as f32);
        }
    }
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x + 1;
            s += &format!(
                "f {} {} {}\nf {} {} {}\n",
                a,
                a + 1,
                a + n + 2,
                a,
                a + n + 2,
                a + n + 1
            );
        }
    }
    std::fs::write(&p, s).unwrap();
    p
}

/// The centre `size`² crop of `data/brick.png`.
fn brick_crop(dir: &Path, size: usize) -> PathBuf {
    let src = imageio::read_rgb(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick.png")).unwrap();
    let (ox, oy) = ((src.width - size) / 2, (src.height - size) / 2);
    let mut data = Vec::with_capacity(size * size * 3);
    for y in 0..size {
        let row = (y + oy) * src.width + ox;
        data.extend_from_slice(&src.data[row * 3..(row + size) * 3]);
    }
    let p = dir.join(format!("brick{size}.png"));
    imageio::write_png(
        &p,
        &RgbImage {
            width: size,
            height: size,
            data,
        },
        PngDepth::Eight,
    )
    .unwrap();
    p
}

fn bench_tile(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let gim_path = dir.path().join("square400.gim");
    gim::build_gim(
        &square(dir.path()),
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
        &brick_crop(dir.path(), 192),
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
}

criterion_group!(benches, bench_tile);
criterion_main!(benches);
