//! BTF rendering of a [`Mesostructure`] by ray marching its height field.
//!
//! Conventions: sample `(i, j)` of the height field sits at the continuous
//! position `(i, j)`. The value of texel `(x, y)` for view `v` is the radiance
//! seen along the ray that crosses the mean-height plane at `(x, y)`. The ray is
//! marched down from `max_height` to its first intersection `q` with the
//! (bilinear) height field (parallax + masking); `q` is shaded with a Lambert +
//! GGX model and attenuated by a per-light horizon (cast shadow) map.
//!
//! Every quantity depends only on global (wrapped) texel coordinates, so a texel
//! renders bit-identically in any block of any size.

use glam::Vec3;
use rayon::prelude::*;

use super::material::{lerp, wrap_pair, Mesostructure};
use crate::math;
use crate::mesh::unit_or;

/// Unit vector from polar angle `theta` (from the surface normal +z) and azimuth
/// `phi`, both in degrees: `(sinθcosφ, sinθsinφ, cosθ)`.
pub fn direction(theta_deg: f32, phi_deg: f32) -> [f32; 3] {
    let (st, ct) = math::sin_cos(theta_deg.to_radians());
    let (sp, cp) = math::sin_cos(phi_deg.to_radians());
    [st * cp, st * sp, ct]
}

/// Horizontal ray-march step, in texels.
const STEP: f32 = 0.5;
/// Width of the soft shadow transition, in texels of height.
const SHADOW_SOFT: f32 = 0.1;
/// Ambient term, as a fraction of the albedo.
const AMBIENT: f32 = 0.03;
/// Fresnel reflectance at normal incidence.
const F0: f32 = 0.04;
/// Largest view polar angle the shadow-map margin is sized for; steeper views
/// still work (slower fallback for hit points outside the map).
const MAX_THETA_DEG: f32 = 80.0;
/// Smallest `cot θ` of a view ray (θ ≈ 89.4°), bounding the march length.
const MIN_COT: f32 = 0.01;

/// Light-dependent constants for shadow casting.
struct Light {
    /// Unit direction towards the light.
    l: Vec3,
    /// Horizontal unit direction towards the light.
    dir: [f32; 2],
    /// cot θ of the light.
    cot: f32,
    /// Longest horizontal distance at which an occluder can matter.
    smax: f32,
    /// False for (nearly) vertical lights, which cast no shadow.
    casts: bool,
}

/// Renders all light directions for a block of texels, one view at a time.
///
/// `Sync`: call [`BlockRenderer::render_view`] for different views in parallel.
pub struct BlockRenderer<'a> {
    meso: &'a Mesostructure,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    lights: Vec<Light>,
    /// Global x/y of the shadow map's first grid point (block origin − margin).
    gx0: i64,
    gy0: i64,
    /// Shadow map grid size.
    gw: usize,
    gh: usize,
    /// Horizon heights, layout `[gy][gx][light]`.
    shadow: Vec<f32>,
    /// Height of the reference (mean) plane the texel rays cross.
    z_ref: f32,
    /// Horizon value of non-casting lights (below every surface point).
    no_shadow: f32,
}

impl<'a> BlockRenderer<'a> {
    /// Prepare rendering of the texel block `[x0, x0+w) × [y0, y0+h)` under the
    /// given light directions (unit vectors, z > 0): computes per-light horizon
    /// maps over the block plus a margin covering parallax up to 80°.
    pub fn new(
        meso: &'a Mesostructure,
        x0: usize,
        y0: usize,
        w: usize,
        h: usize,
        lights: &[[f32; 3]],
    ) -> Self {
        let range = (meso.max_height - meso.min_height).max(0.0);
        let lights: Vec<Light> = lights
            .iter()
            .map(|&l| {
                // a zero direction counts as the vertical light
                let l = unit_or(l.into(), Vec3::Z);
                let lxy = (l.x * l.x + l.y * l.y).sqrt();
                if lxy < 1e-4 || l.z <= 0.0 {
                    return Light {
                        l,
                        dir: [0.0, 0.0],
                        cot: 0.0,
                        smax: 0.0,
                        casts: false,
                    };
                }
                let cot = l.z / lxy;
                let smax = range / cot;
                Light {
                    l,
                    dir: [l.x / lxy, l.y / lxy],
                    cot,
                    smax,
                    casts: smax >= STEP,
                }
            })
            .collect();
        let margin = (range * math::tan(MAX_THETA_DEG.to_radians())).ceil() as usize + 2;
        let gw = w + 2 * margin;
        let gh = h + 2 * margin;
        // Mean height, summed sequentially in f64: deterministic.
        let z_ref = (meso.height_field.iter().map(|&v| v as f64).sum::<f64>()
            / meso.height_field.len() as f64) as f32;
        let mut r = BlockRenderer {
            meso,
            x0,
            y0,
            w,
            h,
            lights,
            gx0: x0 as i64 - margin as i64,
            gy0: y0 as i64 - margin as i64,
            gw,
            gh,
            shadow: Vec::new(),
            z_ref,
            no_shadow: meso.min_height - 1.0,
        };
        let nl = r.lights.len();
        let mut shadow = vec![0.0f32; gw * gh * nl];
        if nl > 0 {
            shadow.par_chunks_mut(gw * nl).enumerate().for_each(|(j, row)| {
                let gy = r.gy0 + j as i64;
                for (i, cell) in row.chunks_exact_mut(nl).enumerate() {
                    let gx = r.gx0 + i as i64;
                    for (k, v) in cell.iter_mut().enumerate() {
                        *v = r.horizon(gx, gy, k);
                    }
                }
            });
        }
        r.shadow = shadow;
        r
    }

    /// Horizon height `z_s = max_{s>0} h(p + s·dir) − s·cotθ` at the (wrapped)
    /// global grid point `(gx, gy)` for light `k`.
    fn horizon(&self, gx: i64, gy: i64, k: usize) -> f32 {
        let light = &self.lights[k];
        if !light.casts {
            return self.no_shadow;
        }
        let m = self.meso;
        let px = gx.rem_euclid(m.width as i64) as f32;
        let py = gy.rem_euclid(m.height as i64) as f32;
        let mut best = f32::MIN;
        let mut s = STEP;
        while s <= light.smax {
            let drop = s * light.cot;
            if m.max_height - drop <= best {
                break;
            }
            let z = m.height_at(px + s * light.dir[0], py + s * light.dir[1]) - drop;
            best = best.max(z);
            s += STEP;
        }
        best
    }

    /// First intersection of the view ray of texel `(x, y)` with the height field.
    fn trace(&self, x: f32, y: f32, v: Vec3) -> [f32; 3] {
        let m = self.meso;
        let vxy = (v.x * v.x + v.y * v.y).sqrt();
        if vxy < 1e-6 {
            return [x, y, m.height_at(x, y)];
        }
        let (dx, dy) = (-v.x / vxy, -v.y / vxy);
        let cot = (v.z / vxy).max(MIN_COT);
        let tan = 1.0 / cot;
        let t_top = (m.max_height - self.z_ref) * tan;
        let s_end = (m.max_height - m.min_height) * tan;
        let (ox, oy) = (x - dx * t_top, y - dy * t_top);
        // Signed height of the ray above the surface at march distance s.
        let f = |s: f32| (m.max_height - s * cot) - m.height_at(ox + dx * s, oy + dy * s);
        let point = |s: f32| [ox + dx * s, oy + dy * s, m.max_height - s * cot];
        let mut s0 = 0.0f32;
        let mut f0 = f(s0);
        if f0 <= 0.0 {
            return point(s0);
        }
        loop {
            let s1 = (s0 + STEP).min(s_end);
            let mut f1 = f(s1);
            if f1 <= 0.0 {
                // Regula falsi refinement; f0 > 0 >= f1 throughout.
                let mut s1 = s1;
                for _ in 0..4 {
                    let sm = s0 + (s1 - s0) * f0 / (f0 - f1);
                    let fm = f(sm);
                    if fm > 0.0 {
                        s0 = sm;
                        f0 = fm;
                    } else {
                        s1 = sm;
                        f1 = fm;
                    }
                }
                return point(s0 + (s1 - s0) * f0 / (f0 - f1));
            }
            if s1 >= s_end {
                // Only reachable through rounding: the ray is at min_height.
                return point(s_end);
            }
            s0 = s1;
            f0 = f1;
        }
    }

    /// Render every light for one view direction into `out`
    /// (len `w*h*lights*3`), layout `[y][x][light][rgb]`, linear radiance.
    ///
    /// Radiance for unit irradiance normalisation `E = π`: diffuse
    /// `albedo·max(n·l,0)`, specular `ks·π·D·F·G/(4 n·v n·l)·max(n·l,0)`, both
    /// times the shadow visibility, plus `0.03·albedo` ambient.
    pub fn render_view(&self, view: [f32; 3], out: &mut [f32]) {
        let nl = self.lights.len();
        assert_eq!(out.len(), self.w * self.h * nl * 3, "render_view: output length");
        if nl == 0 {
            return;
        }
        // a zero view (and a zero half vector) counts as the vertical one
        let v = unit_or(view.into(), Vec3::Z);
        let m = self.meso;
        // Half vectors and Fresnel are texel-independent for distant view/light.
        let half: Vec<(Vec3, f32)> = self
            .lights
            .iter()
            .map(|lt| {
                let hv = unit_or(v + lt.l, Vec3::Z);
                let c = (1.0 - v.dot(hv).max(0.0)).clamp(0.0, 1.0);
                let c2 = c * c;
                (hv, F0 + (1.0 - F0) * c2 * c2 * c)
            })
            .collect();
        let mut scratch = vec![0.0f32; 4 * nl];
        for ty in 0..self.h {
            for tx in 0..self.w {
                let gx = (self.x0 + tx) as f32;
                let gy = (self.y0 + ty) as f32;
                let q = self.trace(gx, gy, v);

                // Surface attributes at q (bilinear, wrapped).
                let (i0, i1, fx) = wrap_pair(q[0], m.width);
                let (j0, j1, fy) = wrap_pair(q[1], m.height);
                let idx = [
                    j0 * m.width + i0,
                    j0 * m.width + i1,
                    j1 * m.width + i0,
                    j1 * m.width + i1,
                ];
                let bil = |f: &dyn Fn(usize) -> f32| {
                    lerp(lerp(f(idx[0]), f(idx[1]), fx), lerp(f(idx[2]), f(idx[3]), fx), fy)
                };
                let albedo = Vec3::new(
                    bil(&|i| m.albedo[i][0]),
                    bil(&|i| m.albedo[i][1]),
                    bil(&|i| m.albedo[i][2]),
                );
                let ks = bil(&|i| m.specular[i]);
                let alpha = bil(&|i| m.roughness[i]);
                let a2 = alpha * alpha;
                let hx = 0.5 * (m.height_at(q[0] + 1.0, q[1]) - m.height_at(q[0] - 1.0, q[1]));
                let hy = 0.5 * (m.height_at(q[0], q[1] + 1.0) - m.height_at(q[0], q[1] - 1.0));
                let n = unit_or(Vec3::new(-hx, -hy, 1.0), Vec3::Z);
                let nv = n.dot(v).max(0.0);
                let lam_v = 1.0 / (nv + (a2 + (1.0 - a2) * nv * nv).sqrt());

                // Shadow map corners around q (fallback outside the map).
                let fqx = q[0].floor();
                let fqy = q[1].floor();
                let (sx, sy) = (q[0] - fqx, q[1] - fqy);
                let li = fqx as i64 - self.gx0;
                let lj = fqy as i64 - self.gy0;
                let inside = li >= 0 && lj >= 0 && (li as usize + 1) < self.gw && (lj as usize + 1) < self.gh;
                let (src, b00, b10, b01, b11): (&[f32], usize, usize, usize, usize) = if inside {
                    let b = (lj as usize * self.gw + li as usize) * nl;
                    (&self.shadow, b, b + nl, b + self.gw * nl, b + self.gw * nl + nl)
                } else {
                    let (cx, cy) = (fqx as i64, fqy as i64);
                    for k in 0..nl {
                        scratch[k] = self.horizon(cx, cy, k);
                        scratch[nl + k] = self.horizon(cx + 1, cy, k);
                        scratch[2 * nl + k] = self.horizon(cx, cy + 1, k);
                        scratch[3 * nl + k] = self.horizon(cx + 1, cy + 1, k);
                    }
                    (&scratch, 0, nl, 2 * nl, 3 * nl)
                };

                let base = (ty * self.w + tx) * nl * 3;
                let dst = &mut out[base..base + nl * 3];
                let amb = albedo * AMBIENT;
                for (k, (px, (lt, &(hv, fres)))) in dst
                    .chunks_exact_mut(3)
                    .zip(self.lights.iter().zip(half.iter()))
                    .enumerate()
                {
                    let ndl = n.dot(lt.l);
                    if ndl <= 0.0 {
                        px.copy_from_slice(&amb.to_array());
                        continue;
                    }
                    let zs = lerp(
                        lerp(src[b00 + k], src[b10 + k], sx),
                        lerp(src[b01 + k], src[b11 + k], sx),
                        sy,
                    );
                    let vis = ((q[2] - zs) / SHADOW_SOFT + 1.0).clamp(0.0, 1.0);
                    if vis <= 0.0 {
                        px.copy_from_slice(&amb.to_array());
                        continue;
                    }
                    let nh = n.dot(hv).max(0.0);
                    let d = nh * nh * (a2 - 1.0) + 1.0;
                    let lam_l = 1.0 / (ndl + (a2 + (1.0 - a2) * ndl * ndl).sqrt());
                    // π·D·F·G/(4 n·v n·l)·n·l with separable Smith-GGX G.
                    let spec = ks * a2 / (d * d) * fres * lam_v * lam_l * ndl;
                    let diff = vis * ndl;
                    let sv = vis * spec;
                    px.copy_from_slice(&(amb + albedo * diff + sv).to_array());
                }
            }
        }
    }

    /// Number of lights this renderer was prepared for.
    pub fn num_lights(&self) -> usize {
        self.lights.len()
    }
}

#[cfg(test)]
mod tests {
    use super::super::material::{Family, Imperfection, MaterialParams};
    use super::*;

    fn meso(f: Family, imp: Imperfection, n: usize, seed: u64) -> Mesostructure {
        Mesostructure::generate(&MaterialParams {
            family: f,
            imperfection: imp,
            width: n,
            height: n,
            seed,
        })
    }

    fn standard_lights() -> Vec<[f32; 3]> {
        let mut v = Vec::new();
        for t in 0..8 {
            for p in 0..12 {
                v.push(direction(5.0 + 10.0 * t as f32, 30.0 * p as f32));
            }
        }
        v
    }

    fn render(
        m: &Mesostructure,
        x0: usize,
        y0: usize,
        w: usize,
        h: usize,
        lights: &[[f32; 3]],
        view: [f32; 3],
    ) -> Vec<f32> {
        let r = BlockRenderer::new(m, x0, y0, w, h, lights);
        let mut out = vec![0.0; w * h * lights.len() * 3];
        r.render_view(view, &mut out);
        out
    }

    #[test]
    fn direction_is_unit() {
        let d = direction(0.0, 123.0);
        assert!((d[2] - 1.0).abs() < 1e-6);
        let d = direction(90.0, 90.0);
        assert!(d[0].abs() < 1e-6 && (d[1] - 1.0).abs() < 1e-6 && d[2].abs() < 1e-6);
        let d = direction(37.0, 211.0);
        assert!((Vec3::from(d).length_squared() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn renderer_is_sync() {
        fn assert_sync<T: Sync>() {}
        assert_sync::<BlockRenderer<'static>>();
    }

    #[test]
    fn block_decomposition_independent() {
        let n = 64;
        let m = meso(Family::Bricks, Imperfection::Scratches, n, 9);
        let lights = [
            direction(15.0, 10.0),
            direction(45.0, 100.0),
            direction(75.0, 200.0),
            direction(75.0, 330.0),
            direction(0.0, 0.0),
        ];
        let nl = lights.len();
        for view in [
            direction(0.0, 0.0),
            direction(60.0, 40.0),
            direction(80.0, 250.0),
            direction(88.0, 130.0), // hit points beyond the shadow-map margin
        ] {
            let full = render(&m, 0, 0, n, n, &lights, view);
            for &(x0, y0, w, h) in &[
                (37usize, 5usize, 27usize, 20usize),
                (60, 60, 4, 4),
                (0, 63, 1, 1),
                (13, 40, 9, 17),
            ] {
                let part = render(&m, x0, y0, w, h, &lights, view);
                for y in 0..h {
                    for x in 0..w {
                        let a = &full[((y0 + y) * n + x0 + x) * nl * 3..][..nl * 3];
                        let b = &part[(y * w + x) * nl * 3..][..nl * 3];
                        let ab: Vec<u32> = a.iter().map(|v| v.to_bits()).collect();
                        let bb: Vec<u32> = b.iter().map(|v| v.to_bits()).collect();
                        assert_eq!(ab, bb, "texel ({}, {}) view {view:?}", x0 + x, y0 + y);
                    }
                }
            }
        }
    }

    #[test]
    fn outputs_finite_and_sane() {
        let lights = standard_lights();
        for f in Family::ALL {
            for imp in [Imperfection::None, Imperfection::Scratches] {
                let m = meso(f, imp, 48, 3);
                for view in [direction(0.0, 0.0), direction(45.0, 60.0), direction(75.0, 300.0)] {
                    let out = render(&m, 0, 0, 48, 48, &lights, view);
                    assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0), "{f:?}");
                    let mean = out.iter().sum::<f32>() / out.len() as f32;
                    assert!((0.01..0.8).contains(&mean), "{f:?} {imp:?} mean {mean}");
                    let mut s = out.clone();
                    s.sort_by(|a, b| a.total_cmp(b));
                    let p99 = s[s.len() * 99 / 100];
                    assert!(p99 < 1.5, "{f:?} {imp:?} p99 {p99}");
                }
                // Head-on light, head-on view: values around the albedo.
                let top = render(&m, 0, 0, 48, 48, &[[0.0, 0.0, 1.0]], [0.0, 0.0, 1.0]);
                let mean = top.iter().sum::<f32>() / top.len() as f32;
                let amean =
                    m.albedo.iter().map(|a| a[0] + a[1] + a[2]).sum::<f32>() / (3 * m.albedo.len()) as f32;
                assert!(
                    mean > 0.5 * amean && mean < 1.5 * amean + 0.1,
                    "{f:?} {mean} vs {amean}"
                );
            }
        }
    }

    /// Fraction of texels (head-on view) that get only ambient light.
    fn shadowed_fraction(m: &Mesostructure, light: [f32; 3]) -> f32 {
        let n = m.width;
        let out = render(m, 0, 0, n, m.height, &[light], [0.0, 0.0, 1.0]);
        let mut count = 0;
        for i in 0..n * m.height {
            let s: f32 = out[i * 3..i * 3 + 3].iter().sum();
            let a: f32 = m.albedo[i].iter().sum();
            if s <= AMBIENT * a * 1.001 + 1e-7 {
                count += 1;
            }
        }
        count as f32 / (n * m.height) as f32
    }

    #[test]
    fn shadows_grow_with_light_angle() {
        let m = meso(Family::Bricks, Imperfection::None, 128, 4);
        let mut prev = -1.0;
        let mut fr = Vec::new();
        for theta in [5.0, 25.0, 45.0, 65.0, 75.0, 85.0] {
            let f = shadowed_fraction(&m, direction(theta, 20.0));
            fr.push(f);
            assert!(f >= prev, "fractions {fr:?}");
            prev = f;
        }
        assert!(fr[0] < 0.01, "head-on light shadows {fr:?}");
        assert!(fr[4] > 0.05, "grazing light shadows {fr:?}");
        // Under a grazing light some texels are darker than under a head-on one.
        let a = render(&m, 0, 0, 128, 128, &[direction(5.0, 20.0)], [0.0, 0.0, 1.0]);
        let b = render(&m, 0, 0, 128, 128, &[direction(75.0, 20.0)], [0.0, 0.0, 1.0]);
        let darker = a.iter().zip(&b).filter(|(a, b)| **b < 0.3 * **a).count();
        assert!(darker > a.len() / 50);
    }

    #[test]
    fn cast_shadow_behind_wall() {
        // Flat floor at 0 with a 3-texel-high wall at x in [20, 22].
        let n = 64;
        let mut hf = vec![0.0f32; n * n];
        for y in 0..n {
            for x in 20..=22 {
                hf[y * n + x] = 3.0;
            }
        }
        let m = Mesostructure {
            width: n,
            height: n,
            height_field: hf,
            albedo: vec![[0.5; 3]; n * n],
            specular: vec![0.0; n * n],
            roughness: vec![0.5; n * n],
            mask: vec![0.0; n * n],
            max_height: 3.0,
            min_height: 0.0,
        };
        // Light from +x at 60°: shadow length 3·tan60° ≈ 5.2 texels on the -x side.
        let out = render(&m, 0, 0, n, n, &[direction(60.0, 0.0)], [0.0, 0.0, 1.0]);
        let at = |x: usize| out[(10 * n + x) * 3];
        let lit = 0.5 * 0.5 + 0.5 * AMBIENT;
        assert!((at(16) - 0.5 * AMBIENT).abs() < 1e-4, "{}", at(16)); // in shadow
        assert!((at(13) - lit).abs() < 1e-4, "{}", at(13)); // beyond shadow
        assert!((at(26) - lit).abs() < 1e-4, "{}", at(26)); // lit side
                                                            // A vertical light casts no shadow.
        let out = render(&m, 0, 0, n, n, &[[0.0, 0.0, 1.0]], [0.0, 0.0, 1.0]);
        assert!((out[(10 * n + 16) * 3] - (0.5 + 0.5 * AMBIENT)).abs() < 1e-5);
    }

    #[test]
    fn parallax_shifts_hit_point() {
        // On a flat plane the hit point of a texel ray is the texel itself.
        let n = 16;
        let m = Mesostructure {
            width: n,
            height: n,
            height_field: vec![1.0; n * n],
            albedo: vec![[0.5; 3]; n * n],
            specular: vec![0.0; n * n],
            roughness: vec![0.5; n * n],
            mask: vec![0.0; n * n],
            max_height: 1.0,
            min_height: 1.0,
        };
        let r = BlockRenderer::new(&m, 0, 0, n, n, &[]);
        let q = r.trace(5.0, 7.0, direction(60.0, 30.0).into());
        assert!((q[0] - 5.0).abs() < 1e-4 && (q[1] - 7.0).abs() < 1e-4 && (q[2] - 1.0).abs() < 1e-4);
        // A ray grazing a step hits its face, not the floor behind it.
        let meso = meso(Family::Pebbles, Imperfection::None, 64, 1);
        let r = BlockRenderer::new(&meso, 0, 0, 8, 8, &[]);
        for (x, y) in [(3.0, 4.0), (30.0, 12.0), (50.0, 60.0)] {
            let q = r.trace(x, y, direction(70.0, 45.0).into());
            assert!((q[2] - meso.height_at(q[0], q[1])).abs() < 0.02, "{q:?}");
        }
    }
}
