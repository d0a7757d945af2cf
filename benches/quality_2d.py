#!/usr/bin/env python3
"""Coherence and completeness of 400² flat-square quilts (docs/measurements.md,
"Coherence and completeness in 2D").

Usage: python3 benches/quality_2d.py [--btfquilt BIN] [--tile-args "ARGS"]
           [--seeds 1,2,3] [--samples NAME,...] [--work DIR] [--peer BIN]

For each sample and seed: `atlas square.obj --resolution 408` (a flat unit
square, made once), `tile --seed S ARGS`, `evaluate` (its share of sample
pixels never used), `bake`, the inner 400² cropped, and `compare` against the
sample (5×5 windows, exact nearest neighbours; lower is better). Prints one
row per sample (means over the seeds) and the geometric means. Needs Pillow
for the crops; the samples come from data/ and ../shared/data/textures, or
are generated (cracked, pebbles). With `--peer BIN` (the Embark
texture-synthesis CLI, `cargo install texture-synthesis-cli --locked`) each
sample is also synthesized by the peer (`--out-size 400 --seed 1 generate`)
and measured by the same `compare`, in two more columns.
"""
import argparse
import json
import math
import os
import subprocess
import sys

from PIL import Image

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(ROOT, '..', 'shared', 'data', 'textures')
# name -> (path, crop origin or None): the CC0 photos are cropped to 192²
SAMPLES = {
    'brick wall': (os.path.join(ROOT, 'data', 'brick_wall.png'), None),
    'stones': (os.path.join(SHARED, 'classic', 'stones.png'), None),
    'weave': (os.path.join(SHARED, 'classic', 'weave.png'), None),
    'text': (os.path.join(SHARED, 'classic', 'text.png'), None),
    'plaster with sparse cracks': (os.path.join(ROOT, 'data', 'plaster_cracks.png'), None),
    # generated: `generate-btf --family F --size 192 --views 1x1 --lights 4x2`,
    # the image at view 0,0 and light 25,0
    'cracked (generated)': ('generate:cracked', None),
    'pebbles (generated)': ('generate:pebbles', None),
    'CC0 gravel crop': (os.path.join(SHARED, 'cc0', 'gravel.png'), (100, 100)),
    'CC0 brick crop': (os.path.join(SHARED, 'cc0', 'brick.png'), (0, 0)),
    'CC0 grass crop': (os.path.join(SHARED, 'cc0', 'grass.png'), (160, 160)),
    'wood with few holes': (os.path.join(ROOT, 'data', 'wood_holes.png'), None),
}
SQUARE = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"


def run(*cmd):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed:\n{r.stderr}")
    return r.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--btfquilt', default=os.path.join(ROOT, 'target', 'release', 'btfquilt'))
    ap.add_argument('--tile-args', default='')
    ap.add_argument('--seeds', default='1,2,3')
    ap.add_argument('--samples', default=','.join(SAMPLES))
    ap.add_argument('--work', default='/tmp/quality_2d')
    ap.add_argument('--peer', help='texture-synthesis CLI to measure side by side (one seed)')
    argv = sys.argv[1:]  # let `--tile-args "--x 1"` through: glue the value on
    argv = [f'--tile-args={argv[k + 1]}' if a == '--tile-args' and k + 1 < len(argv) else a
            for k, a in enumerate(argv) if not (k and argv[k - 1] == '--tile-args')]
    o = ap.parse_args(argv)
    unknown = [n for n in o.samples.split(',') if n not in SAMPLES]
    if unknown:
        sys.exit(f"unknown sample {', '.join(unknown)}; the samples are: {', '.join(SAMPLES)}")
    os.makedirs(o.work, exist_ok=True)
    obj, gim = os.path.join(o.work, 'square.obj'), os.path.join(o.work, 'square.gim')
    with open(obj, 'w') as f:
        f.write(SQUARE)
    run(o.btfquilt, 'atlas', obj, '--resolution', 408, '-o', gim, '-q')
    seeds = [int(s) for s in o.seeds.split(',')]
    keys = ['coh_mean', 'coh_p95', 'com_mean', 'com_p95', 'never']
    if o.peer:
        keys += ['peer_coh_mean', 'peer_coh_p95', 'peer_com_mean', 'peer_com_p95']
    print(f"btfquilt tile {o.tile_args or '(defaults)'}, seeds {o.seeds}\n")
    head = '| sample | coherence mean / p95 | completeness mean / p95 | never used |'
    if o.peer:
        head += ' peer: coherence mean / p95 | peer: completeness mean / p95 |'
    print(head)
    print('|---' * (head.count('|') - 1) + '|')
    logs = {k: [] for k in keys}
    for name in o.samples.split(','):
        path, crop = SAMPLES[name]
        if path.startswith('generate:'):
            family = path.split(':')[1]
            btf, path = (os.path.join(o.work, family + e) for e in ('.btf', '.png'))
            run(o.btfquilt, 'generate-btf', '--family', family, '--size', 192, '--views', '1x1',
                '--lights', '4x2', '-o', btf, '-q')
            run(o.btfquilt, 'export-btf', btf, '--view', '0,0', '--light', '25,0', '-o', path, '-q')
        if not os.path.exists(path):
            print(f'| {name} | skipped: {path} absent |' + ' |' * (head.count('|') - 3))
            continue
        if crop:
            cropped = os.path.join(o.work, name.replace(' ', '_') + '.png')
            Image.open(path).crop((crop[0], crop[1], crop[0] + 192, crop[1] + 192)).save(cropped)
            path = cropped
        acc = {k: 0.0 for k in keys}
        for s in seeds:
            q = os.path.join(o.work, 'out.quilt')
            run(o.btfquilt, 'tile', '--gim', gim, '--sample', path, '--seed', s, '-o', q, '-q',
                *o.tile_args.split())
            ev = json.loads(run(o.btfquilt, 'evaluate', q, '--gim', gim, '-q'))
            baked = os.path.join(o.work, 'baked.png')
            run(o.btfquilt, 'bake', q, '-o', baked, '-q')
            inner = os.path.join(o.work, 'inner.png')
            Image.open(baked).crop((4, 4, 404, 404)).save(inner)
            c = json.loads(run(o.btfquilt, 'compare', inner, '--sample', path, '-q'))
            acc['coh_mean'] += c['coherence']['mean'] / len(seeds)
            acc['coh_p95'] += c['coherence']['p95'] / len(seeds)
            acc['com_mean'] += c['completeness']['mean'] / len(seeds)
            acc['com_p95'] += c['completeness']['p95'] / len(seeds)
            acc['never'] += 100.0 * ev['usage'][0]['never_used'] / len(seeds)
        if o.peer:
            out = os.path.join(o.work, 'peer.png')
            run(o.peer, '--no-progress', '--out-size', 400, '--seed', 1, '--out', out, 'generate', path)
            c = json.loads(run(o.btfquilt, 'compare', out, '--sample', path, '-q'))
            acc['peer_coh_mean'], acc['peer_coh_p95'] = c['coherence']['mean'], c['coherence']['p95']
            acc['peer_com_mean'], acc['peer_com_p95'] = c['completeness']['mean'], c['completeness']['p95']
        for k in keys:
            logs[k].append(math.log(max(acc[k], 1e-12)))
        print(row(name, acc, o.peer), flush=True)
    g = {k: math.exp(sum(v) / len(v)) for k, v in logs.items() if v}
    if g:
        print(row('geometric mean', g, o.peer))


def row(name, f, peer):
    """One table row of the figures `f`."""
    r = (f"| {name} | {f['coh_mean']:.4f} / {f['coh_p95']:.4f} | "
         f"{f['com_mean']:.4f} / {f['com_p95']:.4f} | {f['never']:.0f} % |")
    if peer:
        r += (f" {f['peer_coh_mean']:.4f} / {f['peer_coh_p95']:.4f} | "
              f"{f['peer_com_mean']:.4f} / {f['peer_com_p95']:.4f} |")
    return r


if __name__ == '__main__':
    main()
