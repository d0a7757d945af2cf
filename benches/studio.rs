//! The studio measured in headless Chromium (software GL): frames per second
//! at 1280×720, the verbatim preview's round trip under the cursor, the time
//! from a brush stroke's release to the refreshed texture, and the server's
//! memory while painting ten strokes.
//!
//! ```text
//! cargo bench --bench studio -- SURFACE.quilt [--sample S --sample-mask M] [--memory M] [--strokes N] [--screenshot PNG]
//! ```
//!
//! The server runs as its own process (`btfquilt serve`), so its peak RSS
//! (`VmHWM`) is the studio's alone. Without a surface, or without
//! Chromium, it says so and measures nothing.

use std::io::BufRead;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Instant;

#[path = "../tests/common/cdp.rs"]
mod cdp;

fn status_kib(pid: u32, key: &str) -> u64 {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    text.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let mut args = std::env::args().skip(1).filter(|a| a != "--bench");
    let mut quilt = None;
    let (mut sample, mut mask, mut memory, mut strokes) = (None, None, None, 10usize);
    let mut screenshot = None;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--sample" => sample = args.next(),
            "--sample-mask" => mask = args.next(),
            "--memory" => memory = args.next(),
            "--screenshot" => screenshot = args.next().map(PathBuf::from),
            "--strokes" => strokes = args.next().and_then(|s| s.parse().ok()).unwrap_or(10),
            _ => quilt = Some(PathBuf::from(a)),
        }
    }
    let Some(quilt) = quilt else {
        eprintln!("studio bench: give a surface: cargo bench --bench studio -- SURFACE.quilt");
        return;
    };
    if cdp::chromium().is_none() {
        eprintln!("studio bench: no Chromium on PATH (Debian: apt-get install chromium)");
        return;
    }
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_btfquilt"));
    let mut cmd = Command::new(bin);
    cmd.args(["serve", "--port", "0", "-q"]).arg(&quilt);
    if let Some(m) = &memory {
        cmd.args(["--memory", m]);
    }
    if let (Some(s), Some(m)) = (&sample, &mask) {
        cmd.args(["--sample", s, "--sample-mask", m]);
    }
    let mut server = cmd.stdout(Stdio::piped()).spawn().expect("btfquilt serve");
    let pid = server.id();
    let line = std::io::BufReader::new(server.stdout.take().unwrap())
        .lines()
        .next()
        .expect("the studio's address")
        .unwrap();
    let url = line.split(" at ").last().unwrap().trim().to_string();
    let rss_open = status_kib(pid, "VmRSS:");
    let (w, h) = (1280, 720);
    let mut b = cdp::Browser::open(&format!("{url}#w={w}&h={h}"), w, h).expect("Chromium");
    let t = Instant::now();
    b.wait("window.studio && window.studio.ready", 600);
    println!(
        "page ready in {:.2} s (server RSS after opening {} MiB)",
        t.elapsed().as_secs_f64(),
        rss_open / 1024
    );
    let fps = b.eval("studio.measureFps(10)").as_f64().unwrap();
    println!(
        "frames per second at {w}×{h}: {fps:.2} (frame {:.0} ms)",
        1000.0 / fps
    );

    // verbatim previews under the cursor, across the middle of the view
    let k = if sample.is_some() { 1 } else { 0 };
    b.eval(&format!(
        "document.getElementById('sample').value = {k}; studio.setMode('verbatim'); true"
    ));
    let (mut fetch, mut full) = (Vec::new(), Vec::new());
    for i in 0..12 {
        let x = w as f64 * (0.42 + 0.015 * i as f64);
        b.eval(&format!("studio.preview({x}, {})", h as f64 * 0.55));
        fetch.push(b.eval("studio.lastPreviewFetchMs").as_f64().unwrap_or(f64::NAN));
        full.push(b.eval("studio.lastPreviewMs").as_f64().unwrap_or(f64::NAN));
    }
    // the first opens the preview session
    let first = full[0];
    println!(
        "verbatim preview: first {:.0} ms; then median {:.1} ms request+answer, {:.0} ms with the redraw",
        first,
        median(&mut fetch[1..]),
        median(&mut full[1..])
    );

    // brush strokes, each applied on release
    b.eval(&format!(
        "studio.setMode('brush'); document.getElementById('sample').value = {k}; true"
    ));
    let (mut apply, mut server_paint, mut server_all) = (Vec::new(), Vec::new(), Vec::new());
    let mut drawn = Vec::new();
    for i in 0..strokes {
        // across the flank of a mesh framed by the default camera
        let (x0, y) = (
            w as f64 * (0.40 + 0.02 * i as f64),
            h as f64 * (0.6 + 0.02 * (i % 3) as f64),
        );
        b.mouse("mouseMoved", x0, y, 0);
        b.mouse("mousePressed", x0, y, 1);
        for s in 1..=6 {
            b.mouse("mouseMoved", x0 + 4.0 * s as f64, y, 1);
        }
        let points = b.eval("S.strokes.length");
        assert!(
            points.as_u64() > Some(0),
            "stroke {i} at ({x0}, {y}) missed the surface"
        );
        b.mouse("mouseReleased", x0 + 24.0, y, 0);
        b.wait(&format!("studio.changes >= {}", i + 1), 600);
        let ms = b.eval("studio.lastApplyMs").as_f64().unwrap();
        let job = b.eval(
            "fetch('/api/status').then((r) => r.json()).then((s) => [s.job.paint_seconds, s.job.seconds])",
        );
        server_paint.push(job[0].as_f64().unwrap() * 1000.0);
        server_all.push(job[1].as_f64().unwrap() * 1000.0);
        let err = b.eval("studio.error");
        assert!(err.is_null(), "stroke {i}: {err}");
        apply.push(ms);
        let part = b.eval("studio.lastFrame");
        if i == 0 {
            // (after the time is taken: a whole redraw to compare with)
            let diff = b.eval("studio.redrawDiff()");
            assert_eq!(
                diff.as_u64(),
                Some(0),
                "the first stroke's frame differs from a whole redraw"
            );
        }
        let steps = b.eval("[studio.lastApplySteps, studio.lastChanged]");
        drawn.push(if part.is_array() {
            format!("{:.2} s (part {part}; steps {steps})", ms / 1000.0)
        } else {
            format!("{:.2} s (whole frame; steps {steps})", ms / 1000.0)
        });
    }
    println!(
        "stroke release → refreshed texture: median {:.2} s, max {:.2} s over {strokes} strokes",
        median(&mut apply.clone()) / 1000.0,
        apply.iter().cloned().fold(0.0, f64::max) / 1000.0
    );
    println!("  each: {}", drawn.join(", "));
    println!(
        "  of which in the server: paint median {:.2} s, paint + rebuilding the viewer's data {:.2} s",
        median(&mut server_paint) / 1000.0,
        median(&mut server_all) / 1000.0
    );
    println!(
        "server memory: peak RSS {} MiB (now {} MiB) after {strokes} strokes",
        status_kib(pid, "VmHWM:") / 1024,
        status_kib(pid, "VmRSS:") / 1024
    );
    if let Some(path) = screenshot {
        // the last stroke's region, as painted, under a light from the left
        b.eval("studio.setMode('brush'); true");
        b.mouse("mouseMoved", w as f64 * 0.47, h as f64 * 0.62, 0);
        let img = b.screenshot(w, h);
        btfquilt::io::imageio::write_png(&path, &img, btfquilt::io::imageio::PngDepth::Eight).unwrap();
        println!("wrote {}", path.display());
    }
    drop(b);
    let _ = server.kill();
    let _ = server.wait();
}
