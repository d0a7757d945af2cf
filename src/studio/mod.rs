//! `serve`: a local web studio for a decorated surface. The page (embedded
//! in the binary) draws the surface in WebGL2 exactly as `render` shades it
//! (the baked colour, or a BTF relit in real time from its factorization,
//! Σ g_i p_i per pixel), paints on it with a brush (the constrained
//! graphcut of §IV), previews and merges verbatim copies (§IV's fast
//! preview), walks the paint log back and forth, saves a `.quilt` and
//! exports glTF.
//!
//! The server binds 127.0.0.1 unless told otherwise and answers only
//! requests whose `Host` (and `Origin`, when sent) name the address it
//! listens on, so a page elsewhere cannot reach it through DNS rebinding. It
//! serves its own page and the current surface's data, nothing from disk by
//! name; bodies are bounded ([`MAX_BODY`]). `--memory` is shared out: a
//! quarter for opening a version for the viewer, the rest, less the
//! viewer's mesh and factorization it holds, for painting or the preview
//! session, which never run at once. The viewer's per-texel data (32 bytes
//! an atlas texel for a BTF, 16 for colour) is kept in a hidden file beside
//! the base, `.STEM.studio-PID-texels-….texels`, one per version shown and
//! removed when another is shown. Every painted version is a
//! `.quilt` beside the base (hidden, removed when the studio stops, and by
//! the next studio on that base if the process died); the base is never
//! written. A brush stroke is kept beside the base as
//! `STEM.stroke-HASH.json`: the paint log of every quilt painted with it
//! refers to it, as to any region file.

mod api;
pub mod scene;

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::thread::JoinHandle;

use crate::container::MemoryBudget;
use crate::lock;
use crate::progress::Progress;
use crate::quilt::Quilt;
use crate::{Error, Result};

pub use scene::Payload;

/// Largest request body accepted (a stroke list of some ten thousand
/// points).
pub const MAX_BODY: usize = 1 << 20;
/// Most paint-log versions kept (undo depth).
pub const MAX_VERSIONS: usize = 256;

/// Options of [`Studio::start`].
#[derive(Clone, Debug)]
pub struct ServeConfig {
    /// Address to bind; loopback by default.
    pub bind: IpAddr,
    /// Port; 0 picks a free one.
    pub port: u16,
    /// Threads answering requests.
    pub workers: usize,
    /// Memory for opening the surface and painting.
    pub memory: MemoryBudget,
    /// Further samples offered for painting, each with its foreground mask.
    pub samples: Vec<(PathBuf, Option<PathBuf>)>,
}

impl Default for ServeConfig {
    fn default() -> Self {
        ServeConfig {
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 7878,
            workers: 4,
            memory: MemoryBudget::default(),
            samples: Vec::new(),
        }
    }
}

impl ServeConfig {
    /// Checks the numbers and that every offered sample and mask exists.
    pub fn validate(&self) -> Result<()> {
        if !(1..=64).contains(&self.workers) {
            return Err(Error::Config(format!(
                "--workers {}: expected 1..=64",
                self.workers
            )));
        }
        for (s, m) in &self.samples {
            for p in std::iter::once(s).chain(m) {
                if !p.is_file() {
                    return Err(Error::input(p, "does not exist or is not a file"));
                }
            }
        }
        Ok(())
    }
}

/// Where a paint run is, for `GET /api/status`.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct JobStatus {
    pub running: bool,
    pub stage: String,
    pub done: u64,
    pub total: u64,
    pub note: String,
    /// The last paint's error, if it failed.
    pub error: Option<String>,
    /// The last change's time in the server: all of it, and the paint
    /// alone (the rest rebuilds the viewer's data).
    pub seconds: f64,
    pub paint_seconds: f64,
}

/// What opening a version for the viewer may use: a quarter of `--memory`
/// (the rest is for painting; see `Studio::work_budget`).
fn scene_budget(memory: MemoryBudget) -> MemoryBudget {
    let [scene, _] = memory.split([1, 3]);
    scene
}

/// A new file for a version's viewer texels ([`scene::TexelFile`]) beside
/// the base, `.STEM.studio-PID-texels-RANDOM.texels`: removed when the
/// version is no longer shown, and as a work file of a process that is gone.
/// In the system's temporary folder when the base's cannot be written (a
/// surface only viewed).
fn texel_file(folder: &Path, stem: &str) -> Result<tempfile::NamedTempFile> {
    let mut builder = tempfile::Builder::new();
    let prefix = format!(".{stem}.studio-{}-texels-", std::process::id());
    builder.prefix(&prefix).suffix(".texels");
    builder
        .tempfile_in(folder)
        .or_else(|e| builder.tempfile().map_err(|_| Error::io(folder, e)))
}

/// A [`Progress`] that keeps the last stage and count for the page.
struct JobProgress<'a>(&'a Mutex<JobStatus>);

impl Progress for JobProgress<'_> {
    fn begin(&self, stage: &str, total: u64) {
        let mut s = lock(self.0);
        s.stage = stage.to_string();
        s.total = total;
        s.done = 0;
    }
    fn advance(&self, n: u64) {
        lock(self.0).done += n;
    }
    fn note(&self, line: &str) {
        lock(self.0).note = line.to_string();
    }
}

/// The paint log as the studio walks it: the base, then each painted
/// version; `current` indexes it.
struct History {
    versions: Vec<PathBuf>,
    current: usize,
    /// Counter for work-file names (never reused within a run).
    next: usize,
}

/// The studio's state, shared by the request threads.
pub struct Studio {
    base: PathBuf,
    folder: PathBuf,
    stem: String,
    cfg: ServeConfig,
    history: Mutex<History>,
    payload: RwLock<Arc<Payload>>,
    /// Bumped whenever the current version changes.
    version: std::sync::atomic::AtomicU64,
    status: Mutex<JobStatus>,
    /// Held while a paint (or undo/redo) changes the current version.
    painting: Mutex<()>,
    preview: Mutex<Option<(PathBuf, usize, crate::paint::PreviewSession)>>,
    /// (sample, mask) per paintable sample: the quilt's own, then the
    /// configured ones.
    samples: Vec<(PathBuf, Option<PathBuf>)>,
    gim: PathBuf,
    texel_size: f64,
}

/// A running studio: its address, and the handle to stop it.
pub struct Server {
    addr: SocketAddr,
    studio: Arc<Studio>,
    http: Arc<tiny_http::Server>,
    stop: Arc<AtomicBool>,
    workers: Vec<JoinHandle<()>>,
}

impl Server {
    /// The address the studio listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The studio's page.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// The current version of the surface (a `.quilt`).
    pub fn current(&self) -> PathBuf {
        self.studio.current()
    }

    /// A handle that stops the studio from another thread (the one that
    /// waits for a signal in `btfquilt serve`).
    pub fn stop_handle(&self) -> StopHandle {
        StopHandle {
            http: self.http.clone(),
            stop: self.stop.clone(),
            workers: self.workers.len(),
        }
    }

    /// Answers requests until a [`StopHandle`] stops the studio (or the
    /// process ends), then removes the work files.
    pub fn wait(mut self) {
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
        // (dropped here: the work files go)
    }

    /// Stops answering, waits for the request threads and removes the work
    /// files.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop_handle().stop();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
        self.studio.remove_work_files(std::process::id());
    }
}

/// Stops a running studio: its request threads finish the request they
/// are answering and end, and [`Server::wait`] returns.
#[derive(Clone)]
pub struct StopHandle {
    http: Arc<tiny_http::Server>,
    stop: Arc<AtomicBool>,
    workers: usize,
}

impl StopHandle {
    pub fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
        for _ in 0..self.workers {
            self.http.unblock();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
    }
}

impl Studio {
    /// Opens `quilt` and starts answering on `cfg.bind:cfg.port`.
    pub fn start(quilt: &Path, cfg: &ServeConfig) -> Result<Server> {
        cfg.validate()?;
        let q = Quilt::open(quilt, cfg.memory)?;
        let gim = q.open_gim(None, cfg.memory)?;
        let mut samples: Vec<(PathBuf, Option<PathBuf>)> = q
            .samples
            .iter()
            .enumerate()
            .map(|(k, s)| {
                (
                    s.clone(),
                    (k + 1 == q.samples.len())
                        .then(|| q.sample_mask.clone())
                        .flatten(),
                )
            })
            .collect();
        samples.extend(cfg.samples.iter().cloned());
        let folder = crate::io::staging::parent_dir(quilt).to_path_buf();
        let stem = quilt
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "surface".into());
        let payload = Payload::build(quilt, scene_budget(cfg.memory), texel_file(&folder, &stem)?)?;
        let studio = Arc::new(Studio {
            base: quilt.to_path_buf(),
            folder,
            stem,
            cfg: cfg.clone(),
            history: Mutex::new(History {
                versions: vec![quilt.to_path_buf()],
                current: 0,
                next: 1,
            }),
            payload: RwLock::new(Arc::new(payload)),
            version: Default::default(),
            status: Mutex::new(JobStatus::default()),
            painting: Mutex::new(()),
            preview: Mutex::new(None),
            samples,
            gim: gim.container().path().to_path_buf(),
            texel_size: gim.texel_size,
        });
        studio.remove_stale_work_files();
        let http = tiny_http::Server::http(SocketAddr::new(cfg.bind, cfg.port))
            .map_err(|e| Error::Config(format!("cannot listen on {}:{}: {e}", cfg.bind, cfg.port)))?;
        let addr = http
            .server_addr()
            .to_ip()
            .ok_or_else(|| Error::Config("the studio's socket has no IP address".into()))?;
        let http = Arc::new(http);
        let stop = Arc::new(AtomicBool::new(false));
        let guard = Arc::new(api::Guard::new(addr));
        let workers = (0..cfg.workers)
            .map(|_| {
                let (http, stop, studio, guard) = (http.clone(), stop.clone(), studio.clone(), guard.clone());
                std::thread::spawn(move || {
                    while let Ok(req) = http.recv() {
                        if stop.load(Ordering::SeqCst) {
                            let _ = req.respond(tiny_http::Response::empty(503));
                            break;
                        }
                        // a bug in one handler must not take the studio down:
                        // the request is answered 500 and the thread goes on
                        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                            api::handle(&studio, &guard, req)
                        }));
                    }
                })
            })
            .collect();
        Ok(Server {
            addr,
            studio,
            http,
            stop,
            workers,
        })
    }

    fn current(&self) -> PathBuf {
        let h = lock(&self.history);
        h.versions[h.current].clone()
    }

    /// A work file's name for this process: `.STEM.studio-PID-N.EXT` (and
    /// the viewer's texels: [`texel_file`]).
    fn work_file(&self, n: usize, ext: &str) -> PathBuf {
        self.folder
            .join(format!(".{}.studio-{}-{n}.{ext}", self.stem, std::process::id()))
    }

    /// Removes this base's work files of process `pid`.
    fn remove_work_files(&self, pid: u32) {
        let prefix = format!(".{}.studio-{pid}-", self.stem);
        self.remove_matching(|name| name.starts_with(&prefix));
    }

    /// Removes the work files of studios on this base whose process is
    /// gone (where the system tells: [`crate::io::staging::process_alive`]).
    fn remove_stale_work_files(&self) {
        let prefix = format!(".{}.studio-", self.stem);
        self.remove_matching(|name| {
            let Some(rest) = name.strip_prefix(&prefix) else {
                return false;
            };
            let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
            pid.is_some_and(|p| {
                p != std::process::id() && crate::io::staging::process_alive(p) == Some(false)
            })
        });
    }

    fn remove_matching(&self, doomed: impl Fn(&str) -> bool) {
        let Ok(entries) = std::fs::read_dir(&self.folder) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if (name.ends_with(".quilt") || name.ends_with(".texels")) && doomed(&name) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// What a paint, a preview session or an export may use: three
    /// quarters of `--memory`, less twice the viewer's data held in memory
    /// (the current version's and, while it is rebuilt, the next one's; its
    /// texels are in a file), but at least an eighth.
    fn work_budget(&self) -> MemoryBudget {
        let total = self.cfg.memory.bytes();
        let held = {
            let p = self.payload.read().unwrap_or_else(|p| p.into_inner());
            (p.mesh.len() + p.basis.len()) as u64
        };
        MemoryBudget((total / 4 * 3).saturating_sub(2 * held).max(total / 8))
    }

    /// Makes `path` (a version in the history) current and rebuilds the
    /// viewer's data.
    fn show(&self, path: &Path) -> Result<()> {
        let file = texel_file(&self.folder, &self.stem)?;
        let payload = Payload::build(path, scene_budget(self.cfg.memory), file)?;
        *self.payload.write().unwrap_or_else(|p| p.into_inner()) = Arc::new(payload);
        self.version.fetch_add(1, Ordering::SeqCst);
        Ok(())
    }
}
