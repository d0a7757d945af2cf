//! BTF rendering of a decorated mesh: an oracle on a flat square (the
//! rendered pixel equals Σ g_i p_i at a measured direction pair), response
//! to the light, orbit frames, thread-count independence and bad inputs.
//!
//! Inputs are tiny: a flat 8×8-quad square on a 64² atlas tiled with a 32²
//! generated bricks BTF on a 4φ×3θ grid of views and lights (144 pairs).

use std::path::{Path, PathBuf};

use btfquilt::artifact::btf::{self, Angles};
use btfquilt::artifact::gim::Gim;
use btfquilt::artifact::svd::SvdArtifact;
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::generate::{
    self, BlockRenderer, Family, GenerateConfig, Imperfection, MaterialParams, Mesostructure,
};
use btfquilt::io::imageio::{self, RgbImage};
use btfquilt::output::render::{self, Camera, Light, RenderConfig, BACKGROUND};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, Quilt, TileConfig, NO_PATCH};

use crate::common::{self, btfquilt, fails_clearly, listing, s};

const ATLAS: usize = 64;

struct Fixture {
    dir: tempfile::TempDir,
    gim: PathBuf,
    svd: PathBuf,
    quilt: PathBuf,
}

/// A 32² generated bricks BTF (4×3 views × 4×3 lights) factorized into 12
/// terms: `dir/bricks.svd` (beside `dir/bricks.btf`).
pub(crate) fn bricks_svd(dir: &Path) -> PathBuf {
    let btf_path = dir.join("bricks.btf");
    let grid = btf::grid(4, 3, 75.0);
    let g = GenerateConfig {
        family: Family::Bricks,
        imperfection: Imperfection::None,
        width: 32,
        height: 32,
        views: grid.clone(),
        lights: grid,
        seed: 2,
        block: 32,
        ..GenerateConfig::default()
    };
    generate::generate_btf(&g, &btf_path, &Silent).unwrap();
    let svd = dir.join("bricks.svd");
    let f = FactorizeConfig {
        terms: Some(12),
        ..FactorizeConfig::default()
    };
    factorize::factorize(&btf_path, &svd, &f, &Silent).unwrap();
    svd
}

/// Square + 64² atlas + 32² bricks BTF (4×3 views × 4×3 lights) + its
/// factorization + a quilt, all in a fresh temporary folder.
fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let gim_path = dir.path().join("square.gim");
    let cfg = AtlasConfig {
        resolution: ATLAS,
        ..AtlasConfig::default()
    };
    atlas::build_gim(&common::square_obj(dir.path()), &gim_path, &cfg, &Silent).unwrap();
    let svd = bricks_svd(dir.path());
    let quilt_path = dir.path().join("square.quilt");
    let t = TileConfig {
        patch_radius: Some(12),
        ..TileConfig::default()
    };
    quilt::tile(&gim_path, &svd, &quilt_path, &t, &Silent).unwrap();
    Fixture {
        dir,
        gim: gim_path,
        svd,
        quilt: quilt_path,
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

fn mix(a: [f32; 3], sa: f32, b: [f32; 3], sb: f32) -> [f32; 3] {
    [
        a[0] * sa + b[0] * sb,
        a[1] * sa + b[1] * sb,
        a[2] * sa + b[2] * sb,
    ]
}

/// Σ_i g_i(x, y) p_i(pair) with g bilinear at (x, y): the oracle.
fn reconstruct(svd: &SvdArtifact, g: &[f32], p: &[f32], pair: usize, x: f32, y: f32) -> [f32; 3] {
    let (w, n) = (svd.width, svd.terms);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let mut gi = vec![0f32; n];
    for (xx, yy, wt) in [
        (x0, y0, (1.0 - fx) * (1.0 - fy)),
        (x0 + 1, y0, fx * (1.0 - fy)),
        (x0, y0 + 1, (1.0 - fx) * fy),
        (x0 + 1, y0 + 1, fx * fy),
    ] {
        let (xx, yy) = (xx.min(w - 1), yy.min(svd.height - 1));
        for i in 0..n {
            gi[i] += wt * g[(yy * w + xx) * n + i];
        }
    }
    std::array::from_fn(|c| (0..n).map(|i| gi[i] * p[(pair * 3 + c) * n + i]).sum())
}

fn pixel(img: &RgbImage, x: usize, y: usize) -> [f32; 3] {
    let i = (y * img.width + x) * 3;
    [img.data[i], img.data[i + 1], img.data[i + 2]]
}

/// A texel whose 5×5 neighbourhood lies in one patch (its Jacobian is
/// exact there), away from the sample's border.
fn interior_texels(q: &Quilt) -> Vec<usize> {
    let (patches, coords) = (q.patches().unwrap(), q.coords().unwrap());
    let r = q.resolution;
    let mut out = Vec::new();
    for y in 4..r - 4 {
        for x in 4..r - 4 {
            let t = y * r + x;
            let p = patches[t];
            if p == NO_PATCH || coords[t].iter().any(|&c| !(2.0..29.0).contains(&c)) {
                continue;
            }
            if (-2isize..=2).all(|dy| {
                (-2isize..=2)
                    .all(|dx| patches[(y as isize + dy) as usize * r + (x as isize + dx) as usize] == p)
            }) {
                out.push(t);
            }
        }
    }
    out
}

/// (a) Straight at a texel centre along a measured view direction, under a
/// directional light along a measured light direction (both in the texel's
/// frame: φ from the sample's +x towards its +y, image down), the centre
/// pixel of a linear EXR equals Σ_i g_i p_i(view, light) at the texel's
/// sample coordinate.
#[test]
fn measured_directions_reproduce_the_factorization() {
    let fx = fixture();
    let budget = MemoryBudget::default();
    let q = Quilt::open(&fx.quilt, budget).unwrap();
    let gim = Gim::open(&fx.gim, budget).unwrap();
    let svd = SvdArtifact::open(&fx.svd, budget).unwrap();
    let (g, p) = (svd.geometry_maps().unwrap(), svd.appearance().unwrap());
    let positions: Vec<f32> = gim.read("position").unwrap();
    let normals: Vec<f32> = gim.read("normal").unwrap();
    let pos = |t: usize| [positions[t * 3], positions[t * 3 + 1], positions[t * 3 + 2]];
    let (coords, jac) = (q.coords().unwrap(), q.jacobians().unwrap());
    let r = ATLAS;
    let texels = interior_texels(&q);
    let patches = q.patches().unwrap();
    eprintln!(
        "interior texels {} of {}, patches {:?}",
        texels.len(),
        patches.iter().filter(|&&p| p != NO_PATCH).count(),
        {
            let mut v: Vec<u32> = patches.clone();
            v.sort();
            v.dedup();
            v.len()
        }
    );
    assert!(texels.len() > 20, "too few interior texels: {}", texels.len());
    // a few texels spread over the square (different patches and rotations)
    let picks: Vec<usize> = (0..4).map(|k| texels[k * (texels.len() - 1) / 3]).collect();
    let out = fx.dir.path().join("oracle.exr");
    let mut checked = 0;
    let mut flip_gap = 0f32;
    for &t in &picks {
        let x = pos(t);
        let n = [normals[t * 3], normals[t * 3 + 1], normals[t * 3 + 2]];
        assert!(n[2] > 0.999, "the square's normal is +z: {n:?}");
        // the atlas → 3D map from the neighbouring texels' positions
        let d_x = sub(pos(t + 1), x);
        let d_y = sub(pos(t + r), x);
        let j = jac[t];
        let det = j[0] * j[3] - j[1] * j[2];
        let sx = mix(d_x, j[3] / det, d_y, -j[1] / det); // sample +x on the surface
        let sy = mix(d_x, -j[2] / det, d_y, j[0] / det); // sample +y on the surface
        let xh = normalize(mix(sx, 1.0, n, -dot(sx, n)));
        let y0 = mix(sy, 1.0, n, -dot(sy, n));
        let yh = normalize(mix(y0, 1.0, xh, -dot(y0, xh)));
        let world = |a: Angles| {
            let d = generate::direction(a.theta, a.phi);
            mix(mix(xh, d[0], yh, d[1]), 1.0, n, d[2])
        };
        let view = Angles {
            theta: 15.0,
            phi: 90.0,
        };
        let v = world(view);
        let cam = Camera {
            eye: [x[0] + 60.0 * v[0], x[1] + 60.0 * v[1], x[2] + 60.0 * v[2]],
            target: x,
            up: [0.0, 1.0, 0.0],
            fov: 1.0,
        };
        let mut by_phi = Vec::new();
        for light in [
            Angles {
                theta: 45.0,
                phi: 90.0,
            },
            Angles {
                theta: 75.0,
                phi: 90.0,
            },
            Angles {
                theta: 75.0,
                phi: 270.0,
            },
            Angles {
                theta: 75.0,
                phi: 0.0,
            },
            Angles {
                theta: 15.0,
                phi: 180.0,
            },
        ] {
            let cfg = RenderConfig {
                camera: Some(cam),
                lights: vec![Light::directional(world(light))],
                width: 33,
                height: 33,
                exposure: 0.0,
            };
            render::render(&fx.quilt, &cfg, &out, budget).unwrap();
            let img = imageio::read_rgb(&out).unwrap();
            let got = pixel(&img, 16, 16);
            let pair = svd.find_pair(view, light).unwrap();
            let want = reconstruct(&svd, &g, &p, pair, coords[t][0], coords[t][1]);
            for c in 0..3 {
                let tol = 2e-3 + 1e-2 * want[c].abs();
                assert!(
                    (got[c] - want[c]).abs() <= tol,
                    "texel {t} light {light:?} channel {c}: rendered {got:?}, Σ g p = {want:?}"
                );
            }
            by_phi.push(want);
            checked += 1;
        }
        // light from the sample's +y and from its −y look different here, so
        // a flipped φ convention could not pass
        flip_gap = flip_gap.max(
            (0..3)
                .map(|c| (by_phi[1][c] - by_phi[2][c]).abs())
                .fold(0.0, f32::max),
        );
        // between measured lights: the blend of the 3 nearest with weights
        // 1/α_k − 1/α_4 (α_4 the fourth nearest's angle, so the blend is
        // continuous); one beyond θ 75° is clamped onto it and faded by
        // cos θ / cos 75°
        for light in [
            Angles {
                theta: 35.0,
                phi: 30.0,
            },
            Angles {
                theta: 60.0,
                phi: 290.0,
            },
            Angles {
                theta: 85.0,
                phi: 110.0,
            },
        ] {
            let clamped = light.theta.min(75.0);
            let fade = light.theta.to_radians().cos() / clamped.to_radians().cos();
            let d = generate::direction(clamped, light.phi);
            let mut near: Vec<(f32, usize)> = svd
                .lights
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    let c = dot(d, generate::direction(m.theta, m.phi)).clamp(-1.0, 1.0);
                    (c.acos(), k)
                })
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0));
            assert!(
                near[3].0 - near[2].0 > 0.01,
                "ambiguous third neighbour for {light:?}"
            );
            let weight = |a: f32| 1.0 / a - 1.0 / near[3].0;
            let total: f32 = near[..3].iter().map(|a| weight(a.0)).sum();
            let mut want = [0f32; 3];
            for &(a, k) in &near[..3] {
                let pair = svd.find_pair(view, svd.lights[k]).unwrap();
                let v = reconstruct(&svd, &g, &p, pair, coords[t][0], coords[t][1]);
                for c in 0..3 {
                    want[c] += fade * v[c] * weight(a) / total;
                }
            }
            let cfg = RenderConfig {
                camera: Some(cam),
                lights: vec![Light::directional(world(light))],
                width: 33,
                height: 33,
                exposure: 0.0,
            };
            render::render(&fx.quilt, &cfg, &out, budget).unwrap();
            let got = pixel(&imageio::read_rgb(&out).unwrap(), 16, 16);
            for c in 0..3 {
                let tol = 2e-3 + 1e-2 * want[c].abs();
                assert!(
                    (got[c] - want[c]).abs() <= tol,
                    "texel {t} light {light:?} channel {c}: rendered {got:?}, blend {want:?}"
                );
            }
        }
    }
    assert_eq!(checked, 20);
    assert!(
        flip_gap > 0.02,
        "φ 90° and 270° are indistinguishable at the picked texels: {flip_gap}"
    );
}

/// The convention the renderer matches: in the generator, φ = 90° points to
/// image +y (down the rows). Slopes whose normal leans towards +y are brighter
/// under a grazing light from φ 90° than from φ 270°.
#[test]
fn generator_phi_90_points_down_the_image() {
    let m = Mesostructure::generate(&MaterialParams {
        family: Family::Bricks,
        imperfection: Imperfection::None,
        width: 48,
        height: 48,
        seed: 3,
    });
    let lights = [generate::direction(70.0, 90.0), generate::direction(70.0, 270.0)];
    let r = BlockRenderer::new(&m, 0, 0, 48, 48, &lights);
    let mut out = vec![0f32; 48 * 48 * 2 * 3];
    r.render_view(generate::direction(0.0, 0.0), &mut out);
    let (mut agree, mut disagree) = (0, 0);
    for y in 0..48 {
        for x in 0..48 {
            // normal y component = −∂h/∂y
            let ny = -(m.height_at(x as f32, y as f32 + 1.0) - m.height_at(x as f32, y as f32 - 1.0));
            if ny.abs() < 0.05 {
                continue;
            }
            let i = (y * 48 + x) * 6;
            let diff = out[i] - out[i + 3];
            if diff.abs() < 1e-3 {
                continue;
            }
            if (diff > 0.0) == (ny > 0.0) {
                agree += 1;
            } else {
                disagree += 1;
            }
        }
    }
    assert!(
        agree > 4 * disagree && agree > 20,
        "agree {agree} disagree {disagree}"
    );
}

/// A camera looking straight down at the square, filling most of the frame.
fn top_camera() -> Camera {
    Camera {
        eye: [0.5, 0.5, 3.0],
        target: [0.5, 0.5, 0.0],
        up: [0.0, 1.0, 0.0],
        fov: 25.0,
    }
}

fn render_exr(fx: &Fixture, name: &str, lights: Vec<Light>) -> RgbImage {
    let out = fx.dir.path().join(name);
    let cfg = RenderConfig {
        camera: Some(top_camera()),
        lights,
        width: 48,
        height: 48,
        exposure: 0.0,
    };
    render::render(&fx.quilt, &cfg, &out, MemoryBudget::default()).unwrap();
    imageio::read_rgb(&out).unwrap()
}

fn is_background(px: &[f32]) -> bool {
    px.iter().zip(BACKGROUND).all(|(a, b)| (a - b).abs() < 1e-3)
}

/// (b) Head-on and grazing light give different, dimmer-at-grazing images;
/// a light below the horizon gives black; a far point light matches the
/// directional light along it (its falloff is normalised at the centre).
#[test]
fn shading_follows_the_light() {
    let fx = fixture();
    let head_on = render_exr(&fx, "head.exr", vec![Light::directional([0.0, 0.0, 1.0])]);
    let grazing = render_exr(&fx, "grazing.exr", vec![Light::directional([0.0, 1.0, 0.2])]);
    let below = render_exr(&fx, "below.exr", vec![Light::directional([0.3, 0.2, -1.0])]);
    let mesh: Vec<usize> = (0..48 * 48)
        .filter(|&i| !is_background(&head_on.data[i * 3..i * 3 + 3]))
        .collect();
    assert!(
        mesh.len() > 48 * 48 / 3,
        "the square is not in view: {} pixels",
        mesh.len()
    );
    let mean = |img: &RgbImage| {
        mesh.iter()
            .map(|&i| img.data[i * 3..i * 3 + 3].iter().sum::<f32>())
            .sum::<f32>()
            / mesh.len() as f32
    };
    let diff = mesh
        .iter()
        .map(|&i| {
            (0..3)
                .map(|c| (head_on.data[i * 3 + c] - grazing.data[i * 3 + c]).abs())
                .sum::<f32>()
        })
        .sum::<f32>()
        / mesh.len() as f32;
    assert!(diff > 0.05, "grazing and head-on light look alike: {diff}");
    assert!(
        mean(&grazing) < 0.8 * mean(&head_on),
        "{} vs {}",
        mean(&grazing),
        mean(&head_on)
    );
    assert!(
        mesh.iter()
            .all(|&i| below.data[i * 3..i * 3 + 3] == [0.0, 0.0, 0.0]),
        "a light below the horizon lit the surface"
    );
    // two lights add up
    let both = render_exr(
        &fx,
        "both.exr",
        vec![
            Light::directional([0.0, 0.0, 1.0]),
            Light::directional([0.0, 1.0, 0.2]),
        ],
    );
    for &i in mesh.iter().step_by(7) {
        for c in 0..3 {
            let sum = head_on.data[i * 3 + c] + grazing.data[i * 3 + c];
            assert!(
                (both.data[i * 3 + c] - sum).abs() <= 2e-3 + 2e-3 * sum,
                "pixel {i}: {} vs {sum}",
                both.data[i * 3 + c]
            );
        }
    }
    // a point light far away along the same direction, intensity 1 at the centre
    let d = normalize([0.0, 1.0, 0.2]);
    let far = 1e4;
    let point = render_exr(
        &fx,
        "point.exr",
        vec![Light::Point {
            position: [0.5 + far * d[0], 0.5 + far * d[1], far * d[2]],
            intensity: 1.0,
        }],
    );
    for &i in &mesh {
        for c in 0..3 {
            let (a, b) = (point.data[i * 3 + c], grazing.data[i * 3 + c]);
            assert!(
                (a - b).abs() <= 5e-3 + 1e-2 * b,
                "pixel {i}: point {a} vs directional {b}"
            );
        }
    }
}

/// (c) `--orbit-light 4` writes four different frames and prints their paths.
#[test]
fn orbit_writes_distinct_frames() {
    let fx = fixture();
    let out = fx.dir.path().join("orbit.png");
    let o = btfquilt(&[
        "render",
        s(&fx.quilt),
        "--camera",
        "0.5,0.5,3,0.5,0.5,0,0,1,0,25",
        "--light",
        "0.8,0,0.6",
        "--orbit-light",
        "4",
        "--width",
        "40",
        "--height",
        "40",
        "-o",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    let frames: Vec<Vec<u8>> = (0..4)
        .map(|k| {
            let p = fx.dir.path().join(format!("orbit_{k:03}.png"));
            assert!(stdout.contains(s(&p)), "{} not printed: {stdout}", p.display());
            std::fs::read(&p).unwrap()
        })
        .collect();
    for a in 0..4 {
        for b in a + 1..4 {
            assert_ne!(frames[a], frames[b], "frames {a} and {b} are the same");
        }
    }
    assert!(!out.exists() && !fx.dir.path().join("orbit_004.png").exists());
    // the light circles the view axis: its angle to the axis stays, a quarter
    // turn moves it by 90° about the axis
    let cam = Camera::parse("0.5,0.5,3,0.5,0.5,0,0,1,0,25").unwrap();
    let Light::Directional { direction: d, .. } =
        Light::directional([0.8, 0.0, 0.6]).orbit(&cam, std::f32::consts::FRAC_PI_2)
    else {
        unreachable!()
    };
    assert!(
        d[0].abs() < 1e-6 && (d[1].abs() - 0.8).abs() < 1e-6 && (d[2] - 0.6).abs() < 1e-6,
        "{d:?}"
    );
}

/// (d) The same image, byte for byte, on 1 and 2 threads.
#[test]
fn output_does_not_depend_on_threads() {
    let fx = fixture();
    let cfg = RenderConfig {
        lights: vec![
            Light::directional([0.3, 0.5, 0.8]),
            Light::Point {
                position: [1.5, -0.5, 1.0],
                intensity: 0.7,
            },
        ],
        width: 96,
        height: 72,
        ..RenderConfig::default()
    };
    let bytes: Vec<Vec<u8>> = [1, 2]
        .iter()
        .map(|&k| {
            let out = fx.dir.path().join(format!("t{k}.exr"));
            let pool = rayon::ThreadPoolBuilder::new().num_threads(k).build().unwrap();
            pool.install(|| render::render(&fx.quilt, &cfg, &out, MemoryBudget::default()))
                .unwrap();
            std::fs::read(&out).unwrap()
        })
        .collect();
    assert_eq!(bytes[0], bytes[1]);
    // and something was drawn
    let img = imageio::read_rgb(&fx.dir.path().join("t1.exr")).unwrap();
    assert!(img.data.chunks_exact(3).filter(|p| !is_background(p)).count() > 96 * 72 / 20);
}

/// (e) Bad lights, zero orbit frames, a missing quilt, a quilt whose sample
/// is gone, an unknown image type: a clear error, non-zero exit, no file.
#[test]
fn bad_inputs_are_refused_cleanly() {
    let fx = fixture();
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("view.png");
    let q = s(&fx.quilt);
    let o = s(&out);
    fails_clearly(
        &btfquilt(&["render", q, "--light", "1,2", "-o", o]),
        &["'1,2'", "--light"],
    );
    fails_clearly(
        &btfquilt(&["render", q, "--light", "0,0,0", "-o", o]),
        &["'0,0,0'", "--light"],
    );
    fails_clearly(
        &btfquilt(&["render", q, "--light", "1,x,2", "-o", o]),
        &["'1,x,2'", "--light"],
    );
    fails_clearly(
        &btfquilt(&["render", q, "--point-light", "1,2,nan", "-o", o]),
        &["--point-light"],
    );
    fails_clearly(
        &btfquilt(&["render", q, "--orbit-light", "0", "-o", o]),
        &["--orbit-light 0"],
    );
    fails_clearly(&btfquilt(&["render", q, "--width", "0", "-o", o]), &["--width 0"]);
    fails_clearly(
        &btfquilt(&["render", q, "-o", s(&out_dir.path().join("view.bmp"))]),
        &["view.bmp", ".png or .exr"],
    );
    let missing = fx.dir.path().join("nope.quilt");
    fails_clearly(&btfquilt(&["render", s(&missing), "-o", o]), &["nope.quilt"]);
    // the sample the quilt refers to is gone
    std::fs::remove_file(&fx.svd).unwrap();
    fails_clearly(
        &btfquilt(&["render", q, "-o", o]),
        &["square.quilt", "bricks.svd", "gone"],
    );
    fails_clearly(
        &btfquilt(&["render", q, "--orbit-light", "3", "-o", o]),
        &["bricks.svd"],
    );
    assert!(
        listing(out_dir.path()).is_empty(),
        "left behind: {:?}",
        listing(out_dir.path())
    );
}
