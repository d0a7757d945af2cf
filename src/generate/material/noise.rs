//! The procedural building blocks of the materials: interpolation, hashed
//! value noise and fBm, Voronoi cells, cracks, scratches and palettes.

use super::*;

/// Split a continuous coordinate into the two wrapped sample indices around it
/// and the fraction between them.
#[inline]
pub(crate) fn wrap_pair(x: f32, n: usize) -> (usize, usize, f32) {
    let f = x.floor();
    let t = x - f;
    let i0 = (f as i64).rem_euclid(n as i64) as usize;
    let i1 = if i0 + 1 == n { 0 } else { i0 + 1 };
    (i0, i1, t)
}

#[inline]
pub(crate) fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a + (b - a) * t
}

/// [`lerp`] of each component, `a + (b − a) t` (glam's `Vec3::lerp`
/// computes `a (1 − t) + b t`, which rounds differently).
#[inline]
pub(super) fn lerp3(a: Vec3, b: Vec3, t: f32) -> Vec3 {
    a + (b - a) * t
}

#[inline]
pub(super) fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

// ---------------------------------------------------------------------------
// Hashing and noise
// ---------------------------------------------------------------------------

/// Hash of a seed and two integer coordinates.
#[inline]
pub(super) fn hash2(seed: u64, a: i64, b: i64) -> u64 {
    let h = mix64(seed.wrapping_add(GOLDEN) ^ 0x243f_6a88_85a3_08d3);
    let h = mix64(h.wrapping_add((a as u64).wrapping_mul(GOLDEN)));
    mix64(h ^ (b as u64).wrapping_add(0x1319_8a2e_0370_7344))
}

/// Top 24 bits of a hash as a float in `[0, 1)`.
#[inline]
pub(super) fn unit(h: u64) -> f32 {
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

/// Second independent float in `[0, 1)` from the low bits of a hash.
#[inline]
pub(super) fn unit_lo(h: u64) -> f32 {
    ((h >> 8) & 0xff_ffff) as f32 * (1.0 / 16_777_216.0)
}

#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Periodic value noise in `[0, 1)` on a lattice of `px × py` cells; `(u, v)`
/// are in cell units.
#[inline]
fn value_noise(u: f32, v: f32, px: i64, py: i64, seed: u64) -> f32 {
    let fu = u.floor();
    let fv = v.floor();
    let su = fade(u - fu);
    let sv = fade(v - fv);
    let i0 = (fu as i64).rem_euclid(px);
    let j0 = (fv as i64).rem_euclid(py);
    let i1 = (i0 + 1) % px;
    let j1 = (j0 + 1) % py;
    let a = unit(hash2(seed, i0, j0));
    let b = unit(hash2(seed, i1, j0));
    let c = unit(hash2(seed, i0, j1));
    let d = unit(hash2(seed, i1, j1));
    lerp(lerp(a, b, su), lerp(c, d, su), sv)
}

/// The periodic domain `[0, w) × [0, h)` with feature-size based noise.
#[derive(Clone, Copy)]
pub(super) struct Domain {
    pub(super) w: f32,
    pub(super) h: f32,
}

impl Domain {
    /// Number of lattice cells so that one cell is about `feature` texels.
    pub(super) fn cells(extent: f32, feature: f32) -> i64 {
        ((extent / feature).round() as i64).max(1)
    }

    /// Anisotropic periodic fBm in `[0, 1)`, features `fx × fy` texels at the
    /// coarsest octave.
    pub(super) fn fbm2(&self, x: f32, y: f32, fx: f32, fy: f32, octaves: u32, seed: u64) -> f32 {
        let cx = Self::cells(self.w, fx);
        let cy = Self::cells(self.h, fy);
        let mut sum = 0.0;
        let mut norm = 0.0;
        let mut amp = 1.0;
        for o in 0..octaves {
            let px = cx << o;
            let py = cy << o;
            let u = x * px as f32 / self.w;
            let v = y * py as f32 / self.h;
            sum += amp * value_noise(u, v, px, py, seed.wrapping_add(o as u64 * GOLDEN));
            norm += amp;
            amp *= 0.5;
        }
        sum / norm
    }

    /// Isotropic periodic fBm in `[0, 1)`.
    pub(super) fn fbm(&self, x: f32, y: f32, feature: f32, octaves: u32, seed: u64) -> f32 {
        self.fbm2(x, y, feature, feature, octaves, seed)
    }
}

/// Result of a periodic Voronoi query.
pub(super) struct VorHit {
    /// Hash identifying the (wrapped) cell.
    pub(super) id: u64,
    /// Nearest site, unwrapped (near the query point), in texels.
    pub(super) site: [f32; 2],
    /// Distance to the nearest site.
    pub(super) d1: f32,
    /// Distance to the nearest cell border.
    pub(super) edge: f32,
}

/// Periodic jittered-grid Voronoi diagram.
pub(super) struct Cells {
    pub(super) nx: i64,
    pub(super) ny: i64,
    cw: f32,
    ch: f32,
    pub(super) seed: u64,
}

impl Cells {
    pub(super) fn new(dom: &Domain, feature: f32, seed: u64) -> Cells {
        let nx = Domain::cells(dom.w, feature);
        let ny = Domain::cells(dom.h, feature);
        Cells {
            nx,
            ny,
            cw: dom.w / nx as f32,
            ch: dom.h / ny as f32,
            seed,
        }
    }

    #[inline]
    pub(super) fn site(&self, i: i64, j: i64) -> [f32; 2] {
        let h = hash2(self.seed, i.rem_euclid(self.nx), j.rem_euclid(self.ny));
        let jx = 0.8 * (unit(h) - 0.5);
        let jy = 0.8 * (unit_lo(h) - 0.5);
        [(i as f32 + 0.5 + jx) * self.cw, (j as f32 + 0.5 + jy) * self.ch]
    }

    pub(super) fn query(&self, x: f32, y: f32) -> VorHit {
        let ci = (x / self.cw).floor() as i64;
        let cj = (y / self.ch).floor() as i64;
        let mut best = (f32::MAX, ci, cj, [0.0f32; 2]);
        for j in cj - 1..=cj + 1 {
            for i in ci - 1..=ci + 1 {
                let s = self.site(i, j);
                let d2 = (s[0] - x).powi(2) + (s[1] - y).powi(2);
                if d2 < best.0 {
                    best = (d2, i, j, s);
                }
            }
        }
        let (d2, bi, bj, s) = best;
        let mut edge = f32::MAX;
        for j in bj - 2..=bj + 2 {
            for i in bi - 2..=bi + 2 {
                if i == bi && j == bj {
                    continue;
                }
                let o = self.site(i, j);
                let (ex, ey) = (o[0] - s[0], o[1] - s[1]);
                let len = (ex * ex + ey * ey).sqrt().max(1e-6);
                let (mx, my) = (0.5 * (o[0] + s[0]), 0.5 * (o[1] + s[1]));
                edge = edge.min(((mx - x) * ex + (my - y) * ey) / len);
            }
        }
        VorHit {
            id: hash2(
                self.seed ^ 0x5bd1_e995,
                bi.rem_euclid(self.nx),
                bj.rem_euclid(self.ny),
            ),
            site: s,
            d1: d2.sqrt(),
            edge: edge.max(0.0),
        }
    }
}

// ---------------------------------------------------------------------------
// Per-texel fields, cracks, scratches and palettes
// ---------------------------------------------------------------------------

/// All fields of one texel.
#[derive(Clone, Copy, Default)]
pub(super) struct Texel {
    pub(super) h: f32,
    pub(super) a: Vec3,
    pub(super) ks: f32,
    pub(super) r: f32,
    pub(super) m: f32,
}

/// 1-D value-noise fBm in `[0, 1)` (not periodic), `t` in lattice units.
fn fbm1(t: f32, octaves: u32, seed: u64) -> f32 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    let mut amp = 1.0;
    let mut f = 1.0;
    for o in 0..octaves {
        let u = t * f;
        let i = u.floor();
        let s = seed.wrapping_add(o as u64 * GOLDEN);
        let a = unit(hash2(s, i as i64, 0));
        let b = unit(hash2(s, i as i64 + 1, 0));
        sum += amp * lerp(a, b, fade(u - i));
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// A meandering crack: a segment whose centre line is displaced sideways by
/// 1-D noise of the distance along it.
pub(super) struct Crack {
    pub(super) p: [f32; 2],
    pub(super) d: [f32; 2],
    pub(super) len: f32,
    pub(super) half_width: f32,
    pub(super) amp: f32,
    pub(super) seed: u64,
}

impl Crack {
    /// Sideways displacement of the centre line at distance `a` (0 at the start).
    pub(super) fn offset(&self, a: f32) -> f32 {
        let raw = |a: f32| {
            2.0 * self.amp * (fbm1(a / 28.0, 2, self.seed) - 0.5)
                + 2.5 * (fbm1(a / 3.5, 2, self.seed ^ 1) - 0.5)
        };
        raw(a) - raw(0.0)
    }

    /// Centre-line point at distance `a`.
    pub(super) fn center(&self, a: f32) -> [f32; 2] {
        let o = self.offset(a);
        [
            self.p[0] + a * self.d[0] - o * self.d[1],
            self.p[1] + a * self.d[1] + o * self.d[0],
        ]
    }
}

/// A straight scratch segment.
pub(super) struct Scratch {
    pub(super) p: [f32; 2],
    pub(super) d: [f32; 2],
    pub(super) len: f32,
    pub(super) half_width: f32,
    pub(super) bright: bool,
}

pub(super) const BRICK_TONES: [[f32; 3]; 5] = [
    [0.46, 0.16, 0.09],
    [0.38, 0.20, 0.12],
    [0.56, 0.30, 0.17],
    [0.30, 0.12, 0.08],
    [0.50, 0.24, 0.14],
];

pub(super) const YARN_PAIRS: [[[f32; 3]; 2]; 5] = [
    [[0.05, 0.08, 0.24], [0.58, 0.49, 0.34]],
    [[0.45, 0.06, 0.05], [0.72, 0.66, 0.55]],
    [[0.10, 0.25, 0.10], [0.50, 0.40, 0.25]],
    [[0.30, 0.30, 0.32], [0.06, 0.06, 0.07]],
    [[0.12, 0.20, 0.40], [0.76, 0.75, 0.72]],
];

pub(super) const PAINTS: [[f32; 3]; 6] = [
    [0.78, 0.76, 0.70],
    [0.20, 0.45, 0.45],
    [0.52, 0.12, 0.08],
    [0.70, 0.55, 0.20],
    [0.45, 0.60, 0.72],
    [0.25, 0.42, 0.20],
];

pub(super) const STONES: [[f32; 3]; 6] = [
    [0.45, 0.44, 0.42],
    [0.35, 0.30, 0.25],
    [0.58, 0.52, 0.44],
    [0.24, 0.24, 0.25],
    [0.50, 0.38, 0.28],
    [0.66, 0.64, 0.60],
];
