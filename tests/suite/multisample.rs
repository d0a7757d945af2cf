//! Surfaces that draw from several samples: rendering (colour and BTF),
//! baking for the mesh export, the surface BTF export, and the errors for a
//! missing or incompatible second sample.
//!
//! Most fixtures are made by hand, so the split is known exactly: a flat
//! square is tiled with sample A, then a copy of its `.quilt` gets a per
//! texel `sample` array marking the left half (x < ½) as sample 1 and the
//! params `sample_count` = 2, `sample_1` = sample B (as `paint --sample`
//! writes them). A second copy draws everything from B with the same
//! coordinates, so every texel of sample 1 can be compared with the surface
//! that is all B, and every texel of sample 0 with the original. The last
//! test does the same with a surface painted by `paint --sample`.

use std::path::{Path, PathBuf};

use btfquilt::artifact::gim::Gim;
use btfquilt::artifact::svd::SvdArtifact;
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::{ArraySpec, Container, ContainerWriter, DType, MemoryBudget, Param};
use btfquilt::generate::Family;
use btfquilt::io::imageio::{self, PngDepth, RgbImage};
use btfquilt::output::render::{Camera, Light, RenderConfig, Scene, BACKGROUND};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, Quilt, TileConfig, NO_PATCH};

use crate::common::{self, btf_sample, btfquilt, channel, fails_clearly, ok, read_exr, s, write_mask_png};

const ATLAS: usize = 64;
/// Rendered image edge (pixels).
const EDGE: usize = 96;

/// Copies the `.quilt` at `src` to `out`, drawing from `samples` (the first
/// replaces the recorded tiling sample) with the per-texel `index` (`None`:
/// no `sample` array). Every other array and param is copied as it is.
fn rewrite_quilt(src: &Path, out: &Path, samples: &[&Path], index: Option<&[u8]>) {
    let c = Container::open(src, MemoryBudget::default()).unwrap();
    let m = c.metadata();
    let mut w = ContainerWriter::create(out, &m.kind).unwrap();
    if let Some(seed) = m.seed {
        w.set_seed(seed);
    }
    let role = |k: &str| k.strip_suffix("_bytes").unwrap_or(k).to_string();
    let ours = |k: &str| {
        let k = role(k);
        k == "sample" || k == "sample_count" || (k.starts_with("sample_") && k[7..].parse::<usize>().is_ok())
    };
    for i in &m.inputs {
        if !ours(&i.name) {
            w.add_input(&i.name, i.hash);
        }
    }
    for (k, v) in &m.params {
        if !ours(k) {
            w.set_param(k, v.clone());
        }
    }
    // each sample recorded as `paint --sample` records it: path, size and
    // content hash (a missing one with none, so readers find it gone)
    if samples.len() > 1 {
        w.set_param("sample_count", Param::Int(samples.len() as i64));
    }
    for (k, p) in samples.iter().enumerate() {
        let name = if k == 0 {
            "sample".to_string()
        } else {
            format!("sample_{k}")
        };
        let (bytes, hash) = btfquilt::container::file_identity(p).unwrap_or((0, 0));
        w.add_input(&name, hash);
        w.set_param(&name, Param::Text(s(p).to_string()));
        w.set_param(&format!("{name}_bytes"), Param::Int(bytes as i64));
    }
    let mut patch_spec = None;
    for spec in &m.arrays {
        if spec.name == "sample" {
            continue;
        }
        let id = c.array(&spec.name).unwrap();
        let to = w.add_array(spec.clone()).unwrap();
        match spec.dtype {
            DType::F32 => w.write_array(to, &c.read_array::<f32>(id).unwrap()).unwrap(),
            DType::U32 => w.write_array(to, &c.read_array::<u32>(id).unwrap()).unwrap(),
            DType::U8 => w.write_array(to, &c.read_array::<u8>(id).unwrap()).unwrap(),
            DType::F16 => panic!("a quilt holds no f16 array ('{}')", spec.name),
        }
        if spec.name == "patch" {
            patch_spec = Some(spec.clone());
        }
    }
    if let Some(index) = index {
        let p = patch_spec.expect("a quilt has a 'patch' array");
        let spec = ArraySpec::new("sample", DType::U8, &p.shape, &p.chunk_shape).unwrap();
        let id = w.add_array(spec).unwrap();
        w.write_array(id, index).unwrap();
    }
    w.finish().unwrap();
}

/// Copies the `.svd` at `src` to `out` with its appearance functions all
/// zero (so a texel of it adds nothing under any light); the rotated copies,
/// which rendering does not read, are left out.
fn zeroed_svd(src: &Path, out: &Path) {
    let c = Container::open(src, MemoryBudget::default()).unwrap();
    let m = c.metadata();
    let mut w = ContainerWriter::create(out, &m.kind).unwrap();
    for (k, v) in &m.params {
        w.set_param(k, v.clone());
    }
    w.set_param("rotations", Param::Int(0));
    for spec in &m.arrays {
        if spec.name.starts_with("rotated_") {
            continue;
        }
        assert_eq!(spec.dtype, DType::F32, "array '{}'", spec.name);
        let mut values: Vec<f32> = c.read_array(c.array(&spec.name).unwrap()).unwrap();
        if spec.name == "appearance" {
            values.fill(0.0);
        }
        let to = w.add_array(spec.clone()).unwrap();
        w.write_array(to, &values).unwrap();
    }
    w.finish().unwrap();
}

/// The flat square's 64² atlas and, per texel, 1 where its surface point
/// lies at x < ½ (0 elsewhere and on empty texels).
fn square(dir: &Path) -> (PathBuf, Vec<u8>) {
    let g = dir.join("square.gim");
    let cfg = AtlasConfig {
        resolution: ATLAS,
        ..AtlasConfig::default()
    };
    atlas::build_gim(&common::square_obj(dir), &g, &cfg, &Silent).unwrap();
    let gim = Gim::open(&g, MemoryBudget::default()).unwrap();
    let pos: Vec<f32> = gim.read("position").unwrap();
    let left = (0..ATLAS * ATLAS).map(|t| u8::from(pos[t * 3] < 0.5)).collect();
    (g, left)
}

/// A mixed quilt and the two single-sample ones it is compared with.
struct Quilts {
    /// Tiled with A.
    a: PathBuf,
    /// A's coordinates, everything from B.
    b: PathBuf,
    /// A's coordinates; left half from B (sample 1), right half from A.
    mixed: PathBuf,
    /// The sample index written into `mixed`, with 0 on empty texels.
    index: Vec<u8>,
}

/// Tiles the square with `sample_a` and writes the all-B and the mixed copy.
fn quilts(dir: &Path, sample_a: &Path, sample_b: &Path) -> Quilts {
    let (g, left) = square(dir);
    let a = dir.join("a.quilt");
    let t = TileConfig {
        patch_radius: Some(12),
        ..TileConfig::default()
    };
    quilt::tile(&g, sample_a, &a, &t, &Silent).unwrap();
    let q = Quilt::open(&a, MemoryBudget::default()).unwrap();
    let patches = q.patches().unwrap();
    let index: Vec<u8> = (0..ATLAS * ATLAS)
        .map(|t| if patches[t] == NO_PATCH { 0 } else { left[t] })
        .collect();
    let b = dir.join("b.quilt");
    rewrite_quilt(&a, &b, &[sample_b], None);
    let mixed = dir.join("mixed.quilt");
    rewrite_quilt(&a, &mixed, &[sample_a, sample_b], Some(&index));
    Quilts { a, b, mixed, index }
}

/// A brick crop's luminance l, tinted: `tint` × (0.3 + 0.7 l), so the
/// channels keep the tint's ratios everywhere.
fn tinted(dir: &Path, name: &str, origin: (usize, usize), tint: [f32; 3]) -> PathBuf {
    let sub = dir.join(name);
    std::fs::create_dir(&sub).unwrap();
    let crop = imageio::read_rgb(&common::brick_crop(&sub, 48, Some(origin))).unwrap();
    let data = crop
        .data
        .chunks_exact(3)
        .flat_map(|p| {
            let l = 0.3 * p[0] + 0.6 * p[1] + 0.1 * p[2];
            tint.map(|c| (c * (0.3 + 0.7 * l)).min(1.0))
        })
        .collect();
    let p = dir.join(format!("{name}.png"));
    let img = RgbImage {
        width: 48,
        height: 48,
        data,
    };
    imageio::write_png(&p, &img, PngDepth::Eight).unwrap();
    p
}

/// Looking straight down at the square, which fills ¾ of the frame (a
/// little off centre, so pixel centres do not straddle x = ½ evenly).
fn top_camera() -> Camera {
    Camera {
        eye: [0.507, 0.5, 3.0],
        target: [0.507, 0.5, 0.0],
        up: [0.0, 1.0, 0.0],
        fov: 25.0,
    }
}

/// The world (x, y) on the square's plane seen at the centre of pixel
/// (px, py) by [`top_camera`] (image x along world +x, image y along −y).
fn world_at(px: usize, py: usize) -> (f32, f32) {
    let cam = top_camera();
    let focal = 0.5 * EDGE as f32 / (0.5 * cam.fov.to_radians()).tan();
    let z = cam.eye[2];
    let half = EDGE as f32 / 2.0;
    (
        cam.eye[0] + (px as f32 + 0.5 - half) / focal * z,
        cam.eye[1] - (py as f32 + 0.5 - half) / focal * z,
    )
}

fn render(quilt: &Path, lights: Vec<Light>) -> RgbImage {
    let scene = Scene::open(quilt, MemoryBudget::default()).unwrap();
    let cfg = RenderConfig {
        camera: Some(top_camera()),
        lights,
        width: EDGE,
        height: EDGE,
        exposure: 0.0,
    };
    scene.render_image(&cfg).unwrap()
}

fn pixel(img: &RgbImage, i: usize) -> [f32; 3] {
    [img.data[i * 3], img.data[i * 3 + 1], img.data[i * 3 + 2]]
}

/// Pixels well inside the square: (left of x = ½, right of it, near it),
/// at least `margin` (world units) from the line x = ½ for the first two.
fn regions(margin: f32) -> (Vec<usize>, Vec<usize>, Vec<usize>) {
    let (mut left, mut right, mut seam) = (Vec::new(), Vec::new(), Vec::new());
    for py in 0..EDGE {
        for px in 0..EDGE {
            let (x, y) = world_at(px, py);
            if !(0.06..0.94).contains(&x) || !(0.06..0.94).contains(&y) {
                continue;
            }
            let i = py * EDGE + px;
            if x < 0.5 - margin {
                left.push(i);
            } else if x > 0.5 + margin {
                right.push(i);
            } else {
                seam.push(i);
            }
        }
    }
    (left, right, seam)
}

/// Checks the mixed render against the two single-sample ones: exactly B's
/// over the left half, exactly A's over the right, and unlike both on some
/// pixels where they meet (a pixel between the last texel of sample 1 and
/// the first of sample 0, in every row). Returns the mean absolute
/// difference between A and B over the left half.
fn check_halves(mixed: &RgbImage, a: &RgbImage, b: &RgbImage, what: &str) -> f32 {
    let (left, right, seam) = regions(0.08);
    assert!(
        left.len() > 300 && right.len() > 300,
        "{} / {} pixels",
        left.len(),
        right.len()
    );
    for (&i, side, want) in left
        .iter()
        .map(|i| (i, "left", b))
        .chain(right.iter().map(|i| (i, "right", a)))
    {
        assert!(
            !pixel(mixed, i).iter().zip(BACKGROUND).all(|(p, q)| p == &q),
            "{what}: pixel {i} shows no surface"
        );
        assert_eq!(
            pixel(mixed, i),
            pixel(want, i),
            "{what}: {side} pixel {i} {:?} is not its sample's",
            world_at(i % EDGE, i / EDGE)
        );
    }
    let blended = seam
        .iter()
        .filter(|&&i| {
            let m = pixel(mixed, i);
            m != pixel(a, i) && m != pixel(b, i)
        })
        .count();
    assert!(
        blended > EDGE / 2,
        "{what}: only {blended} of {} pixels near x = ½ blend the samples",
        seam.len()
    );
    left.iter()
        .map(|&i| {
            let (pa, pb) = (pixel(a, i), pixel(b, i));
            (0..3).map(|c| (pa[c] - pb[c]).abs()).sum::<f32>()
        })
        .sum::<f32>()
        / left.len() as f32
}

/// Asserts `got` ≈ `want` on every pixel of the square, up to `tol`.
fn assert_close(got: &RgbImage, want: &RgbImage, tol: f32, what: &str) {
    let (left, right, seam) = regions(0.08);
    for i in left.into_iter().chain(right).chain(seam) {
        let (g, w) = (pixel(got, i), pixel(want, i));
        assert!(
            (0..3).all(|c| (g[c] - w[c]).abs() <= tol),
            "{what}: pixel {i} {:?}: {g:?} vs {w:?}",
            world_at(i % EDGE, i / EDGE)
        );
    }
}

/// Colour samples: the render shows each texel's own sample's colours (the
/// left half blue, the right half red), and so does the baked atlas of the
/// mesh export.
#[test]
fn colour_surface_shows_each_texels_sample() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let red = tinted(d, "red", (40, 40), [1.0, 0.12, 0.08]);
    let blue = tinted(d, "blue", (150, 90), [0.08, 0.15, 1.0]);
    let q = quilts(d, &red, &blue);
    assert_eq!(
        Quilt::open(&q.mixed, MemoryBudget::default()).unwrap().samples,
        [red.clone(), blue.clone()]
    );
    let lights = vec![Light::directional([0.2, 0.3, 1.0])];
    let (mixed, a, b) = (
        render(&q.mixed, lights.clone()),
        render(&q.a, lights.clone()),
        render(&q.b, lights),
    );
    let gap = check_halves(&mixed, &a, &b, "colour");
    assert!(gap > 0.2, "the two samples look alike: {gap}");
    let (left, right, _) = regions(0.08);
    for &i in &left {
        let p = pixel(&mixed, i);
        assert!(p[2] > 2.0 * p[0], "left pixel {i} is not blue: {p:?}");
    }
    for &i in &right {
        let p = pixel(&mixed, i);
        assert!(p[0] > 2.0 * p[2], "right pixel {i} is not red: {p:?}");
    }

    // the mesh export bakes every texel from its own sample too
    let out = d.join("obj");
    ok(&["export", s(&q.mixed), "--format", "obj", "-o", s(&out)]);
    let atlas = imageio::read_rgb(&out.join("atlas.png")).unwrap();
    assert_eq!((atlas.width, atlas.height), (ATLAS, ATLAS));
    let patches = Quilt::open(&q.mixed, MemoryBudget::default())
        .unwrap()
        .patches()
        .unwrap();
    let (mut blue_texels, mut red_texels) = (0, 0);
    for (t, &patch) in patches.iter().enumerate() {
        if patch == NO_PATCH {
            continue;
        }
        let p = pixel(&atlas, t);
        if q.index[t] == 1 {
            assert!(
                p[2] > 2.0 * p[0],
                "atlas texel {t} of sample 1 is not blue: {p:?}"
            );
            blue_texels += 1;
        } else {
            assert!(p[0] > 2.0 * p[2], "atlas texel {t} of sample 0 is not red: {p:?}");
            red_texels += 1;
        }
    }
    assert!(
        blue_texels > 500 && red_texels > 500,
        "{blue_texels} / {red_texels}"
    );
}

/// BTF samples with different term counts: over the texels of sample 1 the
/// render is exactly that of the surface drawn all from B, over sample 0's
/// exactly the original. Each texel's g is dotted with its own sample's p
/// only: with B's appearance functions zeroed the render is exactly A's
/// part (zero over sample 1), and the A part plus the B part is the mixed
/// render, seams included. The same sample listed twice renders as the
/// surface of that one sample. The surface BTF export writes the index
/// channel and B's own factors.
#[test]
fn btf_surface_shades_each_texel_in_its_own_basis() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svd_a = btf_sample(d, "bricks", Family::Bricks, 2, 8, 4);
    let svd_b = btf_sample(d, "weave", Family::Weave, 5, 5, 4);
    let q = quilts(d, &svd_a, &svd_b);
    let (zero_a, zero_b, copy_a) = (d.join("zero_a.svd"), d.join("zero_b.svd"), d.join("copy_a.svd"));
    zeroed_svd(&svd_a, &zero_a);
    zeroed_svd(&svd_b, &zero_b);
    std::fs::copy(&svd_a, &copy_a).unwrap();
    let part_a = d.join("part_a.quilt");
    let part_b = d.join("part_b.quilt");
    let twice = d.join("twice.quilt");
    rewrite_quilt(&q.a, &part_a, &[&svd_a, &zero_b], Some(&q.index));
    rewrite_quilt(&q.a, &part_b, &[&zero_a, &svd_b], Some(&q.index));
    rewrite_quilt(&q.a, &twice, &[&svd_a, &copy_a], Some(&q.index));
    let (left, right, _) = regions(0.08);
    let mut gaps = Vec::new();
    for lights in [
        vec![Light::directional([0.2, 0.3, 1.0])],
        vec![
            Light::directional([-0.6, 0.1, 0.5]),
            Light::Point {
                position: [1.2, 0.2, 0.8],
                intensity: 0.6,
            },
        ],
    ] {
        let (mixed, a, b) = (
            render(&q.mixed, lights.clone()),
            render(&q.a, lights.clone()),
            render(&q.b, lights.clone()),
        );
        let scale = a.data.iter().chain(&b.data).fold(0f32, |m, &v| m.max(v));
        gaps.push(check_halves(&mixed, &a, &b, "btf") / scale);

        let (pa, pb) = (render(&part_a, lights.clone()), render(&part_b, lights.clone()));
        for &i in &left {
            assert_eq!(pixel(&pa, i), [0.0; 3], "A's part at left pixel {i}");
            assert_eq!(pixel(&pb, i), pixel(&b, i), "B's part at left pixel {i}");
        }
        for &i in &right {
            assert_eq!(pixel(&pa, i), pixel(&a, i), "A's part at right pixel {i}");
            assert_eq!(pixel(&pb, i), [0.0; 3], "B's part at right pixel {i}");
        }
        let sum = RgbImage {
            width: EDGE,
            height: EDGE,
            data: pa.data.iter().zip(&pb.data).map(|(x, y)| x + y).collect(),
        };
        assert_close(&sum, &mixed, 1e-5 * scale, "A part + B part");
        assert_close(&render(&twice, lights), &a, 1e-5 * scale, "A listed twice");
    }
    assert!(
        gaps.iter().all(|&g| g > 0.05),
        "the two BTFs look alike: {gaps:?}"
    );

    // export --btf: the index channel and B's factors beside A's
    let out = d.join("btf");
    ok(&["export", s(&q.mixed), "--btf", s(&out)]);
    assert_eq!(
        common::listing(&out),
        [
            "FORMAT.md",
            "appearance.csv",
            "appearance_1.csv",
            "directions.csv",
            "geometry_maps.exr",
            "geometry_maps_1.exr",
            "singular_values.csv",
            "singular_values_1.csv",
            "synthesis.exr"
        ]
    );
    let budget = MemoryBudget::default();
    let (a, b) = (
        SvdArtifact::open(&svd_a, budget).unwrap(),
        SvdArtifact::open(&svd_b, budget).unwrap(),
    );
    let quilt = Quilt::open(&q.mixed, budget).unwrap();
    let (coords, patches) = (quilt.coords().unwrap(), quilt.patches().unwrap());
    let (_, _, syn) = read_exr(&out.join("synthesis.exr"));
    let mut chans: Vec<&str> = syn.iter().map(|(n, _)| n.as_str()).collect();
    chans.sort();
    assert_eq!(
        chans,
        ["angle", "dudX", "dudY", "dvdX", "dvdY", "sample", "u", "v"]
    );
    let (u, v, k) = (channel(&syn, "u"), channel(&syn, "v"), channel(&syn, "sample"));
    for (t, &patch) in patches.iter().enumerate() {
        if patch == NO_PATCH {
            assert!(k[t].is_nan() && u[t].is_nan(), "empty texel {t}");
        } else {
            assert_eq!(k[t], q.index[t] as f32, "sample index of texel {t}");
            assert_eq!([u[t], v[t]], coords[t], "texel {t}");
        }
    }
    for (k, svd) in [(0, &a), (1, &b)] {
        let suffix = if k == 0 { String::new() } else { format!("_{k}") };
        let (_, _, maps) = read_exr(&out.join(format!("geometry_maps{suffix}.exr")));
        let n = svd.terms;
        assert_eq!(maps.len(), n, "sample {k}: {n} terms");
        let mut g = vec![0f32; svd.width * svd.height * n];
        for i in 0..n {
            for (x, &val) in channel(&maps, &format!("g{i:02}")).iter().enumerate() {
                g[x * n + i] = val;
            }
        }
        assert!(
            g == svd.geometry_maps().unwrap(),
            "sample {k}: geometry maps differ"
        );
        let text = std::fs::read_to_string(out.join(format!("appearance{suffix}.csv"))).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next().unwrap().split(',').count(), 5 + 3 * n);
        let p: Vec<f32> = lines
            .flat_map(|l| {
                l.split(',')
                    .skip(5)
                    .map(|x| x.parse::<f32>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect();
        assert!(p == svd.appearance().unwrap(), "sample {k}: appearance differs");
        let sigma = std::fs::read_to_string(out.join(format!("singular_values{suffix}.csv"))).unwrap();
        assert_eq!(sigma.lines().count(), 1 + svd.singular_values().unwrap().len());
    }
    let md = std::fs::read_to_string(out.join("FORMAT.md")).unwrap();
    for needle in [
        "`sample`",
        "`geometry_maps_1.exr`",
        "`appearance_1.csv`",
        "- sample 0 (`",
        "bricks.svd`): W×H = 32×32, n = 8 terms",
        "- sample 1 (`",
        "weave.svd`): W×H = 32×32, n = 5 terms",
        "12 views × 12 lights",
    ] {
        assert!(md.contains(needle), "'{needle}' missing from FORMAT.md:\n{md}");
    }

    // a surface from one sample keeps the seven channels and file names
    let single = d.join("single");
    ok(&["export", s(&q.a), "--btf", s(&single)]);
    let (_, _, syn) = read_exr(&single.join("synthesis.exr"));
    let mut chans: Vec<&str> = syn.iter().map(|(n, _)| n.as_str()).collect();
    chans.sort();
    assert_eq!(chans, ["angle", "dudX", "dudY", "dvdX", "dvdY", "u", "v"]);
    assert!(!single.join("geometry_maps_1.exr").exists());
    let md = std::fs::read_to_string(single.join("FORMAT.md")).unwrap();
    assert!(!md.contains("`sample`") && md.contains("(sample `"), "{md}");
}

/// A second sample that is gone, or that has other directions (or is a
/// colour image beside a BTF): render and export fail naming the files,
/// without a panic, and leave nothing behind.
#[test]
fn missing_or_incompatible_second_sample_fails_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svd_a = btf_sample(d, "bricks", Family::Bricks, 2, 6, 4);
    let (g, left) = square(d);
    let a = d.join("a.quilt");
    let t = TileConfig {
        patch_radius: Some(12),
        ..TileConfig::default()
    };
    quilt::tile(&g, &svd_a, &a, &t, &Silent).unwrap();
    let out_dir = d.join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let png = out_dir.join("view.png");
    let run = |quilt: &Path, needles: &[&str]| {
        fails_clearly(
            &btfquilt(&[
                "render",
                s(quilt),
                "--width",
                "32",
                "--height",
                "24",
                "-o",
                s(&png),
            ]),
            needles,
        );
        fails_clearly(
            &btfquilt(&["export", s(quilt), "--btf", s(&out_dir.join("btf"))]),
            needles,
        );
        fails_clearly(
            &btfquilt(&[
                "export",
                s(quilt),
                "--format",
                "obj",
                "-o",
                s(&out_dir.join("obj")),
            ]),
            needles,
        );
        let left_behind: Vec<_> = std::fs::read_dir(&out_dir).unwrap().collect();
        assert!(left_behind.is_empty(), "left behind: {left_behind:?}");
    };

    // the painted-in sample is gone
    let gone = d.join("gone_b.svd");
    let q = d.join("lost.quilt");
    rewrite_quilt(&a, &q, &[&svd_a, &gone], Some(&left));
    run(&q, &["lost.quilt", "gone_b.svd", "gone"]);

    // other directions: 3 azimuths instead of 4
    let other = btf_sample(d, "coarse", Family::Weave, 3, 6, 3);
    let q = d.join("coarse.quilt");
    rewrite_quilt(&a, &q, &[&svd_a, &other], Some(&left));
    run(
        &q,
        &["coarse.svd", "bricks.svd", "must share their direction set"],
    );

    // a colour image beside a BTF
    let red = tinted(d, "red", (40, 40), [1.0, 0.1, 0.1]);
    let q = d.join("colour.quilt");
    rewrite_quilt(&a, &q, &[&svd_a, &red], Some(&left));
    run(&q, &["bricks.svd", "must share their direction set"]);

    // and the well-formed one works through the CLI
    let q = d.join("fine.quilt");
    let b = btf_sample(d, "weave", Family::Weave, 5, 4, 4);
    rewrite_quilt(&a, &q, &[&svd_a, &b], Some(&left));
    ok(&["render", s(&q), "--width", "32", "--height", "24", "-o", s(&png)]);
    assert!(png.exists());
}

/// Per pixel of a [`top_camera`] image, the sample of the atlas texel
/// nearest to the surface point it shows, where every texel in the 5×5
/// block around that one has the same sample (`None` elsewhere).
fn pixel_samples(gim: &Path, quilt: &Quilt) -> Vec<Option<u8>> {
    let gim = Gim::open(gim, MemoryBudget::default()).unwrap();
    let pos: Vec<f32> = gim.read("position").unwrap();
    let (index, patches) = (quilt.sample_index().unwrap(), quilt.patches().unwrap());
    let r = quilt.resolution;
    let covered: Vec<usize> = (0..r * r).filter(|&t| patches[t] != NO_PATCH).collect();
    (0..EDGE * EDGE)
        .map(|i| {
            let (x, y) = world_at(i % EDGE, i / EDGE);
            if !(0.06..0.94).contains(&x) || !(0.06..0.94).contains(&y) {
                return None;
            }
            let d = |t: usize| (pos[t * 3] - x).powi(2) + (pos[t * 3 + 1] - y).powi(2);
            let t = *covered.iter().min_by(|&&a, &&b| d(a).total_cmp(&d(b)))?;
            let (tx, ty) = ((t % r) as isize, (t / r) as isize);
            let k = index[t];
            let mut block = (-2..=2).flat_map(|dy| (-2..=2).map(move |dx| (tx + dx, ty + dy)));
            block
                .all(|(bx, by)| {
                    (0..r as isize).contains(&bx)
                        && (0..r as isize).contains(&by)
                        && patches[by as usize * r + bx as usize] != NO_PATCH
                        && index[by as usize * r + bx as usize] == k
                })
                .then_some(k)
        })
        .collect()
}

/// The real thing: `paint --sample B` over the left half of a surface tiled
/// with A records both samples; the render shows B's own values wherever
/// the texels are B's and A's where they are A's, and the export's
/// `sample` channel is the quilt's index.
#[test]
fn painted_with_another_sample_renders_and_exports_each_texels_own() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let svd_a = btf_sample(d, "bricks", Family::Bricks, 2, 7, 4);
    let svd_b = btf_sample(d, "weave", Family::Weave, 5, 5, 4);
    let (g, _) = square(d);
    let base = d.join("base.quilt");
    let t = TileConfig {
        patch_radius: Some(12),
        ..TileConfig::default()
    };
    quilt::tile(&g, &svd_a, &base, &t, &Silent).unwrap();
    let (region, mask) = (d.join("region.png"), d.join("b_mask.png"));
    write_mask_png(&region, ATLAS, ATLAS, |x, _| x < ATLAS / 2);
    write_mask_png(&mask, 32, 32, |x, y| {
        (x as f32 - 16.0).hypot(y as f32 - 16.0) < 10.0
    });
    let painted = d.join("painted.quilt");
    ok(&[
        "paint",
        s(&base),
        "--sample",
        s(&svd_b),
        "--sample-mask",
        s(&mask),
        "--region",
        s(&region),
        "--patch-radius",
        "8",
        "-q",
        "-o",
        s(&painted),
    ]);
    let q = Quilt::open(&painted, MemoryBudget::default()).unwrap();
    assert_eq!(q.samples.len(), 2, "{:?}", q.samples);
    let index = q.sample_index().unwrap();

    // the same coordinates drawn all from A and all from B
    let (all_a, all_b) = (d.join("all_a.quilt"), d.join("all_b.quilt"));
    rewrite_quilt(&painted, &all_a, &[&svd_a], None);
    rewrite_quilt(&painted, &all_b, &[&svd_b], None);
    let lights = vec![
        Light::directional([0.2, 0.3, 1.0]),
        Light::directional([-0.5, 0.4, 0.6]),
    ];
    let (mixed, a, b) = (
        render(&painted, lights.clone()),
        render(&all_a, lights.clone()),
        render(&all_b, lights),
    );
    let mut count = [0usize; 2];
    for (i, k) in pixel_samples(&g, &q).into_iter().enumerate() {
        let Some(k) = k else { continue };
        let want = if k == 1 { &b } else { &a };
        assert_eq!(pixel(&mixed, i), pixel(want, i), "pixel {i} of sample {k}");
        count[k as usize] += 1;
    }
    assert!(
        count[0] > 500 && count[1] > 500,
        "pixels inside one sample: {count:?}"
    );

    let out = d.join("btf");
    ok(&["export", s(&painted), "--btf", s(&out)]);
    let (_, _, syn) = read_exr(&out.join("synthesis.exr"));
    let (k, u) = (channel(&syn, "sample"), channel(&syn, "u"));
    let patches = q.patches().unwrap();
    for t in 0..ATLAS * ATLAS {
        if patches[t] != NO_PATCH {
            assert_eq!(k[t], index[t] as f32, "texel {t}");
        } else {
            assert!(k[t].is_nan() && u[t].is_nan(), "empty texel {t}");
        }
    }
    let (_, _, maps) = read_exr(&out.join("geometry_maps_1.exr"));
    assert_eq!(maps.len(), 5, "sample 1 is B, with 5 terms");
}
