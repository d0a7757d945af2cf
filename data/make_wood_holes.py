#!/usr/bin/env python3
"""Makes data/wood_holes.png: a 192² wood-like ground with five dark holes,
the same bytes on every run (seeded). Needs Pillow.

Usage: python3 data/make_wood_holes.py [OUT.png]
"""
import math
import os
import random
import sys

from PIL import Image

N = 192


def smooth_noise(period, seed):
    """Value noise on a grid `period` px apart, smoothstep-interpolated."""
    r = random.Random(seed)
    g = N // period + 2
    v = [[r.random() for _ in range(g)] for _ in range(g)]

    def f(x, y):
        gx, gy = x / period, y / period
        i, j = int(gx), int(gy)
        u, w = gx - i, gy - j
        u, w = u * u * (3 - 2 * u), w * w * (3 - 2 * w)
        a = v[j][i] + (v[j][i + 1] - v[j][i]) * u
        b = v[j + 1][i] + (v[j + 1][i + 1] - v[j + 1][i]) * u
        return a + (b - a) * w
    return f


def main():
    rng = random.Random(17)
    n1, n2, n3 = smooth_noise(48, 1), smooth_noise(12, 2), smooth_noise(4, 3)
    # five holes (centre, radius), 25 px apart at least
    holes = []
    while len(holes) < 5:
        cx, cy, r = rng.uniform(20, 172), rng.uniform(20, 172), rng.uniform(6, 11)
        if all(math.hypot(cx - a, cy - b) > r + c + 25 for a, b, c in holes):
            holes.append((cx, cy, r))
    img = Image.new('RGB', (N, N))
    px = img.load()
    for y in range(N):
        for x in range(N):
            # grain: a sine over rows warped by two octaves of noise
            warp = 14 * n1(x, y) + 4 * n2(x, y)
            grain = 0.5 + 0.5 * math.sin(2 * math.pi * (y + warp) / 11.0)
            rough = n3(x, y) - 0.5 + 0.4 * (rng.random() - 0.5)
            t = 0.62 + 0.10 * grain + 0.10 * rough + 0.08 * (n2(x, y) - 0.5)
            col = [t * 0.78, t * 0.58, t * 0.38]
            for cx, cy, r in holes:
                d = math.hypot(x - cx, (y - cy) * 1.35) / r
                if d < 1.4:
                    k = 1.0 if d < 1.0 else (1.4 - d) / 0.4
                    dark = 0.12 + 0.10 * d * d
                    col = [c * (1 - k) + dark * m * k for c, m in zip(col, (0.7, 0.55, 0.45))]
            px[x, y] = tuple(max(0, min(255, round(255 * c))) for c in col)
    default = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'wood_holes.png')
    img.save(sys.argv[1] if len(sys.argv) > 1 else default, optimize=True)


if __name__ == '__main__':
    main()
