//! The web studio (`serve`): its request guard (Host/Origin, body size,
//! routes, names), bad and concurrent requests, painting, undo/redo, save
//! and export over its JSON API, and — in headless Chromium driven over the
//! DevTools protocol, skipped with a message when no Chromium is installed —
//! the WebGL2 viewer against the CPU renderer and a brush stroke painted by
//! synthetic pointer events.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::io::imageio::{self, RgbImage};
use btfquilt::output::render::{self, Camera, Light, RenderConfig};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, TileConfig};
use btfquilt::studio::{ServeConfig, Server, Studio, MAX_BODY};
use serde_json::{json, Value};

use crate::common;
use crate::common::cdp::{chromium, get, raw, Browser};

fn start(quilt: &Path) -> Server {
    let cfg = ServeConfig {
        port: 0,
        ..ServeConfig::default()
    };
    Studio::start(quilt, &cfg).unwrap()
}

fn request(addr: SocketAddr, method: &str, path: &str, extra: &str, body: &str) -> Vec<u8> {
    format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n{extra}Content-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .into_bytes()
}

fn post(addr: SocketAddr, path: &str, body: &Value) -> (u16, Value) {
    let (code, bytes) = raw(addr, &request(addr, "POST", path, "", &body.to_string()));
    (code, serde_json::from_slice(&bytes).unwrap_or(Value::Null))
}

fn error_of(body: &[u8]) -> String {
    let v: Value = serde_json::from_slice(body).unwrap_or(Value::Null);
    v["error"].as_str().unwrap_or_default().to_string()
}

/// The atlas uv of the centre of the square's chart.
fn chart_centre(quilt: &Path) -> [f64; 2] {
    let q = btfquilt::quilt::Quilt::open(quilt, MemoryBudget::default()).unwrap();
    let gim = q.open_gim(None, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    let r = gim.resolution;
    let covered: Vec<usize> = (0..r * r).filter(|&t| chart[t] != u32::MAX).collect();
    let mean =
        |f: &dyn Fn(usize) -> usize| covered.iter().map(|&t| f(t) as f64).sum::<f64>() / covered.len() as f64;
    [
        (mean(&|t| t % r) + 0.5) / r as f64,
        (mean(&|t| t / r) + 0.5) / r as f64,
    ]
}

/// The atlas uv of a texel with no chart within 3 texels, if there is one.
fn off_surface(quilt: &Path) -> Option<[f64; 2]> {
    let q = btfquilt::quilt::Quilt::open(quilt, MemoryBudget::default()).unwrap();
    let gim = q.open_gim(None, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    let r = gim.resolution as isize;
    let empty =
        |x: isize, y: isize| x < 0 || y < 0 || x >= r || y >= r || chart[(y * r + x) as usize] == u32::MAX;
    let t = (0..r * r).find(|&t| {
        let (x, y) = (t % r, t / r);
        (-3..=3).all(|dy| (-3..=3).all(|dx| empty(x + dx, y + dy)))
    })?;
    Some([
        ((t % r) as f64 + 0.5) / r as f64,
        ((t / r) as f64 + 0.5) / r as f64,
    ])
}

fn painting_figures(q: &Path) -> (f64, f64) {
    let report = btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default()).unwrap();
    let p = report.painting.expect("painting figures of a painted surface");
    (
        p.region_covered_by_foreground,
        p.foreground_outside_region_and_transition,
    )
}

#[test]
fn the_studio_refuses_foreign_hosts_and_origins_big_bodies_and_bad_requests() {
    let s = crate::paint::scene();
    let base_bytes = std::fs::read(&s.base).unwrap();
    let server = start(&s.base);
    let addr = server.addr();
    assert!(addr.ip().is_loopback(), "binds loopback by default: {addr}");

    let (code, body) = get(addr, "/api/scene");
    assert_eq!(code, 200);
    let scene: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(scene["scene"]["resolution"], 128);
    assert_eq!(scene["scene"]["btf"], false);
    let (code, page) = get(addr, "/");
    assert_eq!(code, 200);
    assert!(String::from_utf8_lossy(&page).contains("studio.js"));
    // localhost names the same loopback address
    let port = addr.port();
    let local = format!("GET /api/status HTTP/1.1\r\nHost: localhost:{port}\r\nConnection: close\r\n\r\n");
    assert_eq!(raw(addr, local.as_bytes()).0, 200);

    // DNS rebinding: a foreign Host or Origin is refused
    let foreign =
        format!("GET /api/scene HTTP/1.1\r\nHost: evil.example:{port}\r\nConnection: close\r\n\r\n");
    let (code, body) = raw(addr, foreign.as_bytes());
    assert_eq!(code, 403);
    assert!(error_of(&body).contains("evil.example"), "{}", error_of(&body));
    let origin = request(addr, "POST", "/api/undo", "Origin: http://evil.example\r\n", "{}");
    let (code, body) = raw(addr, &origin);
    assert_eq!(code, 403);
    assert!(error_of(&body).contains("Origin"), "{}", error_of(&body));
    let no_host = b"GET /api/scene HTTP/1.0\r\n\r\n";
    assert_eq!(raw(addr, no_host).0, 400);
    let own = request(
        addr,
        "GET",
        "/api/status",
        &format!("Origin: http://{addr}\r\n"),
        "",
    );
    assert_eq!(raw(addr, &own).0, 200);

    // bodies over the bound, by their length or their bytes
    let big = format!(
        "POST /api/paint HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n\r\n",
        MAX_BODY + 1
    );
    let (code, body) = raw(addr, big.as_bytes());
    assert_eq!(code, 413, "{}", error_of(&body));
    let huge = format!("{{\"strokes\": [], \"pad\": \"{}\"}}", "x".repeat(MAX_BODY));
    assert_eq!(raw(addr, &request(addr, "POST", "/api/paint", "", &huge)).0, 413);

    // no file by name: traversal and unknown routes are 404
    for path in [
        "/../base.quilt",
        "/base.quilt",
        "/api/../../etc/passwd",
        "/api/nothing",
        "/%2e%2e/base.quilt",
    ] {
        assert_eq!(get(addr, path).0, 404, "{path}");
    }
    assert_eq!(raw(addr, &request(addr, "DELETE", "/api/scene", "", "")).0, 404);

    // malformed and out-of-range bodies: 400 with the reason
    let centre = chart_centre(&s.base);
    for (path, body, needle) in [
        ("/api/paint", "{", "JSON"),
        ("/api/paint", "{\"strokes\": [], \"extra\": 1}", "unknown field"),
        ("/api/paint", "{\"strokes\": []}", "stroke points"),
        (
            "/api/paint",
            "{\"strokes\": [{\"uv\": [2, 0.5], \"radius\": 0.1}]}",
            "0..1",
        ),
        (
            "/api/paint",
            "{\"strokes\": [{\"uv\": [0.5, 0.5], \"radius\": -1}]}",
            "radius",
        ),
        (
            "/api/paint",
            "{\"strokes\": [{\"uv\": [0.5, 0.5], \"radius\": 0.1}], \"sample\": 7}",
            "no sample 7",
        ),
        ("/api/pick", "{\"uv\": [0.5]}", "JSON"),
        ("/api/preview", "{\"uv\": [0.5, 0.5], \"angle\": 1e999}", "JSON"),
        ("/api/save", "{\"name\": \"../x\"}", "name"),
        ("/api/save", "{\"name\": \".hidden\"}", "name"),
        ("/api/export", "{\"name\": \"a/b\"}", "name"),
    ] {
        let (code, reply) = raw(addr, &request(addr, "POST", path, "", body));
        assert_eq!(code, 400, "{path} {body}: {}", error_of(&reply));
        assert!(
            error_of(&reply).contains(needle),
            "{path} {body}: {}",
            error_of(&reply)
        );
    }
    if let Some(uv) = off_surface(&s.base) {
        let (code, reply) = post(addr, "/api/pick", &json!({ "uv": uv }));
        assert_eq!(code, 422, "{uv:?} is off the surface: {reply}");
        assert!(reply["error"].as_str().unwrap().contains("no surface"), "{reply}");
    }
    let (code, reply) = post(addr, "/api/pick", &json!({ "uv": centre }));
    assert_eq!(code, 200, "{reply}");
    let p = reply["point"].as_array().unwrap();
    assert!(p
        .iter()
        .all(|c| c.as_f64().unwrap() > 0.2 && c.as_f64().unwrap() < 0.8 || c == 0.0));
    // the base is never written: saving over it, or over any file, is refused
    let (code, reply) = post(addr, "/api/save", &json!({ "name": "base" }));
    assert_eq!(code, 409, "{reply}");
    let (code, _) = post(addr, "/api/undo", &json!({}));
    assert_eq!(code, 409, "nothing to undo yet");

    // 100 concurrent requests, good and bad: every one answered, nothing lost
    let threads: Vec<_> = (0..100)
        .map(|k| {
            std::thread::spawn(move || match k % 4 {
                0 => get(addr, "/api/scene").0,
                1 => get(addr, "/api/texels").0,
                2 => raw(addr, &request(addr, "POST", "/api/paint", "", "{\"strokes\": 5}")).0,
                _ => raw(addr, b"GARBAGE\r\n\r\n").0,
            })
        })
        .collect();
    let codes: Vec<u16> = threads.into_iter().map(|t| t.join().unwrap()).collect();
    for (k, &c) in codes.iter().enumerate() {
        let want: &[u16] = match k % 4 {
            0 | 1 => &[200],
            2 => &[400],
            _ => &[400, 404, 405, 505],
        };
        assert!(want.contains(&c), "request {k} answered {c}");
    }
    assert_eq!(get(addr, "/api/scene").0, 200, "still answering");
    server.stop();
    assert_eq!(
        std::fs::read(&s.base).unwrap(),
        base_bytes,
        "the base is unchanged"
    );
}

#[test]
fn the_studio_paints_undoes_redoes_saves_and_exports() {
    let s = crate::paint::scene();
    let base_bytes = std::fs::read(&s.base).unwrap();
    let server = start(&s.base);
    let addr = server.addr();
    let centre = chart_centre(&s.base);
    let strokes: Vec<Value> = (0..5)
        .map(|k| json!({ "uv": [centre[0] - 0.04 + 0.02 * k as f64, centre[1]], "radius": 0.08 }))
        .collect();
    let (code, reply) = post(
        addr,
        "/api/paint",
        &json!({ "strokes": strokes, "transition": 5 }),
    );
    assert_eq!(code, 200, "{reply}");
    assert_eq!(reply["status"]["step"], 1);
    let painted = server.current();
    assert_ne!(painted, s.base);
    let (coverage, spill) = painting_figures(&painted);
    assert!(coverage >= 0.95, "F covered by foreground: {coverage}");
    assert!(
        spill <= 0.05,
        "foreground outside F and the transition zone: {spill}"
    );
    let painted_bytes = std::fs::read(&painted).unwrap();

    // undo shows the base again, redo the painted version
    let (code, reply) = post(addr, "/api/undo", &json!({}));
    assert_eq!(code, 200, "{reply}");
    assert_eq!(server.current(), s.base);
    assert_eq!(reply["can_redo"], true);
    let (_, texels_base) = get(addr, "/api/texels");
    let (code, _) = post(addr, "/api/redo", &json!({}));
    assert_eq!(code, 200);
    assert_eq!(server.current(), painted);
    let (_, texels_painted) = get(addr, "/api/texels");
    assert_ne!(
        texels_base, texels_painted,
        "the viewer's texture follows the version"
    );

    // a verbatim preview and copy at the centre
    let (code, preview) = raw(
        addr,
        &request(
            addr,
            "POST",
            "/api/preview",
            "",
            &json!({ "uv": centre, "angle": 30 }).to_string(),
        ),
    );
    assert_eq!(code, 200, "{}", error_of(&preview));
    let word = |k: usize| u32::from_le_bytes(preview[k * 4..k * 4 + 4].try_into().unwrap()) as usize;
    let (w, h) = (word(2), word(3));
    assert!(w > 0 && h > 0 && word(0) + w <= 128 && word(1) + h <= 128);
    assert_eq!(preview.len(), 16 + w * h * 4);
    let (code, reply) = post(addr, "/api/verbatim", &json!({ "uv": centre, "angle": 30 }));
    assert_eq!(code, 200, "{reply}");
    assert_eq!(reply["status"]["step"], 2);

    // save and export land beside the base, never over a file
    let (code, reply) = post(addr, "/api/save", &json!({ "name": "mine" }));
    assert_eq!(code, 200, "{reply}");
    let saved = s.dir.join("mine.quilt");
    assert_eq!(
        std::fs::read(&saved).unwrap(),
        std::fs::read(server.current()).unwrap()
    );
    let (code, _) = post(addr, "/api/save", &json!({ "name": "mine.quilt" }));
    assert_eq!(code, 409, "an existing file is not overwritten");
    let (code, reply) = post(addr, "/api/export", &json!({ "name": "mine_gltf" }));
    assert_eq!(code, 200, "{reply}");
    assert!(s.dir.join("mine_gltf/mesh.glb").is_file(), "{reply}");
    // the saved quilt stands alone: it replays from the base to the same bytes
    let again = s.dir.join("again.quilt");
    btfquilt::paint::replay(&saved, &again, Default::default(), &Silent).unwrap();
    assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(&saved).unwrap());

    // undo twice, paint again: the redo branch is dropped
    for _ in 0..2 {
        assert_eq!(post(addr, "/api/undo", &json!({})).0, 200);
    }
    assert_eq!(server.current(), s.base);
    let (code, reply) = post(
        addr,
        "/api/paint",
        &json!({ "strokes": strokes, "transition": 5 }),
    );
    assert_eq!(code, 200, "{reply}");
    assert_eq!(reply["status"]["can_redo"], false);
    assert_eq!(
        std::fs::read(server.current()).unwrap(),
        painted_bytes,
        "the same stroke, the same bytes"
    );
    // the viewer's texels are one file, the shown version's: each version
    // shown before was removed with it
    let texel_files: Vec<String> = common::listing(&s.dir)
        .into_iter()
        .filter(|n| n.ends_with(".texels"))
        .collect();
    assert_eq!(texel_files.len(), 1, "{texel_files:?}");
    let on_disk = std::fs::read(s.dir.join(&texel_files[0])).unwrap();
    assert_eq!(on_disk, get(addr, "/api/texels").1);

    server.stop();
    assert_eq!(std::fs::read(&s.base).unwrap(), base_bytes);
    let left: Vec<String> = common::listing(&s.dir)
        .into_iter()
        .filter(|n| n.contains(".studio-"))
        .collect();
    assert!(left.is_empty(), "work files left behind: {left:?}");
}

/// PSNR in dB of two 8-bit sRGB pictures (as decoded: linear floats).
fn psnr(a: &RgbImage, b: &RgbImage) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let code = |v: f32| (imageio::linear_to_srgb(v).clamp(0.0, 1.0) * 255.0).round() as f64;
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(&x, &y)| (code(x) - code(y)).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    10.0 * (255.0f64.powi(2) / mse.max(1e-12)).log10()
}

fn crop(img: &RgbImage, x0: usize, y0: usize, w: usize, h: usize) -> RgbImage {
    let mut data = Vec::with_capacity(w * h * 3);
    for y in y0..y0 + h {
        data.extend_from_slice(&img.data[(y * img.width + x0) * 3..(y * img.width + x0 + w) * 3]);
    }
    RgbImage {
        width: w,
        height: h,
        data,
    }
}

/// Share of pixels that differ from the background by more than a few codes.
fn drawn(img: &RgbImage) -> f64 {
    let bg = render::BACKGROUND.map(|v| (imageio::linear_to_srgb(v) * 255.0).round());
    let n = img
        .data
        .chunks_exact(3)
        .filter(|p| (0..3).any(|k| ((imageio::linear_to_srgb(p[k]) * 255.0).round() - bg[k]).abs() > 4.0))
        .count();
    n as f64 / (img.width * img.height) as f64
}

/// Spot (the shipped mesh) on a 128² atlas tiled with render's 32²
/// generated bricks BTF ([`crate::render::bricks_svd`]).
fn btf_spot(dir: &Path) -> PathBuf {
    let g = dir.join("spot.gim");
    let cfg = AtlasConfig {
        resolution: 128,
        ..AtlasConfig::default()
    };
    let mesh = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    atlas::build_gim(&mesh, &g, &cfg, &Silent).unwrap();
    let svd = crate::render::bricks_svd(dir);
    let q = dir.join("spot.quilt");
    quilt::tile(&g, &svd, &q, &TileConfig::default(), &Silent).unwrap();
    q
}

#[test]
fn in_chromium_the_viewer_matches_render_and_relights_a_btf() {
    if chromium().is_none() {
        eprintln!("skipped: no Chromium on PATH (Debian: apt-get install chromium)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let q = btf_spot(dir.path());
    let server = start(&q);
    let (w, h) = (480, 320);
    let camera = Camera::parse("1.9,0.9,2.2,0.0,0.15,0.1,0,1,0,35").unwrap();
    let c = |v: [f32; 3]| format!("{},{},{}", v[0], v[1], v[2]);
    let url = |light: [f32; 3]| {
        format!(
            "{}#bare=1&w={w}&h={h}&camera={},{},{},{}&light={}",
            server.url(),
            c(camera.eye),
            c(camera.target),
            c(camera.up),
            camera.fov,
            c(light)
        )
    };
    let cpu = |light: [f32; 3]| {
        let cfg = RenderConfig {
            camera: Some(camera),
            lights: vec![Light::directional(light)],
            width: w,
            height: h,
            exposure: 0.0,
        };
        let scene = render::Scene::open(&q, MemoryBudget::default()).unwrap();
        scene.render_image(&cfg).unwrap()
    };
    let lights = [[0.4, 0.8, 0.6], [-0.7, 0.3, 0.5]];
    let mut shots = Vec::new();
    for light in lights {
        let Some(mut b) = Browser::open(&url(light), w, h) else {
            return;
        };
        b.wait("window.studio && window.studio.ready", 120);
        let shot = b.screenshot(w, h);
        let want = cpu(light);
        assert!(
            drawn(&shot) > 0.15,
            "the canvas is (nearly) blank: {}",
            drawn(&shot)
        );
        if let Some(d) = std::env::var_os("STUDIO_DUMP") {
            let d = PathBuf::from(d);
            imageio::write_png(
                &d.join(format!("gpu{}.png", shots.len())),
                &shot,
                imageio::PngDepth::Eight,
            )
            .unwrap();
            imageio::write_png(
                &d.join(format!("cpu{}.png", shots.len())),
                &want,
                imageio::PngDepth::Eight,
            )
            .unwrap();
        }
        let db = psnr(&shot, &want);
        assert!(db >= 30.0, "browser vs render under light {light:?}: {db:.1} dB");
        shots.push(shot);
    }
    // the light matters: the two pictures differ more than each from render
    let between = psnr(&shots[0], &shots[1]);
    assert!(between < 25.0, "relighting changed little: {between:.1} dB apart");
    server.stop();
}

#[test]
fn in_chromium_a_brush_stroke_paints_the_region_and_undo_walks_back() {
    if chromium().is_none() {
        eprintln!("skipped: no Chromium on PATH (Debian: apt-get install chromium)");
        return;
    }
    let s = crate::paint::scene();
    let server = start(&s.base);
    let (w, h) = (800, 520);
    // looking straight down on the square, its centre at the canvas centre
    let url = format!(
        "{}#w={w}&h={h}&camera=0.5,0.5,1.6,0.5,0.5,0,0,1,0,40",
        server.url()
    );
    let Some(mut b) = Browser::open(&url, w, h) else {
        return;
    };
    b.wait("window.studio && window.studio.ready", 120);
    let shot = b.screenshot(w, h);
    assert!(
        drawn(&shot) > 0.3,
        "the canvas is (nearly) blank: {}",
        drawn(&shot)
    );
    b.click("mode-brush");
    b.eval("studio.setRadius(0.08); document.getElementById('transition').value = 5; true");
    // a short horizontal stroke right of the panel, released: applied
    let (x0, y) = (w as f64 / 2.0 + 40.0, h as f64 / 2.0);
    b.mouse("mouseMoved", x0, y, 0);
    b.mouse("mousePressed", x0, y, 1);
    for k in 1..=8 {
        b.mouse("mouseMoved", x0 + 5.0 * k as f64, y, 1);
    }
    b.mouse("mouseReleased", x0 + 40.0, y, 0);
    b.wait("studio.changes >= 1", 120);
    // the refreshed frame redrew only what the paint and the stroke's
    // marks covered, and it is the whole frame
    let part = b.eval("studio.lastFrame");
    assert!(part.is_array(), "the change redrew the whole canvas");
    assert_eq!(
        b.eval("studio.redrawDiff()").as_u64(),
        Some(0),
        "redrawn part {part}"
    );
    b.click("mode-view");
    let painted = server.current();
    assert_ne!(painted, s.base, "the stroke made a new version");
    let (coverage, spill) = painting_figures(&painted);
    assert!(coverage >= 0.95, "F covered by foreground: {coverage}");
    assert!(
        spill <= 0.05,
        "foreground outside F and the transition zone: {spill}"
    );
    // the square's middle, clear of the panel, the light widget and the status line
    let view = |img: &RgbImage| crop(img, 300, 40, 300, 400);
    let after = b.screenshot(w, h);
    assert!(
        psnr(&view(&shot), &view(&after)) < 40.0,
        "the texture was not refreshed"
    );
    b.click("undo");
    b.wait("studio.changes >= 2", 60);
    assert_eq!(b.eval("studio.redrawDiff()").as_u64(), Some(0), "after undo");
    assert_eq!(server.current(), s.base);
    let undone = b.screenshot(w, h);
    assert!(
        psnr(&view(&shot), &view(&undone)) > 50.0,
        "undo shows the base again"
    );
    server.stop();
}
