#!/usr/bin/env python3
"""Compare btfquilt's atlas (and optionally xatlas's) on OBJ meshes at 1024².

Usage: python3 benches/atlas_vs_xatlas.py [--btfquilt BIN] [--args "EXTRA ATLAS ARGS"]
           [--xatlas] [--label NAME] MESH.obj...

btfquilt: `BIN atlas MESH --resolution 1024 -o m.gim ARGS` (timed: the whole
process, wall clock), then `BIN export m.gim -o exp`, whose mesh.obj (one `v`
per mesh vertex, `vt` per chart corner) is read back. xatlas (0.0.11 binding):
`Atlas.generate` with PackOptions resolution 1024, padding 2, other options
default (timed: the generate call alone); its uvs are normalised by the atlas's
width and height (not square) as returned. Needs only numpy and xatlas.

Measures, the same for both, from per-face 3D positions and per-corner uvs in
[0,1]² over the 1024² texture:
- charts: uv-connected face sets (union-find); two faces are connected when they
  share a corner: the same 3D vertex with the same uv vertex (vt index; xatlas
  output vertex index). (Sharing an edge instead differs only for xatlas on the
  teapot: 78 charts, not 62, where xatlas welds the mesh's duplicate vertices.)
- under 1 %: charts with less than 1 % of the surface's 3D area.
- stretch (Sander et al. 2001) of the map uv -> 3D after scaling the whole uv
  layout by one factor so that total uv area = total 3D area: Jacobian columns
  Ss, St; a = Ss.Ss, b = Ss.St, c = St.St; Γ = sqrt((a+c+sqrt((a-c)²+4b²))/2).
  L2 = sqrt(Σ A3d (a+c)/2 / Σ A3d); L∞ = max Γ; Γ 99 % = 3D-area-weighted 99th
  percentile of Γ. Triangles with zero uv or zero 3D area are skipped.
- texel centres in a chart: share of the centres ((i+.5)/1024, (j+.5)/1024)
  strictly inside (all barycentrics > 0) at least one uv triangle.
- covered twice: texel centres strictly inside two or more uv triangles.
- seam length: 3D length of the mesh edges shared by exactly two faces (3D
  vertices matched by vertex index) whose uvs differ across the edge at either
  endpoint. Boundary edges are not counted.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

RES = 1024


def load_obj(path):
    """Positions (n,3), uvs (m,2) or None, face vertex indices (f,3), face uv indices (f,3) or None."""
    vs, vts, fv, ft = [], [], [], []
    with open(path) as fh:
        for line in fh:
            p = line.split()
            if not p:
                continue
            if p[0] == 'v':
                vs.append([float(x) for x in p[1:4]])
            elif p[0] == 'vt':
                vts.append([float(x) for x in p[1:3]])
            elif p[0] == 'f':
                cs = [c.split('/') for c in p[1:]]
                vi = [int(c[0]) for c in cs]
                vi = [i - 1 if i > 0 else len(vs) + i for i in vi]
                ti = None
                if all(len(c) > 1 and c[1] for c in cs):
                    ti = [int(c[1]) for c in cs]
                    ti = [i - 1 if i > 0 else len(vts) + i for i in ti]
                for k in range(1, len(vi) - 1):  # fan triangulation
                    fv.append([vi[0], vi[k], vi[k + 1]])
                    if ti is not None:
                        ft.append([ti[0], ti[k], ti[k + 1]])
    fv = np.array(fv, dtype=np.int64)
    ft = np.array(ft, dtype=np.int64) if len(ft) == len(fv) and len(fv) else None
    return np.array(vs, dtype=np.float64), np.array(vts, dtype=np.float64), fv, ft


def measure(pos, fv, uv, ft):
    """pos: 3D positions, fv: faces into pos; uv: uvs in [0,1]², ft: faces into uv."""
    P, Q = pos[fv], uv[ft]  # (f,3,3), (f,3,2)
    # --- charts (corners) and seams (edges)
    parent = list(range(len(fv)))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    first = {}
    for f in range(len(fv)):
        for k in range(3):
            corner = (int(fv[f, k]), int(ft[f, k]))
            if corner in first:
                parent[find(f)] = find(first[corner])
            else:
                first[corner] = f
    edges = {}
    for f in range(len(fv)):
        for k in range(3):
            a, b = int(fv[f, k]), int(fv[f, (k + 1) % 3])
            ua, ub = int(ft[f, k]), int(ft[f, (k + 1) % 3])
            key, val = ((a, b), (ua, ub)) if a < b else ((b, a), (ub, ua))
            edges.setdefault(key, []).append((f, val))
    seam = 0.0
    for (a, b), lst in edges.items():
        if len(lst) == 2 and lst[0][1] != lst[1][1]:
            seam += float(np.linalg.norm(pos[a] - pos[b]))
    charts = len({find(f) for f in range(len(fv))})
    # --- stretch
    a3 = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    chart_area = {}
    for f in range(len(fv)):
        chart_area[find(f)] = chart_area.get(find(f), 0.0) + a3[f]
    tiny = sum(1 for v in chart_area.values() if v < 0.01 * a3.sum())
    d1, d2 = Q[:, 1] - Q[:, 0], Q[:, 2] - Q[:, 0]
    auv2 = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]  # twice the signed uv area
    scale = np.sqrt(a3.sum() / (0.5 * np.abs(auv2).sum()))
    ok = (auv2 != 0) & (a3 > 0)
    s, t = Q[ok, :, 0] * scale, Q[ok, :, 1] * scale
    p, A2 = P[ok], auv2[ok] * scale * scale
    Ss = (p[:, 0] * (t[:, 1] - t[:, 2])[:, None] + p[:, 1] * (t[:, 2] - t[:, 0])[:, None]
          + p[:, 2] * (t[:, 0] - t[:, 1])[:, None]) / A2[:, None]
    St = (p[:, 0] * (s[:, 2] - s[:, 1])[:, None] + p[:, 1] * (s[:, 0] - s[:, 2])[:, None]
          + p[:, 2] * (s[:, 1] - s[:, 0])[:, None]) / A2[:, None]
    a, b, c = (Ss * Ss).sum(1), (Ss * St).sum(1), (St * St).sum(1)
    G = np.sqrt(np.maximum((a + c + np.sqrt((a - c) ** 2 + 4 * b * b)) / 2, 0))
    w = a3[ok]
    l2 = np.sqrt((w * (a + c) / 2).sum() / w.sum())
    order = np.argsort(G)
    cum = np.cumsum(w[order])
    g99 = G[order][min(np.searchsorted(cum, 0.99 * cum[-1]), len(G) - 1)]
    # --- texel centres (strictly inside)
    count = np.zeros((RES, RES), dtype=np.int32)
    X = Q * RES  # texel units; centre of texel i is i + 0.5
    for f in np.nonzero(auv2 != 0)[0]:
        x, y = X[f, :, 0], X[f, :, 1]
        i0, i1 = max(int(np.floor(x.min() - 0.5)), 0), min(int(np.ceil(x.max() - 0.5)), RES - 1)
        j0, j1 = max(int(np.floor(y.min() - 0.5)), 0), min(int(np.ceil(y.max() - 0.5)), RES - 1)
        if i1 < i0 or j1 < j0:
            continue
        cx = np.arange(i0, i1 + 1) + 0.5
        cy = (np.arange(j0, j1 + 1) + 0.5)[:, None]
        den = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0])
        l0 = ((x[1] - cx) * (y[2] - cy) - (x[2] - cx) * (y[1] - cy)) / den
        l1 = ((x[2] - cx) * (y[0] - cy) - (x[0] - cx) * (y[2] - cy)) / den
        l2b = ((x[0] - cx) * (y[1] - cy) - (x[1] - cx) * (y[0] - cy)) / den
        inside = (l0 > 0) & (l1 > 0) & (l2b > 0)
        count[j0:j1 + 1, i0:i1 + 1] += inside
    return dict(charts=charts, tiny=tiny, l2=l2, linf=G.max(), g99=g99,
                cover=100.0 * (count > 0).sum() / RES ** 2, twice=int((count >= 2).sum()), seam=seam)


def run_btfquilt(binary, mesh, extra):
    with tempfile.TemporaryDirectory() as tmp:
        gim, exp = os.path.join(tmp, 'm.gim'), os.path.join(tmp, 'exp')
        cmd = [binary, 'atlas', mesh, '--resolution', str(RES), '-o', gim, '-q'] + extra
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        dt = time.perf_counter() - t0
        subprocess.run([binary, 'export', gim, '-o', exp, '-q'], check=True, stdout=subprocess.DEVNULL)
        pos, uv, fv, ft = load_obj(os.path.join(exp, 'mesh.obj'))
    if ft is None:
        sys.exit(f'{mesh}: the exported OBJ has no uvs')
    m = measure(pos, fv, uv, ft)
    m['time'] = dt
    return m


def run_xatlas(mesh):
    import xatlas
    pos, _, fv, _ = load_obj(mesh)
    atlas = xatlas.Atlas()
    atlas.add_mesh(pos.astype(np.float32), fv.astype(np.uint32))
    co, po = xatlas.ChartOptions(), xatlas.PackOptions()
    po.resolution, po.padding = RES, 2
    t0 = time.perf_counter()
    atlas.generate(co, po)
    dt = time.perf_counter() - t0
    vmap, idx, uvs = atlas[0]
    uvs = np.asarray(uvs, dtype=np.float64)
    if uvs.max() > 1.5:  # in texels, not normalised
        uvs = uvs / np.array([atlas.width, atlas.height], dtype=np.float64)
    idx = np.asarray(idx, dtype=np.int64)
    vmap = np.asarray(vmap, dtype=np.int64)
    m = measure(pos, vmap[idx], uvs, idx)
    m['time'] = dt
    return m


FMT = [('charts', '{:d}'), ('tiny', '{:d}'), ('l2', '{:.3f}'), ('linf', '{:.2f}'), ('g99', '{:.2f}'),
       ('cover', '{:.1f} %'), ('twice', '{:d}'), ('seam', '{:.1f}'), ('time', '{:.2f} s')]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--btfquilt', default='target/release/btfquilt')
    ap.add_argument('--args', default='', help='extra arguments for `btfquilt atlas`')
    ap.add_argument('--xatlas', action='store_true', help='measure xatlas too')
    ap.add_argument('--label', default=None, help='name of the btfquilt configuration')
    ap.add_argument('meshes', nargs='+')
    argv = sys.argv[1:]  # let `--args "--compact"` through: glue the value on
    argv = [f'--args={argv[k + 1]}' if a == '--args' and k + 1 < len(argv) else a
            for k, a in enumerate(argv) if not (k and argv[k - 1] == '--args')]
    o = ap.parse_args(argv)
    extra = o.args.split()
    head = ['mesh', 'charts', 'under 1 %', 'L2', 'L∞', 'Γ 99 %', 'texel centres in a chart',
            'covered twice', 'seam length', 'time']
    who = (o.label or 'btfquilt' + (' ' + o.args if o.args else '')) + (' / xatlas' if o.xatlas else '')
    print(f'{who}, {RES}²\n')
    print('| ' + ' | '.join(head) + ' |')
    print('|' + '---|' * len(head))
    tot = [[0, 0.0], [0, 0.0]]
    for mesh in o.meshes:
        rs = [run_btfquilt(o.btfquilt, mesh, extra)]
        if o.xatlas:
            rs.append(run_xatlas(mesh))
        cells = [os.path.splitext(os.path.basename(mesh))[0]]
        for key, fmt in FMT:
            cells.append(' / '.join(fmt.format(r[key]) for r in rs))
        print('| ' + ' | '.join(cells) + ' |', flush=True)
        for k, r in enumerate(rs):
            tot[k][0] += r['charts']
            tot[k][1] += r['seam']
    n = 2 if o.xatlas else 1
    print(f"\nTotals over {len(o.meshes)} meshes: charts {' / '.join(str(t[0]) for t in tot[:n])}, "
          f"seam length {' / '.join(f'{t[1]:.1f}' for t in tot[:n])}")


if __name__ == '__main__':
    main()
