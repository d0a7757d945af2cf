//! Fixtures shared by the integration tests and the benches (which include
//! this file by path): a flat square mesh and crops of the shipped brick
//! photo.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

pub mod cdp;
use std::process::{Command, Output};

use btfquilt::artifact::btf;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::generate::{self, Family, GenerateConfig, Imperfection};
use btfquilt::io::imageio::{self, PngDepth, RgbImage};
use btfquilt::progress::Silent;

/// Quads per side of the flat square.
pub const SQUARE_QUADS: usize = 8;

/// The flat unit square at z = 0 (normal +z): vertices (x, y) row by row and
/// counter-clockwise triangles (0-based), two per quad.
pub fn square_grid() -> (Vec<[f32; 2]>, Vec<[usize; 3]>) {
    let n = SQUARE_QUADS;
    let mut v = Vec::new();
    for y in 0..=n {
        for x in 0..=n {
            v.push([x as f32 / n as f32, y as f32 / n as f32]);
        }
    }
    let mut f = Vec::new();
    for y in 0..n {
        for x in 0..n {
            let a = y * (n + 1) + x;
            f.push([a, a + 1, a + n + 2]);
            f.push([a, a + n + 2, a + n + 1]);
        }
    }
    (v, f)
}

/// The square as `dir/square.obj`.
pub fn square_obj(dir: &Path) -> PathBuf {
    let (v, f) = square_grid();
    let mut s = String::new();
    for q in &v {
        s += &format!("v {} {} 0\n", q[0], q[1]);
    }
    for t in &f {
        s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let p = dir.join("square.obj");
    std::fs::write(&p, s).unwrap();
    p
}

/// The `size`² crop of `data/brick.png` whose top-left pixel is `origin`
/// (`None`: the centre crop), written as `dir/brick{size}.png`.
pub fn brick_crop(dir: &Path, size: usize, origin: Option<(usize, usize)>) -> PathBuf {
    let src = imageio::read_rgb(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick.png")).unwrap();
    let (ox, oy) = origin.unwrap_or(((src.width - size) / 2, (src.height - size) / 2));
    let mut data = Vec::with_capacity(size * size * 3);
    for y in 0..size {
        let row = (y + oy) * src.width + ox;
        data.extend_from_slice(&src.data[row * 3..(row + size) * 3]);
    }
    let p = dir.join(format!("brick{size}.png"));
    let img = RgbImage {
        width: size,
        height: size,
        data,
    };
    imageio::write_png(&p, &img, PngDepth::Eight).unwrap();
    p
}

/// Runs the built `btfquilt` binary with `args`.
pub fn btfquilt(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .args(args)
        .output()
        .expect("runs")
}

/// Runs `btfquilt` and asserts it succeeded; its standard output.
pub fn ok(args: &[&str]) -> String {
    let out = btfquilt(args);
    assert!(
        out.status.success(),
        "btfquilt {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `btfquilt atlas MESH --resolution R -q -o GIM` with the defaults
/// and asserts it succeeded.
pub fn atlas(mesh: &Path, resolution: usize, gim: &Path) {
    let r = resolution.to_string();
    ok(&["atlas", s(mesh), "--resolution", &r, "-q", "-o", s(gim)]);
}

/// Runs `btfquilt tile --gim GIM --sample SAMPLE -q -o QUILT` with the
/// defaults and asserts it succeeded.
pub fn tile(gim: &Path, sample: &Path, quilt: &Path) {
    ok(&[
        "tile",
        "--gim",
        s(gim),
        "--sample",
        s(sample),
        "-q",
        "-o",
        s(quilt),
    ]);
}

/// Asserts a run failed with a non-zero exit, without a panic, and that
/// its standard error names every needle; the standard error.
pub fn fails_clearly(out: &Output, needles: &[&str]) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(!stderr.contains("panicked"), "panicked: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "'{n}' missing from: {stderr}");
    }
    stderr
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Files (hidden ones included) in a folder, sorted; empty if it is absent.
pub fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect(),
        Err(_) => Vec::new(),
    };
    names.sort();
    names
}

/// Writes a `w`×`h` 8-bit PNG whose pixel (x, y) is `f(x, y)` (linear RGB).
pub fn write_rgb_png(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) {
    let data = (0..w * h).flat_map(|i| f(i % w, i / w)).collect();
    let img = RgbImage {
        width: w,
        height: h,
        data,
    };
    imageio::write_png(path, &img, PngDepth::Eight).unwrap();
}

/// Writes a `w`×`h` mask PNG: white where `f(x, y)`, black elsewhere.
pub fn write_mask_png(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> bool) {
    write_rgb_png(path, w, h, |x, y| if f(x, y) { [1.0; 3] } else { [0.0; 3] });
}

/// The f32 channels of an EXR by name, and its size.
pub fn read_exr(path: &Path) -> (usize, usize, Vec<(String, Vec<f32>)>) {
    let img = exr::prelude::read_first_flat_layer_from_file(path).unwrap();
    let layer = img.layer_data;
    let size = layer.size;
    let channels = layer
        .channel_data
        .list
        .into_iter()
        .map(|c| match c.sample_data {
            exr::prelude::FlatSamples::F32(v) => (c.name.to_string(), v),
            _ => panic!("channel {} is not f32", c.name),
        })
        .collect();
    (size.0, size.1, channels)
}

/// The values of the channel `name` (panics naming it if it is absent).
pub fn channel<'a>(channels: &'a [(String, Vec<f32>)], name: &str) -> &'a [f32] {
    &channels
        .iter()
        .find(|(n, _)| n == name)
        .unwrap_or_else(|| panic!("no channel {name}"))
        .1
}

/// A 32² generated BTF on the 4φ×3θ grid (up to `theta`), factorized to
/// `terms` terms: the `.svd` path.
pub fn btf_sample(dir: &Path, name: &str, family: Family, seed: u64, terms: usize, phis: usize) -> PathBuf {
    let btf_path = dir.join(format!("{name}.btf"));
    let grid = btf::grid(phis, 3, 75.0);
    let g = GenerateConfig {
        family,
        imperfection: Imperfection::None,
        width: 32,
        height: 32,
        views: grid.clone(),
        lights: grid,
        seed,
        block: 32,
        ..GenerateConfig::default()
    };
    generate::generate_btf(&g, &btf_path, &Silent).unwrap();
    let svd = dir.join(format!("{name}.svd"));
    let f = FactorizeConfig {
        terms: Some(terms),
        ..FactorizeConfig::default()
    };
    factorize::factorize(&btf_path, &svd, &f, &Silent).unwrap();
    svd
}
