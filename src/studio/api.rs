//! The studio's HTTP interface: the request guard (Host/Origin, body size),
//! the routes, and JSON in and out (serde).
//!
//! | route | answer |
//! |---|---|
//! | `GET /`, `/studio.js` | the page and its script (embedded) |
//! | `GET /api/scene` | [`super::scene::SceneInfo`] and the version |
//! | `GET /api/mesh`, `/api/texels`, `/api/basis` | the viewer's arrays ([`super::Payload`]) |
//! | `GET /api/status` | the paint run's progress and the history |
//! | `POST /api/pick` | `{uv}` → the dense-mesh point under an atlas position |
//! | `POST /api/paint` | `{strokes: [{uv, radius}], sample, transition, seed}`: constrained graphcut |
//! | `POST /api/preview` | `{uv, angle, sample}` → the verbatim projection (binary) |
//! | `POST /api/verbatim` | `{uv, angle, sample}`: merge a verbatim copy |
//! | `POST /api/undo`, `/api/redo` | walk the paint log |
//! | `POST /api/save` | `{name}`: write `NAME.quilt` beside the base |
//! | `POST /api/export` | `{name}`: write glTF into the folder `NAME` beside the base |

use std::io::{Read, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use tiny_http::{Header, Method, Request, Response, StatusCode};

use super::{JobProgress, JobStatus, Studio, MAX_BODY, MAX_VERSIONS};
use crate::artifact::gim::{Gim, EMPTY};
use crate::lock;
use crate::output::render::nearest_covered;
use crate::paint::{PaintConfig, Verbatim};
use crate::quilt::TileConfig;

const PAGE: &str = include_str!("assets/index.html");
const SCRIPT: &str = include_str!("assets/studio.js");

/// Which `Host` and `Origin` values a request may carry: the listening
/// address, and `localhost` for a loopback one.
pub(super) struct Guard {
    hosts: Vec<String>,
}

impl Guard {
    pub(super) fn new(addr: SocketAddr) -> Guard {
        let port = addr.port();
        let mut hosts = vec![match addr {
            SocketAddr::V4(a) => format!("{}:{port}", a.ip()),
            SocketAddr::V6(a) => format!("[{}]:{port}", a.ip()),
        }];
        if addr.ip().is_loopback() {
            hosts.extend([
                format!("localhost:{port}"),
                format!("127.0.0.1:{port}"),
                format!("[::1]:{port}"),
            ]);
        }
        hosts.dedup();
        Guard { hosts }
    }

    /// Why the request may not be answered, if so.
    fn refuse(&self, req: &Request) -> Option<(u16, String)> {
        let header = |name: &str| {
            req.headers()
                .iter()
                .find(|h| h.field.as_str().as_str().eq_ignore_ascii_case(name))
                .map(|h| h.value.as_str().to_string())
        };
        match header("Host") {
            Some(h) if self.hosts.iter().any(|a| a.eq_ignore_ascii_case(&h)) => {}
            Some(h) => return Some((403, format!("Host '{h}' is not this studio's address"))),
            None => return Some((400, "the request has no Host header".into())),
        }
        if let Some(o) = header("Origin") {
            let ok = o
                .strip_prefix("http://")
                .is_some_and(|h| self.hosts.iter().any(|a| a.eq_ignore_ascii_case(h)));
            if !ok {
                return Some((403, format!("Origin '{o}' is not this studio")));
            }
        }
        None
    }
}

/// An error answer: a status and a message for the page.
struct Refusal(u16, String);

impl From<crate::Error> for Refusal {
    fn from(e: crate::Error) -> Self {
        let status = match e {
            crate::Error::Config(_) => 400,
            _ => 422,
        };
        Refusal(status, e.to_string())
    }
}

type Answer = std::result::Result<Response<Box<dyn Read + Send>>, Refusal>;

/// Bytes shared with the payload, read without copying.
struct Shared(Arc<Vec<u8>>, usize);

impl Read for Shared {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let rest = &self.0[self.1.min(self.0.len())..];
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        self.1 += n;
        Ok(n)
    }
}

fn header(name: &str, value: &str) -> Header {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("a valid ASCII header")
}

fn bytes(data: Arc<Vec<u8>>, kind: &str) -> Answer {
    let len = data.len();
    body_of(Box::new(Shared(data, 0)), len, kind)
}

/// A 200 answer of `len` bytes read from `reader`.
fn body_of(reader: Box<dyn Read + Send>, len: usize, kind: &str) -> Answer {
    Ok(Response::new(
        StatusCode(200),
        vec![header("Content-Type", kind), header("Cache-Control", "no-store")],
        reader,
        Some(len),
        None,
    ))
}

fn json<T: Serialize>(value: &T) -> Answer {
    let text = serde_json::to_vec(value).map_err(|e| Refusal(500, e.to_string()))?;
    bytes(Arc::new(text), "application/json")
}

/// Answers one request (never panics on what a client sends).
pub(super) fn handle(studio: &Studio, guard: &Guard, mut req: Request) {
    let answer = match guard.refuse(&req) {
        Some((code, why)) => Err(Refusal(code, why)),
        None => route(studio, &mut req),
    };
    let response = answer.unwrap_or_else(|Refusal(code, why)| {
        let body = serde_json::json!({ "error": why }).to_string().into_bytes();
        let len = body.len();
        Response::new(
            StatusCode(code),
            vec![header("Content-Type", "application/json")],
            Box::new(std::io::Cursor::new(body)) as Box<dyn Read + Send>,
            Some(len),
            None,
        )
    });
    let _ = req.respond(response);
}

/// The body as `T`, at most [`MAX_BODY`] bytes.
fn body<T: for<'de> Deserialize<'de>>(req: &mut Request) -> std::result::Result<T, Refusal> {
    if req.body_length().is_some_and(|n| n > MAX_BODY) {
        return Err(Refusal(413, format!("the body is larger than {MAX_BODY} bytes")));
    }
    let mut data = Vec::new();
    req.as_reader()
        .take(MAX_BODY as u64 + 1)
        .read_to_end(&mut data)
        .map_err(|e| Refusal(400, format!("reading the body: {e}")))?;
    if data.len() > MAX_BODY {
        return Err(Refusal(413, format!("the body is larger than {MAX_BODY} bytes")));
    }
    serde_json::from_slice(&data).map_err(|e| Refusal(400, format!("the body is not the JSON expected: {e}")))
}

fn route(studio: &Studio, req: &mut Request) -> Answer {
    let path = req.url().split(['?', '#']).next().unwrap_or("").to_string();
    let page = |text: &'static str, kind: &str| bytes(Arc::new(text.as_bytes().to_vec()), kind);
    let payload = || studio.payload.read().unwrap_or_else(|p| p.into_inner()).clone();
    match (req.method(), path.as_str()) {
        (Method::Get, "/" | "/index.html") => page(PAGE, "text/html; charset=utf-8"),
        (Method::Get, "/studio.js") => page(SCRIPT, "text/javascript; charset=utf-8"),
        (Method::Get, "/api/scene") => {
            let p = payload();
            json(&serde_json::json!({
                "scene": p.info,
                "version": studio.version.load(Ordering::SeqCst),
                "samples": studio.sample_names(),
                "texel_size": studio.texel_size,
            }))
        }
        (Method::Get, "/api/mesh") => bytes(payload().mesh.clone(), "application/octet-stream"),
        (Method::Get, "/api/texels") => {
            let texels = payload().texels.clone();
            let file = texels.reader().map_err(|e| Refusal(500, e.to_string()))?;
            body_of(Box::new(file), texels.len(), "application/octet-stream")
        }
        (Method::Get, "/api/basis") => bytes(payload().basis.clone(), "application/octet-stream"),
        (Method::Get, "/api/status") => json(&studio.status_json()),
        (Method::Post, "/api/pick") => {
            let r: At = body(req)?;
            let (texel, point) = studio.pick(&studio.open_gim()?, r.uv)?;
            json(&serde_json::json!({ "texel": texel, "point": point }))
        }
        (Method::Post, "/api/paint") => {
            let r: PaintRequest = body(req)?;
            studio.paint(r)
        }
        (Method::Post, "/api/preview") => {
            let r: VerbatimRequest = body(req)?;
            studio.preview(r)
        }
        (Method::Post, "/api/verbatim") => {
            let r: VerbatimRequest = body(req)?;
            studio.verbatim(r)
        }
        (Method::Post, "/api/undo") => studio.step(-1),
        (Method::Post, "/api/redo") => studio.step(1),
        (Method::Post, "/api/save") => {
            let r: NameRequest = body(req)?;
            studio.save(&r.name)
        }
        (Method::Post, "/api/export") => {
            let r: NameRequest = body(req)?;
            studio.export(&r.name)
        }
        (_, "/" | "/index.html" | "/studio.js") => Err(Refusal(405, "use GET".into())),
        (_, p) if p.starts_with("/api/") => Err(Refusal(404, format!("no route {} {p}", req.method()))),
        (_, p) => Err(Refusal(404, format!("no page {p}"))),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct At {
    uv: [f64; 2],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StrokePoint {
    uv: [f64; 2],
    /// Geodesic radius in the mesh's units.
    radius: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PaintRequest {
    strokes: Vec<StrokePoint>,
    #[serde(default)]
    sample: usize,
    transition: Option<usize>,
    seed: Option<u64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct VerbatimRequest {
    uv: [f64; 2],
    #[serde(default)]
    angle: f64,
    #[serde(default)]
    sample: usize,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NameRequest {
    name: String,
}

/// A stroke point as the paint's strokes file takes it.
#[derive(Serialize)]
struct StrokeSpec {
    point: [f64; 3],
    radius: f64,
}

/// Most points one paint request may carry.
const MAX_STROKE_POINTS: usize = 4096;

impl Studio {
    fn sample_names(&self) -> Vec<String> {
        self.samples
            .iter()
            .map(|(s, _)| {
                s.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            })
            .collect()
    }

    fn status_json(&self) -> serde_json::Value {
        let h = lock(&self.history);
        serde_json::json!({
            "job": *lock(&self.status),
            "version": self.version.load(Ordering::SeqCst),
            "step": h.current,
            "steps": h.versions.len(),
            "can_undo": h.current > 0,
            "can_redo": h.current + 1 < h.versions.len(),
        })
    }

    /// The surface's geometry image, opened for [`Studio::pick`].
    fn open_gim(&self) -> crate::Result<Gim> {
        Gim::open(&self.gim, self.work_budget())
    }

    /// The covered texel at atlas position `uv` (0..1, v down) as the
    /// viewer draws it ([`nearest_covered`], within 3 texels) and its point
    /// on the dense mesh.
    fn pick(&self, gim: &Gim, uv: [f64; 2]) -> std::result::Result<(u32, [f32; 3]), Refusal> {
        if !uv.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)) {
            return Err(Refusal(
                400,
                format!("uv [{}, {}] must lie in 0..1", uv[0], uv[1]),
            ));
        }
        let r = gim.resolution;
        let (xa, ya) = ((uv[0] * r as f64 - 0.5) as f32, (uv[1] * r as f64 - 0.5) as f32);
        // the window nearest_covered searches: 3 rings round the texel under uv
        let centre = |a: f32| a.round().clamp(0.0, (r - 1) as f32) as usize;
        let (x0, y0) = (centre(xa).saturating_sub(3), centre(ya).saturating_sub(3));
        let (w, h) = ((centre(xa) + 4).min(r) - x0, (centre(ya) + 4).min(r) - y0);
        let region = gim.texel_region(x0, y0, w, h)?;
        let local = |t: usize| {
            let (x, y) = (t % r, t / r);
            (x >= x0 && y >= y0 && x < x0 + w && y < y0 + h).then(|| (y - y0) * w + x - x0)
        };
        let covered = |t: usize| local(t).is_some_and(|i| region.chart[i] != EMPTY);
        let (t, _, _) = nearest_covered(covered, r, xa, ya)
            .ok_or_else(|| Refusal(422, "no surface under that point".into()))?;
        let i = local(t).expect("a covered texel lies in the window");
        let p = &region.position[i * 3..i * 3 + 3];
        Ok((t as u32, [p[0], p[1], p[2]]))
    }

    fn sample(&self, k: usize) -> std::result::Result<&(PathBuf, Option<PathBuf>), Refusal> {
        self.samples.get(k).ok_or_else(|| {
            Refusal(
                400,
                format!("no sample {k}: the studio offers {}", self.samples.len()),
            )
        })
    }

    /// Runs `work` as the one change of the current version at a time,
    /// writing a new version; pushes it on the history and shows it.
    fn change(
        &self,
        what: &str,
        work: impl FnOnce(&std::path::Path, &std::path::Path, usize) -> crate::Result<String> + Send,
    ) -> Answer {
        let Ok(_busy) = self.painting.try_lock() else {
            return Err(Refusal(409, "a paint is running: wait for it".into()));
        };
        // the preview session's memory goes to the paint
        *lock(&self.preview) = None;
        let (current, n) = {
            let mut h = lock(&self.history);
            if h.versions.len() >= MAX_VERSIONS && h.current + 1 >= MAX_VERSIONS {
                return Err(Refusal(
                    409,
                    format!("{MAX_VERSIONS} versions: save and restart the studio"),
                ));
            }
            h.next += 1;
            (h.versions[h.current].clone(), h.next - 1)
        };
        *lock(&self.status) = JobStatus {
            running: true,
            stage: what.to_string(),
            ..JobStatus::default()
        };
        let start = Instant::now();
        let out = self.work_file(n, "quilt");
        let mut painted = 0.0;
        // on a thread of its own, one after the other: the allocator then
        // reuses one arena for every paint instead of keeping one per
        // request thread
        let result = std::thread::scope(|scope| {
            scope
                .spawn(|| {
                    work(&current, &out, n).and_then(|report| {
                        painted = start.elapsed().as_secs_f64();
                        self.show(&out)?;
                        Ok(report)
                    })
                })
                .join()
                .unwrap_or_else(|_| {
                    Err(crate::Error::Config(
                        "the paint stopped on an internal error".into(),
                    ))
                })
        });
        let mut status = lock(&self.status);
        status.running = false;
        status.seconds = start.elapsed().as_secs_f64();
        status.paint_seconds = painted;
        match result {
            Ok(report) => {
                status.error = None;
                drop(status);
                let mut h = lock(&self.history);
                let keep = h.current + 1;
                for old in h.versions.drain(keep..) {
                    let _ = std::fs::remove_file(old);
                }
                h.versions.push(out);
                h.current += 1;
                drop(h);
                json(&serde_json::json!({ "report": report, "status": self.status_json() }))
            }
            Err(e) => {
                status.error = Some(e.to_string());
                drop(status);
                let _ = std::fs::remove_file(&out);
                Err(e.into())
            }
        }
    }

    fn paint_config(&self, sample: usize, seed: Option<u64>) -> std::result::Result<PaintConfig, Refusal> {
        let (s, m) = self.sample(sample)?.clone();
        let defaults = TileConfig::default();
        Ok(PaintConfig {
            sample: Some(s),
            sample_mask: m,
            tile: TileConfig {
                seed: seed.unwrap_or(defaults.seed),
                memory: self.work_budget(),
                ..defaults
            },
            ..PaintConfig::default()
        })
    }

    fn paint(&self, r: PaintRequest) -> Answer {
        if r.strokes.is_empty() || r.strokes.len() > MAX_STROKE_POINTS {
            return Err(Refusal(
                400,
                format!("give 1..={MAX_STROKE_POINTS} stroke points"),
            ));
        }
        let gim = self.open_gim()?;
        let mut strokes = Vec::with_capacity(r.strokes.len());
        for (k, s) in r.strokes.iter().enumerate() {
            if !(s.radius.is_finite() && s.radius > 0.0) {
                return Err(Refusal(
                    400,
                    format!("stroke point {k}: radius {} must be > 0", s.radius),
                ));
            }
            let (_, p) = self.pick(&gim, s.uv)?;
            strokes.push(StrokeSpec {
                point: p.map(f64::from),
                radius: s.radius,
            });
        }
        let mut cfg = self.paint_config(r.sample, r.seed)?;
        if let Some(t) = r.transition {
            cfg.transition = t;
        }
        cfg.validate()?;
        self.change("paint", |current, out, _| {
            cfg.region = Some(self.stroke_file(&strokes)?);
            Ok(crate::paint::paint(current, out, &cfg, &JobProgress(&self.status))?.to_string())
        })
    }

    /// The strokes as a file beside the base, named by its content
    /// (`STEM.stroke-HASH.json`): painted quilts' paint logs refer to it, so
    /// it stays when the studio stops, and the same stroke gives the same
    /// log, hence the same bytes.
    fn stroke_file(&self, strokes: &[StrokeSpec]) -> crate::Result<PathBuf> {
        let text = serde_json::to_vec(strokes).map_err(|e| crate::Error::Config(e.to_string()))?;
        let hash = xxhash_rust::xxh3::xxh3_64(&text);
        let file = self.folder.join(format!("{}.stroke-{hash:016x}.json", self.stem));
        if std::fs::read(&file).is_ok_and(|old| old == text) {
            return Ok(file);
        }
        let mut staged = crate::io::staging::staged_file(&file)?;
        staged.write_all(&text).map_err(|e| crate::Error::io(&file, e))?;
        staged
            .persist(&file)
            .map_err(|e| crate::Error::io(&file, e.error))?;
        Ok(file)
    }

    fn verbatim_config(&self, r: &VerbatimRequest) -> std::result::Result<(PaintConfig, Verbatim), Refusal> {
        if !r.angle.is_finite() {
            return Err(Refusal(
                400,
                "the angle must be a finite number of degrees".into(),
            ));
        }
        let (_, at) = self.pick(&self.open_gim()?, r.uv)?;
        let v = Verbatim { at, angle: r.angle };
        let mut cfg = self.paint_config(r.sample, None)?;
        cfg.verbatim = Some(v);
        cfg.validate()?;
        Ok((cfg, v))
    }

    fn verbatim(&self, r: VerbatimRequest) -> Answer {
        let (cfg, _) = self.verbatim_config(&r)?;
        self.change("verbatim", |current, out, _| {
            Ok(crate::paint::paint(current, out, &cfg, &JobProgress(&self.status))?.to_string())
        })
    }

    /// The verbatim projection as `x0, y0, w, h` (u32) then w·h RGBA8
    /// (sRGB; alpha 0 off the surface).
    fn preview(&self, r: VerbatimRequest) -> Answer {
        let (cfg, v) = self.verbatim_config(&r)?;
        let Ok(_busy) = self.painting.try_lock() else {
            return Err(Refusal(
                409,
                "a paint is running: no preview until it ends".into(),
            ));
        };
        let current = self.current();
        let mut slot = lock(&self.preview);
        let fresh = !matches!(&*slot, Some((p, k, _)) if *p == current && *k == r.sample);
        if fresh {
            *slot = None;
            let session = crate::paint::PreviewSession::open(&current, &cfg, &crate::progress::Silent)?;
            *slot = Some((current, r.sample, session));
        }
        let (_, _, session) = slot.as_mut().expect("just opened");
        let (_, p) = session.project(v, &crate::progress::Silent)?;
        let mut out = Vec::with_capacity(16 + p.covered.len() * 4);
        for v in [p.x0, p.y0, p.image.width, p.image.height] {
            out.extend_from_slice(&(v as u32).to_le_bytes());
        }
        for (c, &cov) in p.image.data.chunks_exact(3).zip(&p.covered) {
            if cov {
                out.extend(c.iter().map(|&v| crate::io::imageio::linear_to_srgb8(v)));
                out.push(255);
            } else {
                out.extend([0, 0, 0, 0]);
            }
        }
        bytes(Arc::new(out), "application/octet-stream")
    }

    /// Undo (−1) or redo (+1).
    fn step(&self, by: isize) -> Answer {
        let Ok(_busy) = self.painting.try_lock() else {
            return Err(Refusal(409, "a paint is running: wait for it".into()));
        };
        let target = {
            let h = lock(&self.history);
            let t = h.current as isize + by;
            if t < 0 || t as usize >= h.versions.len() {
                return Err(Refusal(
                    409,
                    format!("nothing to {}", if by < 0 { "undo" } else { "redo" }),
                ));
            }
            t as usize
        };
        let path = lock(&self.history).versions[target].clone();
        self.show(&path)?;
        lock(&self.history).current = target;
        json(&self.status_json())
    }

    /// A plain file name for an output beside the base.
    fn output_name(&self, name: &str, ext: &str) -> std::result::Result<PathBuf, Refusal> {
        let ok = !name.is_empty()
            && name.len() <= 100
            && !name.starts_with('.')
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
        if !ok {
            return Err(Refusal(
                400,
                format!("name '{name}': use 1-100 letters, digits, '.', '_' or '-', not starting with '.'"),
            ));
        }
        let stem = name.strip_suffix(ext).unwrap_or(name);
        Ok(self.folder.join(format!("{stem}{ext}")))
    }

    /// Saves the current version as `NAME.quilt` beside the base (never over
    /// the base or an existing file).
    fn save(&self, name: &str) -> Answer {
        let out = self.output_name(name, ".quilt")?;
        if crate::io::staging::same_file(&out, &self.base) || out.exists() {
            return Err(Refusal(
                409,
                format!("{} exists: choose another name", out.display()),
            ));
        }
        let current = self.current();
        let staged = crate::io::staging::staged_file(&out)?;
        std::fs::copy(&current, staged.path()).map_err(|e| crate::Error::io(&current, e))?;
        staged
            .persist_noclobber(&out)
            .map_err(|e| crate::Error::io(&out, e.error))?;
        json(&serde_json::json!({ "saved": out }))
    }

    /// Exports the current version as glTF into the folder `NAME` beside the
    /// base.
    fn export(&self, name: &str) -> Answer {
        let dir = self.output_name(name, "")?;
        if dir.exists() {
            return Err(Refusal(
                409,
                format!("{} exists: choose another name", dir.display()),
            ));
        }
        let opts = crate::output::export::ExportOptions {
            mesh: Some((crate::output::export::MeshFormat::Gltf, dir)),
            budget: self.work_budget(),
            ..Default::default()
        };
        let written = crate::output::export::export(&self.current(), &opts)?;
        json(&serde_json::json!({ "written": written }))
    }
}
