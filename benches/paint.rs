//! Graphcut texture painting on Spot at 1024² (the shipped mesh), tiled in
//! setup from a 192² crop of the shipped brick photo whose foreground is a
//! disk of radius 40 pixels (kept out of the background by the tiling).
//!
//! `paint/region_radius64`: one `paint::paint` of a stroke of radius 0.219
//! (about 64 texels) with an 8-texel transition zone, including opening
//! the artifacts and writing the painted `.quilt` (issue target < 2 s).
//! `paint/preview_session`: one verbatim preview of a [`PreviewSession`]
//! opened in setup — the direct projection and its PNG (target < 100 ms).

use std::path::Path;
use std::time::Duration;

use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::paint::{self, PaintConfig, PreviewSession, Verbatim};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use criterion::{criterion_group, criterion_main, Criterion, SamplingMode};

#[path = "../tests/common/mod.rs"]
mod common;

/// A `size`² mask PNG with a centred disk of `radius` pixels.
fn disk_mask(path: &Path, size: usize, radius: f32) {
    let c = (size as f32 - 1.0) / 2.0;
    common::write_mask_png(path, size, size, |x, y| {
        (x as f32 - c).powi(2) + (y as f32 - c).powi(2) < radius * radius
    });
}

fn bench_paint(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gim_path = d.join("spot.gim");
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    atlas::build_gim(
        &spot,
        &gim_path,
        &AtlasConfig {
            resolution: 1024,
            ..AtlasConfig::default()
        },
        &Silent,
    )
    .unwrap();
    let sample = common::brick_crop(d, 192, None);
    let mask = d.join("disk.png");
    disk_mask(&mask, 192, 40.0);
    let base = d.join("base.quilt");
    let tile = TileConfig {
        sample_mask: Some(mask.clone()),
        ..TileConfig::default()
    };
    quilt::tile(&gim_path, &sample, &base, &tile, &Silent).unwrap();
    let strokes = d.join("stroke.json");
    std::fs::write(&strokes, r#"[{"point": [0.27, 0.17, 0.23], "radius": 0.219}]"#).unwrap();
    let cfg = PaintConfig {
        sample_mask: Some(mask),
        region: Some(strokes),
        transition: 8,
        ..PaintConfig::default()
    };
    let out = d.join("painted.quilt");

    let mut group = c.benchmark_group("paint");
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(15));
    group.bench_function("region_radius64", |b| {
        b.iter(|| paint::paint(&base, &out, &cfg, &Silent).unwrap())
    });
    let mut session = PreviewSession::open(&base, &cfg, &Silent).unwrap();
    let png = d.join("preview.png");
    let v = Verbatim {
        at: [0.27, 0.17, 0.23],
        angle: 20.0,
    };
    group.measurement_time(Duration::from_secs(5));
    group.bench_function("preview_session", |b| {
        b.iter(|| session.preview(v, &png, &Silent).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench_paint);
criterion_main!(benches);
