#!/usr/bin/env python3
"""Run a `btfquilt batch` plan on a Ray cluster (or a local Ray instance).

Usage:
    python3 examples/cluster/ray_batch.py PLAN -o OUT [--btfquilt PATH]
        [--threads N] [--memory 2GiB] [--address auto|ray://HOST:10001]
        [--num-cpus N] [--mode jobs|shards] [--shards N] [--max-retries 3]

Without --address a local Ray instance is started (--num-cpus sets its CPU
count). PLAN, OUT and --btfquilt must name the same files on every node (a
shared filesystem); relative paths are made absolute here.

  1. The jobs still to do are read from `btfquilt batch PLAN -o OUT --list --json`.
  2. The shared artifacts still to make (geometry images, factorizations;
     `--list --json --stages shared`) are made once, by K tasks
     `--stages shared --shard i/K`, K at most their number.
  3. The jobs run: one task per job (`--job KEY`, --mode jobs) or N tasks
     `--shard i/N` (--mode shards). Each task runs btfquilt with
     `--threads T --memory M -q`, asks Ray for num_cpus=T and memory=M, and
     writes its own manifest OUT/manifests/RUN-TASK.jsonl.
  4. This run's manifests are appended to OUT/manifest.jsonl.

A task that fails (non-zero exit) or whose worker dies is retried by Ray up
to --max-retries times. That is safe: a finished job's folder exists only
when complete and is skipped, and a killed job leaves only a hidden
`.KEY.PID-HOST-BOOT.RAND.partial.d` that the next run of that job on the
same host removes. Outputs are byte-identical whatever the mode, shard
count or thread count.

For tests only: if the environment variable BTFQUILT_RAY_KILL_ONCE=PATH is
set, the first job task (step 3) to find PATH absent creates it, starts
btfquilt, waits until btfquilt's `.partial.d` folder appears under OUT/jobs
(at most 30 s), writes that folder's path into PATH, kills btfquilt and
then its own Ray worker (os._exit), so Ray sees a dead worker and retries
the task (which must remove the partial folder and finish the job).
"""

import argparse
import glob
import json
import logging
import os
import re
import subprocess
import sys
import tempfile
import time

import ray

UNITS = {"": 1, "b": 1, "k": 1 << 10, "kib": 1 << 10, "kb": 10**3,
         "m": 1 << 20, "mib": 1 << 20, "mb": 10**6,
         "g": 1 << 30, "gib": 1 << 30, "gb": 10**9}


def parse_bytes(text):
    """'512MiB', '2GiB', '3G', '65536' -> bytes (as btfquilt's --memory reads them)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]*)\s*", text)
    if not m or m.group(2).lower() not in UNITS:
        raise ValueError(f"--memory: expected a size like 512MiB or 2GiB, not {text!r}")
    return int(float(m.group(1)) * UNITS[m.group(2).lower()])


@ray.remote
def run_btfquilt(argv, out=None, kill_once=None):
    """Runs btfquilt; returns its stdout, raises (so Ray retries) when it fails."""
    with tempfile.TemporaryFile() as so, tempfile.TemporaryFile() as se:
        proc = subprocess.Popen(argv, stdout=so, stderr=se)
        if kill_once and claim(kill_once):  # test hook: see the docstring
            # .KEY.PID-HOST-BOOT.RANDOM.partial.d of this btfquilt process
            mine = os.path.join(out, "jobs", f".*.{proc.pid}-*.partial.d")
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and not glob.glob(mine) and proc.poll() is None:
                time.sleep(0.01)
            with open(kill_once, "w") as f:  # what was left behind, for the test to check
                f.write("".join(p + "\n" for p in glob.glob(mine)))
            proc.kill()
            proc.wait()
            os._exit(1)
        code = proc.wait()
        so.seek(0)
        se.seek(0)
        stdout, stderr = so.read().decode(errors="replace"), se.read().decode(errors="replace")
    if code != 0:
        tail = " | ".join(stderr.strip().splitlines()[-3:])
        raise RuntimeError(f"btfquilt exit code {code}: {tail}")
    return stdout


def claim(path):
    """Creates `path` if absent; whether this call created it."""
    try:
        os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        return True
    except FileExistsError:
        return False


@ray.remote
def gather(out, prefix):
    """Appends this run's task manifests to OUT/manifest.jsonl; their lines."""
    lines = []
    for path in sorted(glob.glob(os.path.join(out, "manifests", prefix + "*.jsonl"))):
        with open(path, "rb") as f:
            lines += [l if l.endswith(b"\n") else l + b"\n" for l in f if l.strip()]
    fd = os.open(os.path.join(out, "manifest.jsonl"), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        for line in lines:  # one write a line: no interleaving with other writers
            os.write(fd, line)
    finally:
        os.close(fd)
    return [json.loads(l) for l in lines]


def list_jobs(base):
    """{key: status} of every job of the plan, in plan order."""
    text = ray.get(run_btfquilt.remote(base + ["--list", "--json"]))
    return {j["job"]: j["status"] for j in map(json.loads, text.splitlines()) if j}


def shared_to_make(base):
    """How many shared artifacts (geometry images, factorizations) are still to make."""
    text = ray.get(run_btfquilt.remote(base + ["--list", "--json", "--stages", "shared"]))
    return sum(1 for s in map(json.loads, text.splitlines()) if s and s["status"] == "todo")


def run_tasks(tasks, opts, kill_once=None, out=None):
    """Runs [(name, argv)] as Ray tasks; the names of those that finally failed."""
    refs = {run_btfquilt.options(name=n, **opts).remote(a, out, kill_once): n for n, a in tasks}
    failed, left = [], list(refs)
    while left:
        ready, left = ray.wait(left, num_returns=1)
        name = refs[ready[0]]
        try:
            summary = ray.get(ready[0]).strip().splitlines()
            print(f"  [{len(refs) - len(left)}/{len(refs)}] {name}: {summary[-1] if summary else 'ok'}")
        except ray.exceptions.RayError as e:
            failed.append(name)
            why = getattr(e, "cause", None) or type(e).__name__  # btfquilt's error, or a lost worker
            print(f"  [{len(refs) - len(left)}/{len(refs)}] {name}: FAILED after retries: {why}", file=sys.stderr)
    return failed


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("plan")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--btfquilt", default="btfquilt", help="the binary (a path, or a name looked up on PATH)")
    p.add_argument("--threads", type=int, default=4, help="threads (and Ray CPUs) per task")
    p.add_argument("--memory", default="2GiB", help="btfquilt --memory, and the Ray memory each task asks for")
    p.add_argument("--address", help="attach to a cluster: auto or ray://HOST:PORT (default: start Ray here)")
    p.add_argument("--num-cpus", type=int, help="CPUs of a local Ray instance (default: all)")
    p.add_argument("--mode", choices=["jobs", "shards"], default="jobs")
    p.add_argument("--shards", type=int, help="tasks in --mode shards (default: task slots of the cluster)")
    p.add_argument("--max-retries", type=int, default=3)
    a = p.parse_args()
    try:
        mem = parse_bytes(a.memory)
    except ValueError as e:
        p.error(str(e))
    binary = os.path.abspath(a.btfquilt) if os.sep in a.btfquilt else a.btfquilt
    plan, out = os.path.abspath(a.plan), os.path.abspath(a.output)
    run_id = time.strftime("ray-%Y%m%dT%H%M%S-") + str(os.getpid())
    kill_once = os.environ.get("BTFQUILT_RAY_KILL_ONCE")

    t0 = time.monotonic()
    quiet = dict(log_to_driver=False, logging_level=logging.WARNING)
    if a.address:
        ray.init(address=a.address, **quiet)
    else:
        # "local": always a new instance on this machine, never one found
        # through a stale /tmp/ray/ray_current_cluster
        ray.init(address="local", num_cpus=a.num_cpus, include_dashboard=False, **quiet)
    t_init = time.monotonic() - t0

    nodes = [n["Resources"] for n in ray.nodes() if n["Alive"]]
    biggest = max(int(n.get("CPU", 0)) for n in nodes)
    threads = max(1, min(a.threads, biggest))
    if threads != a.threads:
        print(f"note: no node has {a.threads} CPUs: using --threads {threads}", file=sys.stderr)
    if mem > max(n.get("memory", 0) for n in nodes):
        sys.exit(f"error: no node has --memory {a.memory} for Ray to give a task")
    slots = max(1, sum(int(n.get("CPU", 0)) // threads for n in nodes))

    base = [binary, "batch", plan, "-o", out]
    before = list_jobs(base)
    todo = [k for k, s in before.items() if s == "todo"]
    print(f"ray.init {t_init:.1f} s; {len(before)} jobs, {len(todo)} to do; "
          f"{slots} task slots of {threads} threads")

    opts = dict(num_cpus=threads, memory=mem, max_retries=a.max_retries, retry_exceptions=True)
    flags = ["--threads", str(threads), "--memory", a.memory, "-q"]

    def task(name, extra):
        manifest = os.path.join(out, "manifests", f"{run_id}-{name}.jsonl")
        return name, base + extra + flags + ["--manifest", manifest]

    failed = []
    if todo:
        shared = shared_to_make(base)
        if shared:
            k = min(shared, slots)
            print(f"shared stages: {shared} to make, {k} tasks")
            failed += run_tasks([task(f"shared-{i}-of-{k}", ["--stages", "shared", "--shard", f"{i}/{k}"])
                                 for i in range(k)], opts)
        if a.mode == "jobs":
            tasks = [task(f"job-{key}", ["--job", key]) for key in todo]
        else:
            n = a.shards or slots
            tasks = [task(f"shard-{i}-of-{n}", ["--shard", f"{i}/{n}"]) for i in range(n)]
        print(f"jobs: {len(tasks)} tasks ({a.mode})")
        failed += run_tasks(tasks, opts, kill_once, out)

    lines = ray.get(gather.remote(out, run_id))
    after = list_jobs(base)
    made = sum(1 for k in todo if after.get(k) == "done")
    missing = [k for k, s in after.items() if s != "done"]
    bad_lines = sum(1 for l in lines if l.get("status") == "failed")
    print(f"{out}: {made} jobs done, {len(before) - len(todo)} skipped (already done), "
          f"{len(missing)} failed or not done ({bad_lines} failed attempts in the manifest), "
          f"{len(failed)} tasks failed; {time.monotonic() - t0:.1f} s")
    for key in missing:
        print(f"not done: {key}", file=sys.stderr)
    sys.exit(1 if failed or missing else 0)


if __name__ == "__main__":
    main()
