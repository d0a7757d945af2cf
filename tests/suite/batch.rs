//! `btfquilt batch`: content-addressed jobs, shards, resuming, the manifest
//! and bad plans.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::{self, btfquilt, fails_clearly, ok, s};

/// A plan over the flat square at two resolutions, two samples (crops of
/// the brick photo) and two seeds: 8 jobs, each with two renders and a glTF.
fn plan_dir() -> (tempfile::TempDir, PathBuf) {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("in");
    std::fs::create_dir(&dir).unwrap();
    common::square_obj(&dir);
    let a = common::brick_crop(&dir, 40, Some((100, 100)));
    std::fs::rename(a, dir.join("a.png")).unwrap();
    let b = common::brick_crop(&dir, 40, Some((300, 200)));
    std::fs::rename(b, dir.join("b.png")).unwrap();
    let plan = dir.join("plan.toml");
    std::fs::write(
        &plan,
        r#"
[[mesh]]
path = "square.obj"
[[sample]]
path = "a.png"
[[sample]]
path = "b.png"
name = "other"
[atlas]
resolutions = [64, 80]
[tile]
seeds = [1, 2]
[render]
width = 64
height = 48
lights = ["0.4,0.8,0.6", "-0.6,0.3,0.7,2"]
[outputs]
gltf = true
"#,
    )
    .unwrap();
    (d, plan)
}

/// Every file under `dir` but the manifests, with its bytes, by relative path.
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            if p.is_dir() {
                walk(root, &p, out);
            } else if !rel.ends_with(".jsonl") {
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut m = BTreeMap::new();
    walk(dir, dir, &mut m);
    m
}

/// Asserts two output trees hold the same files with the same bytes.
fn assert_same_tree(a: &Path, b: &Path) {
    let (ta, tb) = (tree(a), tree(b));
    assert_eq!(
        ta.keys().collect::<Vec<_>>(),
        tb.keys().collect::<Vec<_>>(),
        "different files"
    );
    for (k, v) in &ta {
        assert!(
            v == &tb[k],
            "{k} differs between {} and {}",
            a.display(),
            b.display()
        );
    }
}

/// The jobs `--list --json` prints: (key, status).
fn list(plan: &Path, out: &Path, extra: &[&str]) -> Vec<(String, String)> {
    let mut args = vec!["batch", s(plan), "-o", s(out), "--list", "--json"];
    args.extend_from_slice(extra);
    ok(&args)
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["job"].as_str().unwrap().to_string(),
                v["status"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn manifest(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("manifest.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Hidden entries (partial outputs) anywhere under `dir`.
fn hidden(dir: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.file_name().unwrap().to_string_lossy().starts_with('.') {
                v.push(p.clone());
            }
            if p.is_dir() {
                stack.push(p);
            }
        }
    }
    v
}

#[test]
fn shards_as_separate_processes_equal_one_run_byte_for_byte() {
    let (d, plan) = plan_dir();
    let one = d.path().join("one");
    ok(&["batch", s(&plan), "-o", s(&one), "-q"]);
    let jobs = list(&plan, &one, &[]);
    assert_eq!(jobs.len(), 8);
    assert!(jobs.iter().all(|(_, st)| st == "done"));
    // 3 shards at once, one thread each, a small budget, into another folder
    let sharded = d.path().join("sharded");
    let children: Vec<_> = (0..3)
        .map(|i| {
            Command::new(env!("CARGO_BIN_EXE_btfquilt"))
                .args([
                    "batch",
                    s(&plan),
                    "-o",
                    s(&sharded),
                    "-q",
                    "--threads",
                    "1",
                    "--memory",
                    "16MiB",
                ])
                .args(["--shard", &format!("{i}/3")])
                .output_async()
        })
        .collect();
    all_succeed(children);
    let mut union = Vec::new();
    for i in 0..3 {
        union.extend(list(&plan, &sharded, &["--shard", &format!("{i}/3")]));
    }
    // the shards partition the jobs
    let mut keys: Vec<_> = union.iter().map(|(k, _)| k.clone()).collect();
    keys.sort();
    let mut all: Vec<_> = jobs.iter().map(|(k, _)| k.clone()).collect();
    all.sort();
    assert_eq!(keys, all);
    assert_same_tree(&one, &sharded);
    // nor on jobs run side by side in one process
    let workers = d.path().join("workers");
    ok(&[
        "batch",
        s(&plan),
        "-o",
        s(&workers),
        "-q",
        "--workers",
        "3",
        "--memory",
        "48MiB",
    ]);
    assert_same_tree(&one, &workers);
    // the folder's bytes do not depend on where it or the plan lie
    let moved = d.path().join("deeper/still");
    std::fs::create_dir_all(&moved).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .current_dir(&moved)
        .args(["batch", "../../in/plan.toml", "-o", "here", "-q"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_same_tree(&one, &moved.join("here"));
    // every job's outputs are there and the manifest says what they are
    let lines = manifest(&one);
    assert_eq!(lines.len(), 8);
    for l in &lines {
        assert_eq!(l["status"], "done");
        let folder = one.join(l["folder"].as_str().unwrap());
        let files: Vec<&str> = l["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|o| o["file"].as_str().unwrap())
            .collect();
        for f in [
            "decorated.quilt",
            "baked.png",
            "render-c0-l0.png",
            "render-c0-l1.png",
            "gltf/mesh.glb",
            "job.json",
        ] {
            assert!(files.contains(&f), "{f} missing from {files:?}");
            assert!(folder.join(f).is_file());
        }
        for o in l["outputs"].as_array().unwrap() {
            let len = std::fs::metadata(folder.join(o["file"].as_str().unwrap()))
                .unwrap()
                .len();
            assert_eq!(o["bytes"].as_u64().unwrap(), len);
        }
        let (hash, bytes) = (
            l["mesh"]["hash"].as_str().unwrap(),
            l["mesh"]["bytes"].as_u64().unwrap(),
        );
        assert!(one.join(l["mesh"]["file"].as_str().unwrap()).is_file());
        assert_eq!(
            l["mesh"]["file"].as_str().unwrap(),
            format!("inputs/{hash}-{bytes}.obj")
        );
        assert!(l["seconds"]["tile"].as_f64().unwrap() > 0.0);
    }
    // one geometry image per resolution, one factorization per sample
    let shared = common::listing(&one.join("shared"));
    assert_eq!(
        shared.iter().filter(|f| f.ends_with(".gim")).count(),
        2,
        "{shared:?}"
    );
    assert_eq!(
        shared.iter().filter(|f| f.ends_with(".svd")).count(),
        2,
        "{shared:?}"
    );
    // the quilt reads its geometry image and sample from the folder
    let job = one.join(lines[0]["folder"].as_str().unwrap());
    ok(&[
        "bake",
        s(&job.join("decorated.quilt")),
        "-o",
        s(&d.path().join("again.png")),
    ]);
}

/// `Command::spawn` with captured output.
trait SpawnCaptured {
    fn output_async(&mut self) -> std::process::Child;
}

impl SpawnCaptured for Command {
    fn output_async(&mut self) -> std::process::Child {
        self.stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    }
}

/// Waits for every child process and asserts each succeeded.
fn all_succeed(children: Vec<std::process::Child>) {
    for (i, c) in children.into_iter().enumerate() {
        let out = c.wait_with_output().unwrap();
        assert!(
            out.status.success(),
            "process {i}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

#[test]
fn finished_jobs_are_skipped_and_a_changed_input_reruns_exactly_its_jobs() {
    let (d, plan) = plan_dir();
    let out = d.path().join("out");
    ok(&["batch", s(&plan), "-o", s(&out), "-q"]);
    let before = tree(&out);
    let again = ok(&["batch", s(&plan), "-o", s(&out), "-q"]);
    assert!(again.contains("0 jobs done, 8 already done"), "{again}");
    assert_eq!(before, tree(&out), "a second run changed files");
    let lines = manifest(&out);
    assert_eq!(lines.iter().filter(|l| l["status"] == "skipped").count(), 8);

    // change sample b: its 4 jobs are new, sample a's 4 are still done
    let old = list(&plan, &out, &[]);
    let b = plan.parent().unwrap().join("b.png");
    common::brick_crop(plan.parent().unwrap(), 40, Some((310, 200)));
    std::fs::rename(plan.parent().unwrap().join("brick40.png"), &b).unwrap();
    let new = list(&plan, &out, &[]);
    let kept: Vec<_> = new.iter().filter(|j| old.contains(j)).collect();
    let todo: Vec<_> = new.iter().filter(|(_, st)| st == "todo").collect();
    assert_eq!((kept.len(), todo.len()), (4, 4), "{old:?} → {new:?}");
    let run = ok(&["batch", s(&plan), "-o", s(&out), "-q"]);
    assert!(run.contains("4 jobs done, 4 already done"), "{run}");
    // one more factorization, no more geometry images
    let shared = common::listing(&out.join("shared"));
    assert_eq!(shared.iter().filter(|f| f.ends_with(".gim")).count(), 2);
    assert_eq!(shared.iter().filter(|f| f.ends_with(".svd")).count(), 3);
    // the old jobs' files are untouched
    for (k, v) in &before {
        if k.starts_with("jobs/") {
            assert_eq!(&std::fs::read(out.join(k)).unwrap(), v, "{k}");
        }
    }

    // --job runs exactly the named job; an unknown key is refused
    let other = d.path().join("other");
    let key = &new[0].0;
    ok(&["batch", s(&plan), "-o", s(&other), "-q", "--job", key]);
    assert_eq!(common::listing(&other.join("jobs")), vec![key.clone()]);
    let r = btfquilt(&["batch", s(&plan), "-o", s(&other), "--job", &"0".repeat(32)]);
    fails_clearly(&r, &["plan.toml", "has no job 00000000000000000000000000000000"]);
}

#[test]
fn a_killed_run_resumes_with_no_duplicate_or_partial_output() {
    let (d, plan) = plan_dir();
    let reference = d.path().join("reference");
    ok(&["batch", s(&plan), "-o", s(&reference), "-q"]);
    let out = d.path().join("out");
    // kill the run while a job is staged (its folder under a hidden name)
    let mut child = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .args(["batch", s(&plan), "-o", s(&out), "-q", "--threads", "1"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let mut killed_mid_job = false;
    while start.elapsed().as_secs() < 60 {
        let staged = common::listing(&out.join("jobs"))
            .iter()
            .any(|n| n.ends_with(".partial.d"));
        if staged {
            child.kill().unwrap();
            killed_mid_job = child.wait().unwrap().code().is_none();
            break;
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(killed_mid_job, "the run was not caught in a job");
    // almost always a job's partial folder is left (unless the kill fell
    // just after a job's folder was renamed into place)
    let left_partial = !hidden(&out).is_empty();
    let finished_before = common::listing(&out.join("jobs"))
        .iter()
        .filter(|n| !n.starts_with('.'))
        .count();
    assert!(finished_before < 8);
    let run = btfquilt(&["batch", s(&plan), "-o", s(&out)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stderr = String::from_utf8_lossy(&run.stderr);
    if left_partial {
        assert!(stderr.contains("a partial output left by process"), "{stderr}");
    }
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains(&format!(
            "{} jobs done, {finished_before} already done",
            8 - finished_before
        )),
        "{stdout}"
    );
    assert_eq!(hidden(&out), Vec::<PathBuf>::new());
    assert_same_tree(&reference, &out);
}

#[test]
fn bad_plans_are_refused_naming_the_plan_and_the_fault_with_nothing_written() {
    let (d, plan) = plan_dir();
    let text = std::fs::read_to_string(&plan).unwrap();
    let out = d.path().join("out");
    let cases: Vec<(String, Vec<&str>)> = vec![
        (
            text.replace("square.obj", "gone.obj"),
            vec!["mesh 1 'gone.obj'", "is not a file"],
        ),
        (
            text.replace("seeds = [1, 2]", "seeds = []"),
            vec!["[tile] seeds is empty"],
        ),
        (
            text.replace("seeds = [1, 2]", "seds = [1]"),
            vec!["not a valid plan", "seds"],
        ),
        (
            text.replace("[64, 80]", "[8]"),
            vec!["[atlas] resolutions", "--resolution 8"],
        ),
        (
            text.replace("seeds = [1, 2]", "seeds = [1]\nsample_widths = [-1.0]"),
            vec!["[tile]", "--sample-width -1"],
        ),
        (
            text.replace("seeds = [1, 2]", "seeds = [1]\nrefine_passes = 0"),
            vec!["[tile]", "--refine-passes 0"],
        ),
        (
            text.replace("lights = [", "cameras = [\"1,2\"]\nlights = ["),
            vec!["[render] cameras", "10 numbers"],
        ),
        (text.replace("0.4,0.8,0.6", "0,0,0"), vec!["[render] lights"]),
        (
            text.replace("lights = [\"0.4,0.8,0.6\", \"-0.6,0.3,0.7,2\"]", "lights = []"),
            vec!["[render] lights is empty"],
        ),
        (
            text.replace("[[mesh]]\npath = \"square.obj\"", ""),
            vec!["names no mesh"],
        ),
        ("this is = = not toml".into(), vec!["not a valid plan"]),
    ];
    for (body, needles) in cases {
        std::fs::write(&plan, &body).unwrap();
        let mut all = vec!["plan.toml"];
        all.extend(needles);
        fails_clearly(&btfquilt(&["batch", s(&plan), "-o", s(&out)]), &all);
        assert!(!out.exists(), "a refused plan wrote {}", out.display());
    }
    std::fs::write(&plan, &text).unwrap();
    // the manifest may not be an input, --job goes alone
    fails_clearly(
        &btfquilt(&["batch", s(&plan), "-o", s(&out), "--manifest", s(&plan)]),
        &["plan.toml", "would destroy it"],
    );
    assert!(!out.exists());
    fails_clearly(
        &btfquilt(&[
            "batch",
            s(&plan),
            "-o",
            s(&out),
            "--job",
            &"0".repeat(32),
            "--shard",
            "0/2",
        ]),
        &["--job", "--shard"],
    );
    for bad in ["3/3", "1", "a/2", "0/0"] {
        fails_clearly(
            &btfquilt(&["batch", s(&plan), "-o", s(&out), "--shard", bad]),
            &["--shard"],
        );
    }
    // an output folder holding the inputs is refused (nothing written there)
    let inside = plan.parent().unwrap().to_path_buf();
    let before = common::listing(&inside);
    fails_clearly(
        &btfquilt(&["batch", s(&plan), "-o", s(&inside)]),
        &["give an output folder apart from the inputs"],
    );
    assert_eq!(common::listing(&inside), before);
    // a job that fails is reported, the others are done, and the exit is non-zero
    std::fs::write(plan.parent().unwrap().join("b.png"), b"not a png").unwrap();
    let r = btfquilt(&["batch", s(&plan), "-o", s(&out), "-q"]);
    let stderr = fails_clearly(
        &r,
        &["4 of the batch's jobs or shared stages failed", "manifest.jsonl"],
    );
    // the error names the user's file, not only its copy in inputs/
    assert!(
        stderr.contains("in/b.png") && stderr.contains("in its copy"),
        "{stderr}"
    );
    // an output that is a file is refused
    let file = d.path().join("a-file");
    std::fs::write(&file, b"mine").unwrap();
    fails_clearly(
        &btfquilt(&["batch", s(&plan), "-o", s(&file)]),
        &["a-file", "not a folder"],
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"mine");
    let lines = manifest(&out);
    assert_eq!(lines.iter().filter(|l| l["status"] == "done").count(), 4);
    assert_eq!(lines.iter().filter(|l| l["status"] == "failed").count(), 4);
    assert!(lines
        .iter()
        .all(|l| l["status"] != "failed" || l["error"].is_string()));
    assert_eq!(hidden(&out), Vec::<PathBuf>::new());
}

/// `examples/cluster/NAME`.
fn cluster_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/cluster")
        .join(name)
}

#[test]
fn the_slurm_array_and_the_kubernetes_indexed_job_map_their_index_to_shards() {
    let (d, plan) = plan_dir();
    let reference = d.path().join("reference");
    ok(&["batch", s(&plan), "-o", s(&reference), "-q"]);
    let bin = env!("CARGO_BIN_EXE_btfquilt");
    // a Slurm array --array=1-4: task ids 1..4, one after another
    let slurm = d.path().join("slurm");
    for id in 1..=4 {
        let out = Command::new("bash")
            .arg(cluster_file("slurm_batch.sh"))
            .env("SLURM_ARRAY_TASK_ID", id.to_string())
            .env("SLURM_ARRAY_TASK_MIN", "1")
            .env("SLURM_ARRAY_TASK_COUNT", "4")
            .env("SLURM_CPUS_PER_TASK", "1")
            .env("PLAN", &plan)
            .env("OUT", &slurm)
            .env("BTFQUILT", bin)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "task {id}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains(&format!("shard {}/4", id - 1)), "{stderr}");
    }
    assert_same_tree(&reference, &slurm);
    assert_eq!(common::listing(&slurm.join("manifests")).len(), 4);

    // the Indexed Job's command, with 5 completions (more than some shards' jobs)
    let yaml = std::fs::read_to_string(cluster_file("k8s_indexed_job.yaml")).unwrap();
    let mut lines = yaml.lines();
    lines
        .find(|l| l.trim() == "# shard-command:")
        .expect("a '# shard-command:' line");
    let command = lines.next().unwrap().trim();
    let command = command
        .strip_prefix("- '")
        .and_then(|c| c.strip_suffix('\''))
        .unwrap();
    let k8s = d.path().join("k8s");
    let children: Vec<_> = (0..5)
        .map(|index| {
            Command::new("sh")
                .args(["-c", command])
                .env("JOB_COMPLETION_INDEX", index.to_string())
                .env("SHARDS", "5")
                .env("PLAN", &plan)
                .env("OUT", &k8s)
                .env("BTFQUILT", bin)
                .output_async()
        })
        .collect();
    all_succeed(children);
    assert_same_tree(&reference, &k8s);
    assert_eq!(hidden(&k8s), Vec::<PathBuf>::new());
}

#[test]
fn ray_runs_the_plan_as_tasks_retries_a_killed_worker_and_matches_one_run() {
    let has_ray = Command::new("python3")
        .args(["-c", "import ray"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_ray {
        eprintln!("skipped: Ray for Python is not installed (python3 -m pip install ray)");
        return;
    }
    let (d, plan) = plan_dir();
    let reference = d.path().join("reference");
    ok(&["batch", s(&plan), "-o", s(&reference), "-q"]);
    let out = d.path().join("ray");
    let flag = d.path().join("killed");
    let run = Command::new("python3")
        .arg(cluster_file("ray_batch.py"))
        .args([
            s(&plan),
            "-o",
            s(&out),
            "--num-cpus",
            "3",
            "--threads",
            "1",
            "--memory",
            "256MiB",
        ])
        .args(["--btfquilt", env!("CARGO_BIN_EXE_btfquilt")])
        .env("BTFQUILT_RAY_KILL_ONCE", &flag)
        .env("RAY_USAGE_STATS_ENABLED", "0")
        .output()
        .unwrap();
    let log = format!(
        "{}\n{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(run.status.success(), "{log}");
    // a worker was killed in the middle of a job, and the retry finished it
    let partial = std::fs::read_to_string(&flag).unwrap();
    assert!(partial.trim().ends_with(".partial.d"), "{partial}");
    assert!(!Path::new(partial.trim()).exists(), "{partial} is still there");
    assert_eq!(hidden(&out), Vec::<PathBuf>::new());
    assert_same_tree(&reference, &out);
    // the gathered manifest has a line for every job
    let lines = manifest(&out);
    let mut done: Vec<&str> = lines
        .iter()
        .filter(|l| l["status"] == "done")
        .filter_map(|l| l["job"].as_str())
        .collect();
    done.sort();
    done.dedup();
    assert_eq!(done.len(), 8, "{log}");
    // and a line for each shared artifact its first phase made
    let shared = lines.iter().filter(|l| l["shared"].is_string()).count();
    assert!(shared >= 4, "{shared} shared lines: {log}");
}

#[test]
fn btf_and_factorized_samples_give_renders_and_surface_btfs() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    common::square_obj(dir);
    let btf = dir.join("small.btf");
    ok(&[
        "generate-btf",
        "--family",
        "bricks",
        "--size",
        "32",
        "--views",
        "4x2",
        "--lights",
        "4x2",
    ]
    .into_iter()
    .chain(["-q", "-o", s(&btf)])
    .collect::<Vec<_>>());
    ok(&[
        "factorize",
        s(&btf),
        "--terms",
        "8",
        "-q",
        "-o",
        s(&dir.join("small.svd")),
    ]);
    let plan = dir.join("plan.toml");
    std::fs::write(
        &plan,
        "[[mesh]]\npath = \"square.obj\"\n[[sample]]\npath = \"small.btf\"\n[[sample]]\npath = \"small.svd\"\n\
         [factorize]\nterms = 8\n[atlas]\nresolutions = [64]\n[render]\nwidth = 64\nheight = 48\n\
         [outputs]\nbtf = true\n",
    )
    .unwrap();
    let out = dir.join("out");
    ok(&["batch", s(&plan), "-o", s(&out), "-q"]);
    // the .btf is factorized once into shared/, the .svd used as it is
    let shared = common::listing(&out.join("shared"));
    assert_eq!(
        shared.iter().filter(|f| f.ends_with(".svd")).count(),
        1,
        "{shared:?}"
    );
    let jobs = common::listing(&out.join("jobs"));
    assert_eq!(jobs.len(), 2);
    for j in &jobs {
        let job = out.join("jobs").join(j);
        for f in [
            "decorated.quilt",
            "baked.png",
            "render-c0-l0.png",
            "surface-btf/synthesis.exr",
            "job.json",
        ] {
            assert!(job.join(f).is_file(), "{f} missing in {j}");
        }
        let spec: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(job.join("job.json")).unwrap()).unwrap();
        let sample = spec["sample_file"].as_str().unwrap();
        assert!(out.join(sample).is_file(), "{sample}");
        assert!(sample.ends_with(".svd"), "{sample}");
        // the decorated surface renders again from any working directory,
        // finding its geometry image and sample through the folder
        let again = dir.join(format!("{j}.png"));
        ok(&[
            "render",
            s(&job.join("decorated.quilt")),
            "--width",
            "64",
            "--height",
            "48",
            "-o",
            s(&again),
        ]);
        assert_eq!(
            std::fs::read(&again).unwrap(),
            std::fs::read(job.join("render-c0-l0.png")).unwrap()
        );
    }
}

#[test]
fn the_same_plan_run_twice_at_once_and_incomplete_copies_are_handled() {
    let (d, plan) = plan_dir();
    let reference = d.path().join("reference");
    ok(&["batch", s(&plan), "-o", s(&reference), "-q"]);
    // two unsharded runs at once: every job is run by one or both, none fails
    let out = d.path().join("twice");
    let runs: Vec<_> = (0..2)
        .map(|_| {
            Command::new(env!("CARGO_BIN_EXE_btfquilt"))
                .args(["batch", s(&plan), "-o", s(&out), "-q", "--threads", "1"])
                .output_async()
        })
        .collect();
    all_succeed(runs);
    assert_same_tree(&reference, &out);
    assert_eq!(hidden(&out), Vec::<PathBuf>::new());

    // a job folder without its job.json (a copy cut short) is not taken as
    // done, nor replaced: the run names it and leaves it
    let jobs = list(&plan, &out, &[]);
    let cut = out.join("jobs").join(&jobs[0].0);
    std::fs::remove_file(cut.join("job.json")).unwrap();
    assert_eq!(list(&plan, &out, &[])[0].1, "todo");
    let r = btfquilt(&["batch", s(&plan), "-o", s(&out), "-q"]);
    fails_clearly(&r, &[&jobs[0].0, "holds no job.json", "Remove it"]);
    assert!(
        cut.join("decorated.quilt").is_file(),
        "the incomplete folder was touched"
    );
    std::fs::remove_dir_all(&cut).unwrap();

    // a shared artifact cut short is made again in its place
    let shared = out.join("shared");
    let gim = common::listing(&shared)
        .into_iter()
        .find(|f| f.ends_with(".gim"))
        .unwrap();
    let bytes = std::fs::read(shared.join(&gim)).unwrap();
    std::fs::write(shared.join(&gim), &bytes[..bytes.len() / 2]).unwrap();
    ok(&["batch", s(&plan), "-o", s(&out), "-q"]);
    assert_same_tree(&reference, &out);
}

#[test]
fn shards_partition_any_list_into_contiguous_runs() {
    for len in [0usize, 1, 2, 7, 8, 100] {
        for count in 1..=12 {
            let mut next = 0;
            for index in 0..count {
                let r = btfquilt::batch::Shard { index, count }.range(len);
                assert_eq!(r.start, next, "len {len}, {index}/{count}");
                // sizes differ by at most one
                assert!(r.len() == len / count || r.len() == len / count + 1);
                next = r.end;
            }
            assert_eq!(next, len);
        }
    }
}

#[test]
fn shard_and_key_parse_what_they_print() {
    let s = btfquilt::batch::Shard::parse("3/8").unwrap();
    assert_eq!((s.index, s.count), (3, 8));
    assert_eq!(btfquilt::batch::Shard::parse(&s.to_string()).unwrap(), s);
    for bad in ["8/8", "-1/3", "1", "1/0", "x/2", ""] {
        assert!(btfquilt::batch::Shard::parse(bad).is_err(), "{bad}");
    }
    let k = btfquilt::batch::Key(0x0123_4567_89ab_cdef_0011_2233_4455_6677);
    assert_eq!(k.to_string(), "0123456789abcdef0011223344556677");
    assert_eq!(btfquilt::batch::Key::parse(&k.to_string()), Some(k));
    assert_eq!(btfquilt::batch::Key::parse("0123"), None);
    assert_eq!(btfquilt::batch::Key::parse(&"g".repeat(32)), None);
}

#[test]
fn every_parameter_reaching_an_output_changes_the_key() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("m.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(d.path().join("s.png"), b"any bytes: only hashed here").unwrap();
    let base = "[[mesh]]\npath = \"m.obj\"\n[[sample]]\npath = \"s.png\"\n";
    let key = |extra: &str| {
        let plan =
            btfquilt::batch::Plan::parse(&d.path().join("plan.toml"), &format!("{base}{extra}")).unwrap();
        let jobs = plan.jobs();
        assert_eq!(jobs.len(), 1);
        jobs[0].key
    };
    let k0 = key("");
    // the defaults written out are the same job
    assert_eq!(k0, key("[atlas]\nresolutions = [1024]\n[tile]\nseeds = [1]\n"));
    assert_eq!(k0, key("[tile]\nfeature_align = 0.09\n"));
    assert_eq!(k0, key("[tile]\nrefine_broken = 4\nrefine_passes = 2\n"));
    // passes count only with refinement where features end, and that only
    // with seam refinement: what does nothing leaves the key alone
    let off = key("[tile]\nrefine_broken = 0\n");
    assert_eq!(off, key("[tile]\nrefine_broken = 0\nrefine_passes = 3\n"));
    let no_refine = key("[tile]\nrefine = 0\n");
    assert_eq!(
        no_refine,
        key("[tile]\nrefine = 0\nrefine_broken = 2\nrefine_passes = 3\n")
    );
    assert_eq!(k0, key("[tile]\ncourses = \"free\"\n"));
    assert_eq!(k0, key("[tile]\nmatch_terms = 0\n"));
    // a choice that is not one is refused, naming what it expected
    let bad = btfquilt::batch::Plan::parse(
        &d.path().join("plan.toml"),
        &format!("{base}[tile]\ncourses = \"tight\"\n"),
    )
    .err()
    .expect("courses = tight is refused")
    .to_string();
    assert!(bad.contains("plan.toml") && bad.contains("locked"), "{bad}");
    let variants = [
        "[atlas]\nresolutions = [512]\n",
        "[atlas]\ngutter = 3\n",
        "[tile]\nseeds = [2]\n",
        "[tile]\nsample_widths = [0.5]\n",
        "[tile]\nrefine = 0\n",
        "[tile]\noccurrence_weight = 0.25\n",
        "[tile]\ntolerance = 0.1\n",
        "[tile]\nfeature_align = 0\n",
        "[tile]\nrefine_broken = 0\n",
        "[tile]\nrefine_passes = 3\n",
        "[tile]\nrefine_broken = 2\n",
        "[tile]\ncourses = \"locked\"\n",
        "[tile]\nmatch_terms = 16\n",
        "[factorize]\nterms = 8\n",
        "[render]\nwidth = 320\n",
        "[render]\nlights = [\"0,1,0\"]\n",
        "[render]\ncameras = [\"0,0,3,0,0,0,0,1,0,40\"]\n",
        "[outputs]\ngltf = true\n",
    ];
    let mut keys = vec![k0];
    for v in variants {
        let k = key(v);
        assert!(!keys.contains(&k), "{v} gave a key already seen");
        keys.push(k);
    }
    // a renamed input is the same job; changed content is another
    let renamed = btfquilt::batch::Plan::parse(
        &d.path().join("plan.toml"),
        &base.replace("path = \"s.png\"", "path = \"s.png\"\nname = \"other\""),
    )
    .unwrap();
    assert_eq!(renamed.jobs()[0].key, k0);
    std::fs::write(d.path().join("s.png"), b"other bytes").unwrap();
    assert_ne!(key(""), k0);
}
