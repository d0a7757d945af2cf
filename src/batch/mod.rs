//! `btfquilt batch PLAN -o OUT`: content-addressed batch jobs for dataset
//! generation.
//!
//! A plan ([`plan`]) expands into jobs, one decorated surface each. The
//! output folder holds:
//!
//! | path | what |
//! |---|---|
//! | `inputs/HASH-BYTES.EXT` | a copy of each input, named by its content hash and length |
//! | `shared/atlas-KEY.gim` | one geometry image per mesh and resolution |
//! | `shared/sample-KEY.svd` | one factorization per sample |
//! | `jobs/KEY/` | a job's outputs and its `job.json` |
//! | `manifest.jsonl` | a line per job run or skipped: inputs, hashes, timings, outputs |
//!
//! Every artifact refers to the copies in `inputs/` and `shared/` by paths
//! relative to itself, so the folder's bytes depend only on the plan's
//! content, never on where its inputs or the folder lie; the folder can be
//! moved or merged with another run's. A job folder is built under a
//! hidden name, `job.json` last, and renamed into place when complete, so a
//! job whose folder holds `job.json` is finished and skipped, and a run
//! killed part-way leaves only a hidden partial folder, removed by the next
//! run. Shared artifacts are staged the same way; two processes that make
//! the same one write the same bytes.
//!
//! [`Shard`] splits the jobs (or, with [`Stages::Shared`], the shared
//! stages) into deterministic contiguous parts, so N processes or machines
//! given `--shard 0/N` … `--shard N-1/N` together run every job exactly
//! once and never write the same job folder.

pub mod plan;

use std::collections::HashMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde::Serialize;

pub use plan::{Job, Key, Plan, Shard, SharedStage};

use crate::atlas::{self, AtlasConfig};
use crate::container::MemoryBudget;
use crate::factorize::{self, FactorizeConfig};
use crate::io::staging::{self, StagedDir};
use crate::output::export::{self, ExportOptions, MeshFormat};
use crate::output::{bake, render};
use crate::progress::Progress;
use crate::quilt;
use crate::{lock, Error, Result};

/// The name of a job's decorated surface in its folder.
pub const QUILT: &str = "decorated.quilt";
/// The job's description, written last into its folder.
pub const JOB_JSON: &str = "job.json";

/// Which stages [`run`] runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Stages {
    /// The shard's jobs, with the shared artifacts they need.
    #[default]
    All,
    /// Only the shard's part of the shared stages (geometry images and
    /// factorizations), for a cluster to make them once before the jobs.
    Shared,
}

/// Options of [`run`].
#[derive(Clone, Debug)]
pub struct BatchConfig {
    pub shard: Shard,
    /// Run only these jobs (all of them must be in the plan).
    pub jobs: Vec<Key>,
    pub stages: Stages,
    /// Where the manifest lines go (default `OUT/manifest.jsonl`).
    pub manifest: Option<PathBuf>,
    /// The budget of the whole run, shared evenly by the workers.
    pub memory: MemoryBudget,
    /// Jobs run at once, each on a thread of its own (its stages use the
    /// thread pool too). The quilting loop runs on one core, so on a
    /// machine of C cores C workers finish about C times as many jobs a
    /// minute as one; outputs are the same bytes for any number.
    pub workers: usize,
}

impl Default for BatchConfig {
    fn default() -> Self {
        BatchConfig {
            shard: Shard::ALL,
            jobs: Vec::new(),
            stages: Stages::All,
            manifest: None,
            memory: MemoryBudget::default(),
            workers: 1,
        }
    }
}

/// What [`run`] did.
#[derive(Clone, Debug, Default)]
pub struct BatchReport {
    pub done: usize,
    pub skipped: usize,
    pub failed: Vec<(Key, String)>,
    /// Shared artifacts made by this run.
    pub shared_made: usize,
    pub seconds: f64,
}

impl std::fmt::Display for BatchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} jobs done, {} already done, {} failed, {} shared artifacts made, {:.1} s",
            self.done,
            self.skipped,
            self.failed.len(),
            self.shared_made,
            self.seconds
        )
    }
}

/// A job's state in the output folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JobStatus {
    Done,
    Todo,
}

/// The jobs [`run`] would take with `cfg`, each with whether its folder
/// under `out` is complete.
pub fn selected_jobs(plan: &Plan, out: &Path, cfg: &BatchConfig) -> Result<Vec<(Job, JobStatus)>> {
    let all = plan.jobs();
    let chosen: Vec<Job> = if cfg.jobs.is_empty() {
        all[cfg.shard.range(all.len())].to_vec()
    } else {
        let mut by_key: HashMap<Key, &Job> = all.iter().map(|j| (j.key, j)).collect();
        cfg.jobs
            .iter()
            .map(|k| {
                by_key.remove(k).cloned().ok_or_else(|| {
                    Error::input(&plan.path, format!("has no job {k} (or it was named twice)"))
                })
            })
            .collect::<Result<_>>()?
    };
    Ok(chosen
        .into_iter()
        .map(|j| {
            let status = if job_done(out, &j) {
                JobStatus::Done
            } else {
                JobStatus::Todo
            };
            (j, status)
        })
        .collect())
}

/// Whether a job is finished: its folder holds its `job.json`, written last
/// inside the staged folder that was renamed into place whole.
pub fn job_done(out: &Path, job: &Job) -> bool {
    out.join(job.dir()).join(JOB_JSON).is_file()
}

/// Whether a shared artifact is complete: it opens as a container (whose
/// header promises its length).
fn shared_done(out: &Path, stage: &SharedStage) -> bool {
    let path = out.join(stage.file());
    path.is_file() && crate::container::Container::open(&path, MemoryBudget(1 << 20)).is_ok()
}

/// The shared stages `--stages shared` would take with `cfg`'s shard, each
/// with whether its artifact under `out` exists.
pub fn selected_shared(plan: &Plan, out: &Path, cfg: &BatchConfig) -> Vec<(SharedStage, JobStatus)> {
    let stages = plan.shared_stages();
    stages[cfg.shard.range(stages.len())]
        .iter()
        .map(|s| {
            let status = if shared_done(out, s) {
                JobStatus::Done
            } else {
                JobStatus::Todo
            };
            (s.clone(), status)
        })
        .collect()
}

/// Runs the plan's jobs selected by `cfg` into the folder `out`. A job that
/// fails is reported (and in the manifest) and the others go on; an error
/// is returned only when the batch cannot run at all.
pub fn run(plan: &Plan, out: &Path, cfg: &BatchConfig, progress: &dyn Progress) -> Result<BatchReport> {
    let start = Instant::now();
    let inputs = input_paths(plan);
    let out_resolved = resolved(out);
    for &(role, p) in &inputs {
        if resolved(p).starts_with(&out_resolved) {
            return Err(Error::input(
                out,
                format!(
                    "holds the plan's {role} {}: give an output folder apart from the inputs",
                    p.display()
                ),
            ));
        }
    }
    let manifest_path = cfg.manifest.clone().unwrap_or_else(|| out.join("manifest.jsonl"));
    crate::io::staging::check_output(&manifest_path, &inputs)?;
    if out.exists() && !out.is_dir() {
        return Err(Error::input(
            out,
            "exists and is not a folder: give a folder for the batch's outputs",
        ));
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let workers = cfg.workers.max(1);
    let runner = Runner {
        plan,
        out,
        cfg,
        progress,
        budget: MemoryBudget(cfg.memory.0 / workers as u64),
        failed_shared: Mutex::new(HashMap::new()),
        shared_locks: Mutex::new(HashMap::new()),
        manifest: Mutex::new(Manifest::open(&manifest_path)?),
        report: Mutex::new(BatchReport::default()),
    };
    match cfg.stages {
        Stages::Shared => {
            let mine: Vec<SharedStage> = selected_shared(plan, out, cfg)
                .into_iter()
                .map(|(s, _)| s)
                .collect();
            for (i, stage) in mine.iter().enumerate() {
                progress.note(&format!("shared {}/{}: {}", i + 1, mine.len(), stage.file()));
                let lap = Instant::now();
                let result = runner.shared(stage);
                let seconds = lap.elapsed().as_secs_f64();
                let (status, error) = match &result {
                    Ok(true) => ("done", None),
                    Ok(false) => ("skipped", None),
                    Err(e) => ("failed", Some(e.to_string())),
                };
                runner.record_shared(stage, status, seconds, error.as_deref())?;
                if let Some(e) = error {
                    lock(&runner.report).failed.push((stage.key(), e));
                }
            }
        }
        Stages::All => {
            let jobs = selected_jobs(plan, out, cfg)?;
            // workers take the jobs in order; each job's bytes depend on it alone
            let next = std::sync::atomic::AtomicUsize::new(0);
            let results: Vec<Result<()>> = std::thread::scope(|scope| {
                let handles: Vec<_> = (0..workers.min(jobs.len()).max(1))
                    .map(|_| {
                        scope.spawn(|| -> Result<()> {
                            loop {
                                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                                let Some((job, status)) = jobs.get(i) else {
                                    return Ok(());
                                };
                                runner.take(i, jobs.len(), job, *status)?;
                            }
                        })
                    })
                    .collect();
                handles
                    .into_iter()
                    .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
                    .collect()
            });
            results.into_iter().collect::<Result<()>>()?;
        }
    }
    let mut report = runner.report.into_inner().unwrap_or_else(|e| e.into_inner());
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

/// `path` made absolute with links resolved, as far as it exists (the rest
/// appended as given), for comparing where things lie.
fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(c) = std::fs::canonicalize(existing) {
            let mut p = c;
            p.extend(rest.iter().rev());
            return p;
        }
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                existing = parent;
            }
            _ => return absolute,
        }
    }
}

/// Every input file of the plan with its role.
fn input_paths(plan: &Plan) -> Vec<(&'static str, &Path)> {
    let mut v: Vec<(&'static str, &Path)> = plan.meshes.iter().map(|m| ("mesh", m.path.as_path())).collect();
    for s in &plan.samples {
        v.push(("sample", &s.input.path));
        if let Some(m) = &s.mask {
            v.push(("mask", &m.path));
        }
    }
    v.push(("plan", &plan.path));
    v
}

/// Seconds spent per stage on one job.
#[derive(Clone, Debug, Default, Serialize)]
struct Timings {
    /// Shared artifacts this job had to make (0 when another job had).
    shared: f64,
    tile: f64,
    bake: f64,
    render: f64,
    export: f64,
    total: f64,
}

/// A manifest: JSON lines appended with one write each, so processes
/// sharing it on one machine do not interleave their lines.
struct Manifest {
    path: PathBuf,
    file: std::fs::File,
}

impl Manifest {
    fn open(path: &Path) -> Result<Manifest> {
        std::fs::create_dir_all(staging::parent_dir(path)).map_err(|e| Error::io(path, e))?;
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        Ok(Manifest {
            path: path.to_path_buf(),
            file,
        })
    }

    fn append<T: Serialize>(&mut self, line: &T) -> Result<()> {
        let mut text = serde_json::to_vec(line).map_err(|e| Error::io(&self.path, e.into()))?;
        text.push(b'\n');
        self.file.write_all(&text).map_err(|e| Error::io(&self.path, e))
    }
}

/// An input as the manifest records it: where it was read from and what it is.
#[derive(Serialize)]
struct ManifestInput<'a> {
    path: String,
    #[serde(flatten)]
    id: &'a plan::InputId,
}

/// An output file of a job.
#[derive(Serialize)]
struct ManifestOutput {
    file: String,
    bytes: u64,
}

#[derive(Serialize)]
struct ManifestLine<'a> {
    job: Key,
    status: &'a str,
    folder: String,
    shard: String,
    host: String,
    pid: u32,
    mesh: ManifestInput<'a>,
    sample: ManifestInput<'a>,
    mask: Option<ManifestInput<'a>>,
    resolution: usize,
    seed: u64,
    sample_width: Option<f64>,
    seconds: &'a Timings,
    outputs: Vec<ManifestOutput>,
    error: Option<&'a str>,
}

/// Files under `dir` (relative, sorted) with their sizes.
fn files_under(dir: &Path) -> Vec<ManifestOutput> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<ManifestOutput>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else if let Ok(m) = e.metadata() {
                let rel = p.strip_prefix(root).unwrap_or(&p);
                out.push(ManifestOutput {
                    file: rel.to_string_lossy().replace('\\', "/"),
                    bytes: m.len(),
                });
            }
        }
    }
    let mut v = Vec::new();
    walk(dir, dir, &mut v);
    v.sort_by(|a, b| a.file.cmp(&b.file));
    v
}

/// An error about the copy `copy` of a plan's input, told of the input
/// itself (the file the user named), with the copy in parentheses.
fn naming_the_input(e: Error, copy: &Path, input: &plan::Input) -> Error {
    let text = e.to_string();
    match text.strip_prefix(&format!("{}: ", copy.display())) {
        Some(reason) => Error::input(&input.path, format!("{reason} (in its copy {})", copy.display())),
        None => e,
    }
}

/// An input's manifest entry.
fn input(i: &plan::Input) -> ManifestInput<'_> {
    ManifestInput {
        path: i.path.display().to_string(),
        id: &i.id,
    }
}

/// How a job ended.
enum JobRun {
    Done,
    /// Another process committed the same job first; this one's copy was
    /// dropped.
    DoneElsewhere,
}

/// What [`run`]'s workers share.
struct Runner<'a> {
    plan: &'a Plan,
    out: &'a Path,
    cfg: &'a BatchConfig,
    progress: &'a dyn Progress,
    /// Each worker's share of `--memory`.
    budget: MemoryBudget,
    /// Shared stages that failed in this run, with their error (not tried again).
    failed_shared: Mutex<HashMap<Key, String>>,
    /// One lock per shared artifact: one worker makes it, the others wait.
    shared_locks: Mutex<HashMap<Key, Arc<Mutex<()>>>>,
    manifest: Mutex<Manifest>,
    report: Mutex<BatchReport>,
}

impl Runner<'_> {
    /// Takes job `i` of `n`: skips it if done, else runs it; records it.
    fn take(&self, i: usize, n: usize, job: &Job, status: JobStatus) -> Result<()> {
        let what = format!("job {}/{n} {} ({})", i + 1, job.key, job.describe(self.plan));
        if status == JobStatus::Done {
            self.progress.note(&format!("{what}: already done"));
            lock(&self.report).skipped += 1;
            return self.record(job, "skipped", &Timings::default(), None);
        }
        let mut t = Timings::default();
        let start = Instant::now();
        let result = self.job(job, &mut t);
        t.total = start.elapsed().as_secs_f64();
        match result {
            Ok(JobRun::Done) => {
                self.progress.note(&format!("{what}: done in {:.1} s", t.total));
                lock(&self.report).done += 1;
                self.record(job, "done", &t, None)
            }
            Ok(JobRun::DoneElsewhere) => {
                self.progress
                    .note(&format!("{what}: done meanwhile by another process"));
                lock(&self.report).skipped += 1;
                self.record(job, "skipped", &t, None)
            }
            Err(e) => {
                self.progress.note(&format!("{what}: failed: {e}"));
                let msg = e.to_string();
                self.record(job, "failed", &t, Some(&msg))?;
                lock(&self.report).failed.push((job.key, msg));
                Ok(())
            }
        }
    }

    fn record(&self, job: &Job, status: &str, t: &Timings, error: Option<&str>) -> Result<()> {
        let plan = self.plan;
        let sample = &plan.samples[job.sample];
        let folder = self.out.join(job.dir());
        let outputs = if status == "failed" {
            Vec::new()
        } else {
            files_under(&folder)
        };
        let line = ManifestLine {
            job: job.key,
            status,
            folder: job.dir(),
            shard: self.cfg.shard.to_string(),
            host: staging::host_name().unwrap_or_default(),
            pid: std::process::id(),
            mesh: input(&plan.meshes[job.mesh]),
            sample: input(&sample.input),
            mask: sample.mask.as_ref().map(input),
            resolution: job.resolution,
            seed: job.seed,
            sample_width: job.sample_width,
            seconds: t,
            outputs,
            error,
        };
        lock(&self.manifest).append(&line)
    }

    fn record_shared(
        &self,
        stage: &SharedStage,
        status: &str,
        seconds: f64,
        error: Option<&str>,
    ) -> Result<()> {
        #[derive(Serialize)]
        struct SharedLine<'a> {
            shared: Key,
            status: &'a str,
            file: String,
            shard: String,
            host: String,
            pid: u32,
            input: ManifestInput<'a>,
            resolution: Option<usize>,
            seconds: f64,
            bytes: Option<u64>,
            error: Option<&'a str>,
        }
        let (source, resolution) = match *stage {
            SharedStage::Atlas { mesh, resolution, .. } => (&self.plan.meshes[mesh], Some(resolution)),
            SharedStage::Factorize { sample, .. } => (&self.plan.samples[sample].input, None),
        };
        let line = SharedLine {
            shared: stage.key(),
            status,
            file: stage.file(),
            shard: self.cfg.shard.to_string(),
            host: staging::host_name().unwrap_or_default(),
            pid: std::process::id(),
            input: input(source),
            resolution,
            seconds,
            bytes: std::fs::metadata(self.out.join(stage.file()))
                .ok()
                .map(|m| m.len()),
            error,
        };
        lock(&self.manifest).append(&line)
    }

    /// Copies an input into `inputs/` under its content name, unless there.
    fn stage_input(&self, input: &plan::Input) -> Result<PathBuf> {
        let dest = self.out.join(&input.id.file);
        let present = std::fs::metadata(&dest).is_ok_and(|m| m.len() == input.id.bytes);
        if !present {
            let dir = staging::parent_dir(&dest);
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            let tmp = staging::staged_file(&dest)?;
            std::fs::copy(&input.path, tmp.path()).map_err(|e| Error::io(&input.path, e))?;
            let (bytes, hash) = crate::container::file_identity(tmp.path())?;
            if bytes != input.id.bytes || format!("{hash:016x}") != input.id.hash {
                return Err(Error::input(
                    &input.path,
                    "changed while the batch ran: run the batch again",
                ));
            }
            tmp.persist(&dest).map_err(|e| Error::io(&dest, e.error))?;
        }
        Ok(dest)
    }

    /// Makes a shared artifact unless it exists; whether it was made.
    fn shared(&self, stage: &SharedStage) -> Result<bool> {
        let dest = self.out.join(stage.file());
        let key_lock = lock(&self.shared_locks).entry(stage.key()).or_default().clone();
        let _making = lock(&key_lock);
        // an incomplete one (a copy cut short) is made again, in its place
        if shared_done(self.out, stage) {
            return Ok(false);
        }
        if let Some(e) = lock(&self.failed_shared).get(&stage.key()) {
            return Err(Error::Config(e.clone()));
        }
        let made = self.make_shared(stage, &dest);
        match made {
            Ok(()) => {
                lock(&self.report).shared_made += 1;
                Ok(true)
            }
            Err(e) => {
                lock(&self.failed_shared).insert(stage.key(), e.to_string());
                Err(e)
            }
        }
    }

    fn make_shared(&self, stage: &SharedStage, dest: &Path) -> Result<()> {
        let dir = staging::parent_dir(dest);
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        match *stage {
            SharedStage::Atlas { mesh, resolution, .. } => {
                let input = &self.plan.meshes[mesh];
                let mesh_file = self.stage_input(input)?;
                let cfg = AtlasConfig {
                    resolution,
                    gutter: self.plan.gutter,
                    ..AtlasConfig::default()
                };
                atlas::build_gim(&mesh_file, dest, &cfg, self.progress)
                    .map_err(|e| naming_the_input(e, &mesh_file, input))?;
            }
            SharedStage::Factorize { sample, .. } => {
                let input = &self.plan.samples[sample].input;
                let sample_file = self.stage_input(input)?;
                let cfg = FactorizeConfig {
                    terms: self.plan.terms,
                    memory: self.budget,
                    ..FactorizeConfig::default()
                };
                factorize::factorize(&sample_file, dest, &cfg, self.progress)
                    .map_err(|e| naming_the_input(e, &sample_file, input))?;
            }
        }
        Ok(())
    }

    /// Runs one job into its staged folder and renames it into place.
    fn job(&self, job: &Job, t: &mut Timings) -> Result<JobRun> {
        let plan = self.plan;
        let budget = self.budget;
        let lap = Instant::now();
        self.shared(&job.atlas)?;
        let sample_file = match &job.factorization {
            Some(f) => {
                self.shared(f)?;
                self.out.join(f.file())
            }
            None => self.stage_input(&plan.samples[job.sample].input)?,
        };
        let mask = match &plan.samples[job.sample].mask {
            Some(m) => Some(self.stage_input(m)?),
            None => None,
        };
        t.shared = lap.elapsed().as_secs_f64();

        let dest = self.out.join(job.dir());
        // a job folder appears whole, with its job.json, by one rename
        if dest.exists() {
            if job_done(self.out, job) {
                // another process finished it since this run listed the jobs
                return Ok(JobRun::DoneElsewhere);
            }
            return Err(Error::input(
                &dest,
                format!("exists but holds no {JOB_JSON}: an incomplete copy of a job folder? Remove it to run the job again"),
            ));
        }
        let stage = match StagedDir::new(&dest, None) {
            Ok(stage) => stage,
            Err(_) if job_done(self.out, job) => return Ok(JobRun::DoneElsewhere),
            Err(e) => return Err(e),
        };
        let dir = stage.path().to_path_buf();
        let quilt_path = dir.join(QUILT);

        let lap = Instant::now();
        let cfg = quilt::TileConfig {
            memory: budget,
            sample_mask: mask,
            ..plan::tile_config(&plan.tile, job.seed, job.sample_width)
        };
        quilt::tile(
            &self.out.join(job.atlas.file()),
            &sample_file,
            &quilt_path,
            &cfg,
            self.progress,
        )?;
        t.tile = lap.elapsed().as_secs_f64();

        if plan.outputs.bake {
            let lap = Instant::now();
            bake::bake(&quilt_path, None, &dir.join("baked.png"), budget)?;
            t.bake = lap.elapsed().as_secs_f64();
        }
        let lap = Instant::now();
        let views: Vec<_> = plan
            .renders
            .iter()
            .map(|r| (r.config(plan), dir.join(&r.file)))
            .collect();
        if !views.is_empty() {
            render::render_views(&quilt_path, &views, budget)?;
        }
        t.render = lap.elapsed().as_secs_f64();
        if plan.outputs.gltf || plan.outputs.btf {
            let lap = Instant::now();
            let opts = ExportOptions {
                mesh: plan.outputs.gltf.then(|| (MeshFormat::Gltf, dir.join("gltf"))),
                btf: plan.outputs.btf.then(|| dir.join("surface-btf")),
                sample: None,
                budget,
            };
            export::export(&quilt_path, &opts)?;
            t.export = lap.elapsed().as_secs_f64();
        }
        #[derive(Serialize)]
        struct JobJson<'a> {
            job: Key,
            atlas: String,
            sample_file: String,
            #[serde(flatten)]
            spec: &'a plan::JobSpec,
        }
        let text = serde_json::to_string_pretty(&JobJson {
            job: job.key,
            atlas: job.atlas.file(),
            sample_file: job.sample_file(),
            spec: &job.spec,
        })
        .map_err(|e| Error::io(dir.join(JOB_JSON), e.into()))?;
        std::fs::write(dir.join(JOB_JSON), text + "\n").map_err(|e| Error::io(dir.join(JOB_JSON), e))?;
        // never replace a folder another process committed meanwhile: the
        // keys are content addresses, so it holds the same bytes
        Ok(if stage.commit_unless_present()? {
            JobRun::Done
        } else {
            JobRun::DoneElsewhere
        })
    }
}
