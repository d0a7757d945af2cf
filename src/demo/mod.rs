//! `btfquilt demo`: the whole pipeline on the embedded defaults, writing
//! pictures a person can look at and an `index.html` with the time of every
//! stage.
//!
//! 1. `generate`: the bricks BTF (128², cracks) on the paper's 12×8×12×8
//!    direction grid, shown under one view and eight lights; the other three
//!    families only on those eight direction pairs (so they cost nothing).
//! 2. `factorize`: the bricks into 40 terms with 72 rotated copies, and the
//!    same eight images reconstructed from the factors with their PSNR.
//! 3. `atlas`: Spot (shipped in `data/`) at 1024², with chart, normal and
//!    field pictures.
//! 4. `tile`: Spot with the same bricks generated without the crack layer
//!    (same seed, so the same courses; factorized the same way) by graphcut
//!    quilting, rendered with
//!    BTF shading under a front, a grazing and a side light, baked, evaluated
//!    and exported as glTF.
//! 5. `paint`: the cracked bricks (another sample than the tiling's; its
//!    foreground the cracked zone, the crack lines dilated by 6 texels)
//!    painted into a stroke on Spot's flank by constrained graphcut, rendered.
//! 6. `tile`: Spot with the shipped brick wall (`data/brick_wall.png`, made
//!    from the CC0 brick photo; the colour path), baked and rendered.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;

use crate::artifact::btf::{Angles, Btf};
use crate::artifact::gim::Gim;
use crate::artifact::svd::SvdArtifact;
use crate::atlas::{self, AtlasConfig};
use crate::container::MemoryBudget;
use crate::factorize::{self, FactorizeConfig};
use crate::generate::{self, Family, GenerateConfig, Imperfection};
use crate::ingest;
use crate::io::imageio::{self, PngDepth, RgbImage};
use crate::math;
use crate::mesh::unit_or;
use crate::output::export::{self, ExportOptions, MeshFormat};
use crate::output::render::{self, Camera, Light, RenderConfig};
use crate::paint::{self, PaintConfig};
use crate::progress::Progress;
use crate::quilt::{self, TileConfig};
use crate::{output::bake, output::evaluate, output::show};
use crate::{Error, Result};

/// Texels per side of the generated samples.
const SAMPLE_SIZE: usize = 128;

/// The families shown besides the bricks (only on the eight pairs shown).
const OTHERS: [(Family, Imperfection); 3] = [
    (Family::Weave, Imperfection::Stains),
    (Family::Cracked, Imperfection::Scratches),
    (Family::Pebbles, Imperfection::None),
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

/// Atlas edge for Spot (its geometry image and both tilings).
const ATLAS: usize = 1024;

/// The colour sample next to Spot in `data/`: a frontal brick wall made
/// from the CC0 brick photo (see `data/README.md`).
const BRICK_WALL: &str = "brick_wall.png";

/// Render size.
const RENDER: (usize, usize) = (800, 600);

/// The camera for Spot: a three-quarter view of its face and left side.
const SPOT_CAMERA: Camera = Camera {
    eye: [-2.35, 0.75, -1.6],
    target: [0.24, 0.1, 0.1],
    up: [0.0, 1.0, 0.0],
    fov: 38.0,
};

/// The same from behind, on its right side.
const SPOT_BACK: Camera = Camera {
    eye: [2.45, 0.85, 2.45],
    target: [0.26, 0.1, -0.07],
    up: [0.0, 1.0, 0.0],
    fov: 38.0,
};

/// The lights of the BTF renders: (file suffix, caption, angle to the view
/// axis in degrees, azimuth about it: 0° camera right, 90° camera up).
const BTF_LIGHTS: [(&str, &str, f32, f32); 3] = [
    (
        "front",
        "front light (20° from the view axis, above right)",
        20.0,
        60.0,
    ),
    (
        "grazing",
        "grazing light (75° from the view axis, from above)",
        75.0,
        90.0,
    ),
    (
        "side",
        "side light (85° from the view axis, from the right)",
        85.0,
        5.0,
    ),
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
            "results in {}; open {} to see them",
            self.out_dir.display(),
            self.out_dir.join("index.html").display()
        )
    }
}

/// Stage timings for the report and the page.
struct Stages {
    rows: Vec<(String, f64, String)>,
    lines: Vec<String>,
}

impl Stages {
    fn add(&mut self, stage: &str, seconds: f64, detail: String) {
        self.lines.push(format!("{stage}: {seconds:.1} s — {detail}"));
        self.rows.push((stage.to_string(), seconds, detail));
    }
}

/// A render of the demo's size from `camera` with one directional light at
/// `angle` degrees from the view axis, `azimuth` about it.
fn demo_view(camera: Camera, angle: f32, azimuth: f32) -> RenderConfig {
    RenderConfig {
        camera: Some(camera),
        lights: vec![Light::directional(light_from_camera(&camera, angle, azimuth))],
        width: RENDER.0,
        height: RENDER.1,
        ..RenderConfig::default()
    }
}

/// The direction towards a light at `angle` degrees from the camera's view
/// axis (target → eye), turned by `azimuth` degrees about it (0° towards the
/// image's right, 90° towards its top).
pub fn light_from_camera(camera: &Camera, angle: f32, azimuth: f32) -> [f32; 3] {
    let v = Vec3::from(camera.axis());
    let up = unit_or(camera.up.into(), Vec3::ZERO);
    let up = unit_or(up - v * up.dot(v), Vec3::ZERO);
    let right = up.cross(v);
    let (sa, ca) = math::sin_cos(angle.to_radians());
    let (sz, cz) = math::sin_cos(azimuth.to_radians());
    (ca * v + sa * (cz * right + sz * up)).to_array()
}

/// File name of a path, for links in the page.
fn name_of(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// Writes one view's images under [`LIGHTS`] and their contact sheet;
/// returns the images and the table cells.
fn light_images(btf: &Btf, name: &str, out_dir: &Path) -> Result<(Vec<RgbImage>, String)> {
    let view = btf.layout().views[0];
    let mut frames = Vec::new();
    let mut cells = String::new();
    for (i, &(theta, phi)) in LIGHTS.iter().enumerate() {
        let img = ingest::pair_image(btf, view, Angles { theta, phi })?;
        let file = format!("{name}_light{i}_tl{theta:02}_pl{phi:03}.png");
        imageio::write_png(&out_dir.join(&file), &img, PngDepth::Eight)?;
        let _ = write!(
            cells,
            "<td><img width={w} src=\"{file}\"><br>light θ {theta} φ {phi}</td>",
            w = 2 * img.width
        );
        frames.push(img);
    }
    let sheet = contact_sheet(&frames.iter().collect::<Vec<_>>(), 4, 3);
    imageio::write_png(
        &out_dir.join(format!("{name}_sheet.png")),
        &sheet,
        PngDepth::Eight,
    )?;
    Ok((frames, cells))
}

/// The cell of an imperfection mask, if one was written.
fn mask_cell(report: &generate::GenerateReport) -> String {
    report
        .mask
        .as_ref()
        .map(|m| {
            format!(
                "<td><img width={} src=\"{}\"><br>imperfection mask</td>",
                2 * report.width,
                name_of(m)
            )
        })
        .unwrap_or_default()
}

/// Runs the demo into `out_dir`.
pub fn run(out_dir: &Path, memory: MemoryBudget, progress: &dyn Progress) -> Result<DemoReport> {
    let start = Instant::now();
    std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
    let mut demo = Demo {
        out_dir,
        memory,
        progress,
        st: Stages {
            rows: Vec::new(),
            lines: Vec::new(),
        },
        body: String::new(),
    };
    let (bricks_btf, view, frames) = demo.bricks()?;
    let bricks_svd = demo.factorization(&bricks_btf, view, &frames)?;
    demo.other_families(view)?;
    let (spot, gim_path) = demo.atlas()?;
    let plain_svd = demo.plain_bricks()?;
    let btf_quilt = demo.btf_tiling(&gim_path, &plain_svd)?;
    demo.painting(&bricks_btf, &bricks_svd, &btf_quilt)?;
    demo.photo_tiling(&spot, &gim_path)?;
    demo.page(start)
}

/// The demo's place, budget and progress sink, and what it has written so
/// far: the stage timings and the page's sections.
struct Demo<'a> {
    out_dir: &'a Path,
    memory: MemoryBudget,
    progress: &'a dyn Progress,
    st: Stages,
    body: String,
}

impl Demo<'_> {
    /// 1. The bricks BTF on the full direction grid: its path, the view shown and
    /// the eight light images.
    fn bricks(&mut self) -> Result<(PathBuf, Angles, Vec<RgbImage>)> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        let t = Instant::now();
        let bricks_btf = out_dir.join("bricks.btf");
        let gen = generate::generate_btf(
            &GenerateConfig {
                family: Family::Bricks,
                imperfection: Imperfection::Cracks,
                width: SAMPLE_SIZE,
                height: SAMPLE_SIZE,
                memory,
                seed: 1,
                ..GenerateConfig::default()
            },
            &bricks_btf,
            progress,
        )?;
        let btf = Btf::open(&bricks_btf, memory)?;
        let view = btf.layout().views[0];
        let (frames, cells) = light_images(&btf, "bricks", out_dir)?;
        self.st.add(
            "generate bricks BTF (12×8×12×8) + 8 images",
            t.elapsed().as_secs_f64(),
            gen.to_string(),
        );
        let _ = write!(
            self.body,
            "<h2>1. Generated BTFs</h2><p>Bricks with a crack layer, {SAMPLE_SIZE}² texels on the paper's 12×8×12×8 \
             direction grid (bricks.btf): one view (θ {}°), lights circling at 5°, 25°, 45° and 75° from the normal. \
             Shadows and highlights move with the light.</p><table><tr>{cells}{}</tr>",
            view.theta,
            mask_cell(&gen)
        );
        Ok((bricks_btf, view, frames))
    }

    /// 2. The factorization of the bricks and the eight images reconstructed.
    fn factorization(&mut self, bricks_btf: &Path, view: Angles, frames: &[RgbImage]) -> Result<PathBuf> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        let t = Instant::now();
        let bricks_svd = out_dir.join("bricks.svd");
        let f = factorize::factorize(
            &bricks_btf,
            &bricks_svd,
            &FactorizeConfig {
                memory,
                ..Default::default()
            },
            progress,
        )?;
        let svd = SvdArtifact::open(&bricks_svd, memory)?;
        let mut cells = String::new();
        for (i, (orig, &(theta, phi))) in frames.iter().zip(LIGHTS.iter()).enumerate() {
            let rec = svd.reconstruct_pair(svd.find_pair(view, Angles { theta, phi })?)?;
            let file = format!("bricks_light{i}_reconstructed.png");
            imageio::write_png(&out_dir.join(&file), &rec, PngDepth::Eight)?;
            let _ = write!(
                cells,
                "<td><img width={} src=\"{file}\"><br>PSNR {:.1} dB</td>",
                2 * rec.width,
                factorize::psnr(orig, &rec)
            );
        }
        drop(svd);
        self.st.add(
            "factorize bricks (40 terms, 72 rotated copies) + 8 reconstructions",
            t.elapsed().as_secs_f64(),
            f.to_string(),
        );
        let _ = write!(
            self.body,
            "<tr>{cells}<td>reconstructed from {} terms (bricks.svd)<br>relative error {:.4}</td></tr></table>",
            f.terms, f.relative_error
        );
        Ok(bricks_svd)
    }

    /// The other families, only on the eight pairs shown.
    fn other_families(&mut self, view: Angles) -> Result<()> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        let t = Instant::now();
        let lights: Vec<Angles> = LIGHTS.iter().map(|&(theta, phi)| Angles { theta, phi }).collect();
        let mut others = String::new();
        for (family, imperfection) in OTHERS {
            let name = family.name();
            let path = out_dir.join(format!("{name}.btf"));
            let gen = generate::generate_btf(
                &GenerateConfig {
                    family,
                    imperfection,
                    width: SAMPLE_SIZE,
                    height: SAMPLE_SIZE,
                    views: vec![view],
                    lights: lights.clone(),
                    memory,
                    seed: 1,
                    ..GenerateConfig::default()
                },
                &path,
                progress,
            )?;
            let (_, cells) = light_images(&Btf::open(&path, memory)?, name, out_dir)?;
            let _ = write!(
                others,
                "<h3>{name} ({} imperfection)</h3><table><tr>{cells}{}</tr></table>",
                imperfection.name(),
                mask_cell(&gen)
            );
        }
        self.st.add(
            "generate weave, cracked, pebbles (the 8 pairs shown)",
            t.elapsed().as_secs_f64(),
            format!("{SAMPLE_SIZE}² each"),
        );
        self.body.push_str(&others);
        Ok(())
    }

    /// 3. Spot's atlas and geometry image: the mesh and the `.gim`.
    fn atlas(&mut self) -> Result<(PathBuf, PathBuf)> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        let t = Instant::now();
        let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
        let spot = if spot.exists() {
            spot
        } else {
            PathBuf::from("data/spot_5.8k.obj")
        };
        let gim_path = out_dir.join("spot.gim");
        let atlas = atlas::build_gim(
            &spot,
            &gim_path,
            &AtlasConfig {
                resolution: ATLAS,
                ..AtlasConfig::default()
            },
            progress,
        )?;
        let g = Gim::open(&gim_path, memory)?;
        for what in ["charts", "normals", "field"] {
            show::show(&g, what.parse()?, &out_dir.join(format!("spot_{what}.png")))?;
        }
        drop(g);
        let atlas_s = t.elapsed().as_secs_f64();
        self.st.add(
            &format!("atlas Spot {ATLAS}² + 3 pictures"),
            atlas_s,
            atlas.to_string(),
        );
        let _ = write!(
            self.body,
            "<h2>2. Spot: atlas and multi-chart geometry image ({ATLAS}², spot.gim)</h2><p>{}</p><table><tr>\
             <td><img width=400 src=\"spot_charts.png\"><br>charts</td>\
             <td><img width=400 src=\"spot_normals.png\"><br>normals</td>\
             <td><img width=400 src=\"spot_field.png\"><br>vector field (yellow heads)</td></tr></table>",
            esc(&atlas.to_string())
        );
        Ok((spot, gim_path))
    }

    /// The bricks without the crack layer, factorized.
    fn plain_bricks(&mut self) -> Result<PathBuf> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        // same seed, same courses; the painting puts the cracked ones into a
        // stroke. Its BTF is removed once factorized (only the .svd is used)
        let t = Instant::now();
        let plain_btf = out_dir.join("bricks_plain.btf");
        let plain_svd = out_dir.join("bricks_plain.svd");
        generate::generate_btf(
            &GenerateConfig {
                family: Family::Bricks,
                imperfection: Imperfection::None,
                width: SAMPLE_SIZE,
                height: SAMPLE_SIZE,
                memory,
                seed: 1,
                ..GenerateConfig::default()
            },
            &plain_btf,
            progress,
        )?;
        let fp = factorize::factorize(
            &plain_btf,
            &plain_svd,
            &FactorizeConfig {
                memory,
                ..Default::default()
            },
            progress,
        )?;
        std::fs::remove_file(&plain_btf).map_err(|e| Error::io(&plain_btf, e))?;
        self.st.add(
            "generate + factorize the bricks without cracks",
            t.elapsed().as_secs_f64(),
            fp.to_string(),
        );
        Ok(plain_svd)
    }

    /// 4. Spot tiled with the crack-free bricks BTF, rendered, baked, exported
    /// and evaluated.
    fn btf_tiling(&mut self, gim_path: &Path, plain_svd: &Path) -> Result<PathBuf> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        let t = Instant::now();
        let btf_quilt = out_dir.join("spot_bricks_btf.quilt");
        let tiled = quilt::tile(
            &gim_path,
            &plain_svd,
            &btf_quilt,
            &TileConfig {
                memory,
                ..TileConfig::default()
            },
            progress,
        )?;
        self.st.add(
            &format!("tile Spot {ATLAS}² with the bricks BTF (no cracks)"),
            t.elapsed().as_secs_f64(),
            tiled.to_string(),
        );
        let t = Instant::now();
        let scene = render::Scene::open(&btf_quilt, memory)?;
        let mut renders = String::new();
        for (suffix, caption, angle, azimuth) in BTF_LIGHTS {
            let cfg = demo_view(SPOT_CAMERA, angle, azimuth);
            let file = format!("spot_bricks_btf_{suffix}.png");
            imageio::write_png(&out_dir.join(&file), &scene.render_image(&cfg)?, PngDepth::Eight)?;
            let _ = write!(
                renders,
                "<td><a href=\"{file}\"><img width=480 src=\"{file}\"></a><br>{caption}</td>"
            );
        }
        let back = demo_view(SPOT_BACK, 30.0, 120.0);
        imageio::write_png(
            &out_dir.join("spot_bricks_btf_back.png"),
            &scene.render_image(&back)?,
            PngDepth::Eight,
        )?;
        drop(scene);
        self.st.add(
            &format!("render 4 BTF frames {}×{}", RENDER.0, RENDER.1),
            t.elapsed().as_secs_f64(),
            "front, grazing, side light; back view".into(),
        );
        let t = Instant::now();
        bake::bake(
            &btf_quilt,
            None,
            &out_dir.join("spot_bricks_btf_atlas.png"),
            memory,
        )?;
        let baked_s = t.elapsed().as_secs_f64();
        self.st.add(
            "bake the preview atlas",
            baked_s,
            "spot_bricks_btf_atlas.png".into(),
        );
        let t = Instant::now();
        let gltf_dir = out_dir.join("spot_bricks_gltf");
        let written = export::export(
            &btf_quilt,
            &ExportOptions {
                mesh: Some((MeshFormat::Gltf, gltf_dir.clone())),
                budget: memory,
                ..ExportOptions::default()
            },
        )?;
        let glb = written
            .iter()
            .find(|p| p.extension().is_some_and(|e| e == "glb"))
            .cloned()
            .unwrap_or_else(|| gltf_dir.join("mesh.glb"));
        let glb_bytes = std::fs::metadata(&glb).map(|m| m.len()).unwrap_or(0);
        self.st.add(
            "export glTF",
            t.elapsed().as_secs_f64(),
            format!("{} ({:.1} MB)", glb.display(), glb_bytes as f64 / 1e6),
        );
        let t = Instant::now();
        let figures = serde_json::to_string_pretty(&evaluate::evaluate(&btf_quilt, None, None, memory)?)
            .map_err(|e| crate::Error::Config(format!("writing the figures as JSON: {e}")))?;
        self.st.add(
            "evaluate",
            t.elapsed().as_secs_f64(),
            "seams, zippers, coherence".into(),
        );
        let _ = write!(
            self.body,
            "<h2>3. Spot tiled with the bricks BTF without cracks (bricks_plain.svd; graphcut quilting, {ATLAS}² atlas)</h2><p>{}</p>\
             <p>Rendered with BTF shading: per pixel, the view and light directions in the local frame of the \
             synthesized sample, interpolated between the measured directions, from the 40-term factorization. \
             The same camera, three lights:</p><table><tr>{renders}</tr></table><table><tr>\
             <td><a href=\"spot_bricks_btf_back.png\"><img width=480 src=\"spot_bricks_btf_back.png\"></a><br>\
             from behind</td><td><a href=\"spot_bricks_btf_atlas.png\"><img width=480 src=\"spot_bricks_btf_atlas.png\"></a>\
             <br>baked preview atlas (front-parallel view, head-on light)</td></tr></table>\
             <p>glTF: <a href=\"spot_bricks_gltf/{}\"><code>spot_bricks_gltf/{}</code></a> (the mesh with the baked atlas \
             as base colour). Quality figures (<code>btfquilt evaluate</code>):</p><pre>{}</pre>",
            esc(&tiled.to_string()),
            name_of(&glb),
            name_of(&glb),
            esc(&figures)
        );
        Ok(btf_quilt)
    }

    /// 5. Graphcut texture painting of the cracked bricks into a stroke.
    fn painting(&mut self, bricks_btf: &Path, bricks_svd: &Path, btf_quilt: &Path) -> Result<()> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        // the BTF's crack layer into a stroke on Spot's flank. The foreground is the cracked zone, the generator's
        // thin crack lines dilated by 6 texels: with the lines alone, m0 = 1
        // asks for a crack on every texel of F and the graphcut packs crack
        // fragments, breaking the bricks up
        let t = Instant::now();
        let crack_lines = generate::mask_path(&bricks_btf);
        let (mw, mh) = imageio::image_size(&crack_lines)?;
        let zone = dilate_wrapping(&imageio::read_sized_mask(&crack_lines, mw, mh, "")?, mw, mh, 6);
        let crack_zone = out_dir.join("bricks.crackzone.png");
        imageio::write_mask_png(&crack_zone, mw, mh, &zone)?;
        let strokes = out_dir.join("spot_strokes.json");
        std::fs::write(&strokes, "[{\"point\": [-0.27, 0.17, 0.23], \"radius\": 0.2}]\n")
            .map_err(|e| Error::io(&strokes, e))?;
        let painted = out_dir.join("spot_bricks_painted.quilt");
        let paint_report = paint::paint(
            &btf_quilt,
            &painted,
            &PaintConfig {
                sample: Some(bricks_svd.to_path_buf()),
                sample_mask: Some(crack_zone),
                region: Some(strokes),
                transition: 8,
                tile: TileConfig {
                    memory,
                    ..TileConfig::default()
                },
                ..PaintConfig::default()
            },
            progress,
        )?;
        let (_, caption, angle, azimuth) = BTF_LIGHTS[0];
        let cfg = demo_view(SPOT_CAMERA, angle, azimuth);
        let scene = render::Scene::open(&painted, memory)?;
        imageio::write_png(
            &out_dir.join("spot_bricks_painted_front.png"),
            &scene.render_image(&cfg)?,
            PngDepth::Eight,
        )?;
        drop(scene);
        self.st.add(
            "paint cracks into a stroke on Spot + render",
            t.elapsed().as_secs_f64(),
            paint_report.to_string(),
        );
        let _ = write!(
            self.body,
            "<h2>4. Graphcut texture painting</h2><p>The cracked bricks (<code>bricks.svd</code>, another sample than \
             the crack-free <code>bricks_plain.svd</code> the surface was tiled with; its foreground the cracked zone \
             <code>bricks.crackzone.png</code>, the crack lines of <code>bricks.mask.png</code> dilated by 6 texels) \
             painted into a stroke of radius 0.2 on Spot's flank (<code>spot_strokes.json</code>, an 8-texel \
             transition zone) by constrained graphcut: {}. Nothing outside the stroke and its zone changes.\
             </p><table><tr>\
             <td><a href=\"spot_bricks_btf_front.png\"><img width=480 src=\"spot_bricks_btf_front.png\"></a><br>before</td>\
             <td><a href=\"spot_bricks_painted_front.png\"><img width=480 src=\"spot_bricks_painted_front.png\"></a>\
             <br>painted ({caption})</td></tr></table>",
            esc(&paint_report.to_string())
        );
        Ok(())
    }

    /// 6. Spot tiled with the brick wall (the colour path).
    fn photo_tiling(&mut self, spot: &Path, gim_path: &Path) -> Result<()> {
        let (out_dir, memory, progress) = (self.out_dir, self.memory, self.progress);
        // the brick wall is made from the CC0 brick photo
        let t = Instant::now();
        let wall = spot.with_file_name(BRICK_WALL);
        let photo = out_dir.join(BRICK_WALL);
        std::fs::copy(&wall, &photo).map_err(|e| Error::io(&wall, e))?;
        let size = imageio::image_size(&photo)?.0;
        let photo_quilt = out_dir.join("spot_brick_photo.quilt");
        let tiled = quilt::tile(
            &gim_path,
            &photo,
            &photo_quilt,
            &TileConfig {
                memory,
                ..TileConfig::default()
            },
            progress,
        )?;
        bake::bake(
            &photo_quilt,
            None,
            &out_dir.join("spot_brick_photo_atlas.png"),
            memory,
        )?;
        let scene = render::Scene::open(&photo_quilt, memory)?;
        for (file, camera) in [
            ("spot_brick_photo_front.png", SPOT_CAMERA),
            ("spot_brick_photo_back.png", SPOT_BACK),
        ] {
            let cfg = demo_view(camera, 30.0, 120.0);
            imageio::write_png(&out_dir.join(file), &scene.render_image(&cfg)?, PngDepth::Eight)?;
        }
        drop(scene);
        self.st.add(
            &format!("tile Spot {ATLAS}² with the {size}² brick wall + bake + 2 renders"),
            t.elapsed().as_secs_f64(),
            tiled.to_string(),
        );
        let _ = write!(
            self.body,
            "<h2>5. Spot tiled with a colour sample ({size}² brick wall made from the CC0 brick photo, {ATLAS}² atlas)</h2>\
             <p>{}</p><table><tr><td><img width={size} src=\"{}\"><br>sample</td>\
             <td><a href=\"spot_brick_photo_front.png\"><img width=480 src=\"spot_brick_photo_front.png\"></a></td>\
             <td><a href=\"spot_brick_photo_back.png\"><img width=480 src=\"spot_brick_photo_back.png\"></a></td>\
             <td><a href=\"spot_brick_photo_atlas.png\"><img width=400 src=\"spot_brick_photo_atlas.png\"></a><br>baked atlas</td>\
             </tr></table>",
            esc(&tiled.to_string()),
            name_of(&photo)
        );
        Ok(())
    }

    /// The page: timings first, then the pictures.
    fn page(self, start: Instant) -> Result<DemoReport> {
        let (out_dir, st, body) = (self.out_dir, self.st, self.body);
        let total = start.elapsed().as_secs_f64();
        let mut html = String::from(
            "<!doctype html><meta charset=utf-8><title>btfquilt demo</title>\
             <style>body{font-family:sans-serif;background:#222;color:#ddd;margin:1em}\
             img{image-rendering:auto;margin:2px}a{color:#9cf}td{padding:4px;vertical-align:top;font-size:90%}\
             table.t td{border-bottom:1px solid #444}pre{background:#111;padding:6px;white-space:pre-wrap}</style>\
             <h1>btfquilt demo</h1><p>The whole pipeline on the embedded defaults: a generated BTF, its \
             factorization, Spot's atlas, graphcut quilting of Spot with the BTF and with a colour photo, \
             BTF renders, the baked atlas and a glTF export.</p><h2>Stages</h2><table class=t>\
             <tr><td><b>stage</b></td><td><b>seconds</b></td><td><b>result</b></td></tr>",
        );
        for (stage, s, detail) in &st.rows {
            let _ = write!(
                html,
                "<tr><td>{}</td><td align=right>{s:.1}</td><td>{}</td></tr>",
                esc(stage),
                esc(detail)
            );
        }
        let _ = write!(
            html,
            "<tr><td><b>total</b></td><td align=right><b>{total:.1}</b></td><td></td></tr></table>"
        );
        html.push_str(&body);
        let index = out_dir.join("index.html");
        imageio::write_atomic(&index, |w| {
            std::io::Write::write_all(w, html.as_bytes()).map_err(|e| Error::io(&index, e))
        })?;
        let mut lines = st.lines;
        lines.push(format!("total: {total:.1} s"));
        Ok(DemoReport {
            out_dir: out_dir.to_path_buf(),
            lines,
        })
    }
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

/// A binary mask (≥ ½ is foreground) dilated by a disk of `radius` pixels on
/// a periodic `w`×`h` sample.
fn dilate_wrapping(mask: &[f32], w: usize, h: usize, radius: usize) -> Vec<f32> {
    let r = radius as isize;
    let mut out = vec![0f32; w * h];
    for y in 0..h as isize {
        for x in 0..w as isize {
            let hit = (-r..=r).any(|dy| {
                (-r..=r).any(|dx| {
                    let (sx, sy) = ((x + dx).rem_euclid(w as isize), (y + dy).rem_euclid(h as isize));
                    dx * dx + dy * dy <= r * r && mask[sy as usize * w + sx as usize] >= 0.5
                })
            });
            out[y as usize * w + x as usize] = hit as u8 as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests;
