//! `btfquilt demo`: the pipeline so far on the embedded defaults, writing
//! pictures a person can look at.
//!
//! For now (the foundation stage) it generates one synthetic BTF per material
//! family on the paper's 12×8×12×8 direction grid and writes, for each, the
//! images of one view under lights circling at several elevations, a contact
//! sheet of them, the imperfection mask, and an `index.html` with timings.
//! Then Spot (shipped in `data/`) gets its atlas and geometry image, shown as
//! chart, normal and field pictures and exported as OBJ with atlas UVs.
//! The bricks BTF is also factorized into 40 terms and the same images are
//! reconstructed from the factors, with their PSNR.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::btf::{Angles, Btf};
use crate::container::MemoryBudget;
use crate::factorize::{self, FactorizeConfig, SvdArtifact};
use crate::generate::{self, Family, GenerateConfig, Imperfection};
use crate::gim::{self, AtlasConfig, Gim};
use crate::imageio::{self, PngDepth, RgbImage};
use crate::ingest;
use crate::progress::Progress;
use crate::quilt::{self, TileConfig};
use crate::{bake, evaluate, export, render, show};
use crate::{Error, Result};

/// The demo's samples: (family, imperfection, texels per side).
const SAMPLES: [(Family, Imperfection, usize); 4] = [
    (Family::Bricks, Imperfection::Cracks, 128),
    (Family::Weave, Imperfection::Stains, 128),
    (Family::Cracked, Imperfection::Scratches, 128),
    (Family::Pebbles, Imperfection::None, 128),
];

/// The lights shown for each sample: (θ, φ). The view is the grid's
/// front-most direction.
const LIGHTS: [(f32, f32); 8] = [
    (5.0, 0.0),
    (45.0, 0.0),
    (75.0, 0.0),
    (75.0, 90.0),
    (75.0, 180.0),
    (75.0, 270.0),
    (45.0, 180.0),
    (25.0, 270.0),
];

/// What the demo wrote.
pub struct DemoReport {
    pub out_dir: PathBuf,
    pub lines: Vec<String>,
}

impl std::fmt::Display for DemoReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for l in &self.lines {
            writeln!(f, "{l}")?;
        }
        write!(
            f,
            "open {} to see the results",
            self.out_dir.join("index.html").display()
        )
    }
}

/// Runs the demo into `out_dir`.
pub fn run(out_dir: &Path, memory: MemoryBudget, progress: &dyn Progress) -> Result<DemoReport> {
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut lines = Vec::new();
    let mut html = String::from(
        "<!doctype html><meta charset=utf-8><title>btfquilt demo</title>\
         <style>body{font-family:sans-serif;background:#222;color:#ddd}img{image-rendering:pixelated;margin:2px}\
         td{padding:4px;vertical-align:top}</style><h1>btfquilt demo</h1>\
         <p>Synthetic BTFs on the 12×8×12×8 direction grid: one view, lights circling at 5°, 25°, 45° and 75° \
         from the normal. Shadows and highlights move with the light.</p>",
    );
    for (family, imperfection, size) in SAMPLES {
        let name = family.name();
        let btf_path = out_dir.join(format!("{name}.btf"));
        let cfg = GenerateConfig {
            family,
            imperfection,
            width: size,
            height: size,
            memory,
            seed: 1,
            ..GenerateConfig::default()
        };
        let t = Instant::now();
        let report = generate::generate_btf(&cfg, &btf_path, progress)?;
        let gen_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let btf = Btf::open(&btf_path, memory)?;
        let view = btf.layout().views[0];
        let mut frames = Vec::new();
        for (i, &(theta, phi)) in LIGHTS.iter().enumerate() {
            let light = Angles { theta, phi };
            let img = ingest::pair_image(&btf, view, light)?;
            let file = out_dir.join(format!("{name}_light{i}_tl{theta:02}_pl{phi:03}.png"));
            imageio::write_png(&file, &img, PngDepth::Eight)?;
            frames.push((img, light));
        }
        let sheet = contact_sheet(&frames.iter().map(|(img, _)| img).collect::<Vec<_>>(), 4, 3);
        let sheet_path = out_dir.join(format!("{name}_sheet.png"));
        imageio::write_png(&sheet_path, &sheet, PngDepth::Eight)?;
        let img_s = t.elapsed().as_secs_f64();
        lines.push(format!("{name}: {report}; images {img_s:.2} s"));
        let _ = write!(
            html,
            "<h2>{name} ({} imperfection)</h2><p>generated in {gen_s:.1} s — {}</p><table><tr>",
            imperfection.name(),
            report
        );
        for (i, (_, light)) in frames.iter().enumerate() {
            let _ = write!(
                html,
                "<td><img width={w} src=\"{name}_light{i}_tl{:02}_pl{:03}.png\"><br>light θ {} φ {}</td>",
                light.theta,
                light.phi,
                light.theta,
                light.phi,
                w = size * 2
            );
        }
        if family == Family::Bricks {
            // the factorization: the same lights reconstructed from 40 terms
            let t = Instant::now();
            let svd_path = out_dir.join(format!("{name}.svd"));
            let f = factorize::factorize(
                &btf_path,
                &svd_path,
                &FactorizeConfig {
                    memory,
                    ..Default::default()
                },
                progress,
            )?;
            let svd = SvdArtifact::open(&svd_path, memory)?;
            let mut cells = String::new();
            for (i, (orig, light)) in frames.iter().enumerate() {
                let rec = svd.reconstruct_pair(svd.find_pair(view, *light)?)?;
                let file = format!("{name}_light{i}_reconstructed.png");
                imageio::write_png(&out_dir.join(&file), &rec, PngDepth::Eight)?;
                let _ = write!(
                    cells,
                    "<td><img width={} src=\"{file}\"><br>PSNR {:.1} dB</td>",
                    size * 2,
                    factorize::psnr(orig, &rec)
                );
            }
            let fs = t.elapsed().as_secs_f64();
            lines.push(format!("{name}: factorized in {fs:.1} s: {f}"));
            let _ = write!(
                html,
                "</tr><tr>{cells}<td>reconstructed from {} terms<br>relative error {:.4}<br>{fs:.1} s</td>",
                f.terms, f.relative_error
            );
        }
        if let Some(mask) = &report.mask {
            let mask_name = mask
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let _ = write!(
                html,
                "<td><img width={} src=\"{mask_name}\"><br>imperfection mask</td>",
                size * 2
            );
        }
        html.push_str("</tr></table>");
    }
    // the dense mesh: Spot's atlas and geometry image, with debug pictures
    let t = Instant::now();
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    let spot = if spot.exists() {
        spot
    } else {
        PathBuf::from("data/spot_5.8k.obj")
    };
    let gim_path = out_dir.join("spot.gim");
    let atlas = gim::build_gim(&spot, &gim_path, &AtlasConfig::default(), progress)?;
    let g = Gim::open(&gim_path, memory)?;
    for what in ["charts", "normals", "field"] {
        show::show(&g, what.parse()?, &out_dir.join(format!("spot_{what}.png")))?;
    }
    export::export_gim_obj(&g, &out_dir.join("spot_obj"))?;
    let atlas_s = t.elapsed().as_secs_f64();
    lines.push(format!(
        "spot atlas: {atlas} — with pictures and OBJ export in {atlas_s:.1} s"
    ));
    let _ = write!(
        html,
        "<h2>Spot: atlas and multi-chart geometry image (1024²)</h2><p>{atlas}; {atlas_s:.1} s with pictures. \
         The mesh with its atlas UVs: <code>spot_obj/mesh.obj</code>.</p><table><tr>\
         <td><img width=512 src=\"spot_charts.png\"><br>charts</td>\
         <td><img width=512 src=\"spot_normals.png\"><br>normals</td>\
         <td><img width=512 src=\"spot_field.png\"><br>vector field (yellow heads)</td></tr></table>"
    );
    // graphcut quilting (work in progress): Spot at 512² tiled with a crop of
    // the shipped CC0 brick photo, baked and rendered from two sides
    let t = Instant::now();
    let spot512 = out_dir.join("spot512.gim");
    gim::build_gim(
        &spot,
        &spot512,
        &AtlasConfig {
            resolution: 512,
            ..AtlasConfig::default()
        },
        progress,
    )?;
    let brick = imageio::read_rgb(&spot.with_file_name("brick.png"))?;
    let size = 192.min(brick.width).min(brick.height);
    let mut crop = Vec::with_capacity(size * size * 3);
    for y in 0..size {
        let row = (y + (brick.height - size) / 2) * brick.width + (brick.width - size) / 2;
        crop.extend_from_slice(&brick.data[row * 3..(row + size) * 3]);
    }
    let sample = out_dir.join("brick192.png");
    imageio::write_png(
        &sample,
        &RgbImage {
            width: size,
            height: size,
            data: crop,
        },
        PngDepth::Eight,
    )?;
    let quilt_path = out_dir.join("spot_brick.quilt");
    let tiled = quilt::tile(
        &spot512,
        &sample,
        &quilt_path,
        &TileConfig {
            memory,
            ..TileConfig::default()
        },
        progress,
    )?;
    bake::bake(&quilt_path, None, &out_dir.join("spot_brick_atlas.png"), memory)?;
    let views = [
        (
            "spot_brick_front.png",
            render::Camera::parse("2.2,0.9,2.6,0,0.1,0,0,1,0,38")?,
            [0.4, 0.8, 0.6],
        ),
        (
            "spot_brick_back.png",
            render::Camera::parse("-2.6,0.6,-1.8,0,0.1,0,0,1,0,38")?,
            [-0.5, 0.7, -0.5],
        ),
    ];
    for (file, cam, light) in views {
        let cfg = render::RenderConfig {
            camera: Some(cam),
            lights: vec![render::Light::directional(light)],
            width: 640,
            height: 480,
            exposure: 0.0,
        };
        render::render(&quilt_path, &cfg, &out_dir.join(file), memory)?;
    }
    let figures = evaluate::evaluate(&quilt_path, None, None, memory)?;
    let tile_s = t.elapsed().as_secs_f64();
    lines.push(format!(
        "spot tiled: {tiled}; with atlas, bake, renders and evaluation {tile_s:.1} s"
    ));
    let _ = write!(
        html,
        "<h2>Spot tiled with bricks by graphcut quilting (512² atlas; work in progress)</h2><p>{tiled}; {tile_s:.1} s \
         with bake, renders and evaluation.</p><table><tr><td><img src=\"spot_brick_front.png\"></td>\
         <td><img src=\"spot_brick_back.png\"></td><td><img width=384 src=\"spot_brick_atlas.png\"><br>baked atlas</td>\
         </tr></table><pre>{figures}</pre>"
    );
    let index = out_dir.join("index.html");
    imageio::write_atomic(&index, |w| {
        std::io::Write::write_all(w, html.as_bytes()).map_err(|e| Error::io(&index, e))
    })?;
    Ok(DemoReport {
        out_dir: out_dir.to_path_buf(),
        lines,
    })
}

/// Lays images of one size out in a grid with `gap` pixels between them.
pub fn contact_sheet(images: &[&RgbImage], columns: usize, gap: usize) -> RgbImage {
    let (w, h) = (images[0].width, images[0].height);
    let rows = images.len().div_ceil(columns);
    let sw = columns * w + (columns - 1) * gap;
    let sh = rows * h + (rows - 1) * gap;
    let mut data = vec![0.02f32; sw * sh * 3];
    for (i, img) in images.iter().enumerate() {
        let (ox, oy) = ((i % columns) * (w + gap), (i / columns) * (h + gap));
        for y in 0..h {
            let src = &img.data[y * w * 3..(y + 1) * w * 3];
            let d = ((oy + y) * sw + ox) * 3;
            data[d..d + w * 3].copy_from_slice(src);
        }
    }
    RgbImage {
        width: sw,
        height: sh,
        data,
    }
}
