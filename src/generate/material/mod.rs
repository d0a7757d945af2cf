//! Procedural, tileable mesostructure for synthetic BTFs.
//!
//! Every field is a pure function of the texel coordinate and the seed
//! (seeded hash value noise, fBm and periodic Voronoi), evaluated in parallel
//! rows, so the result is bit-identical whatever the rayon thread count.
//! All fields are periodic over `width × height`; feature sizes are given in
//! texels, so a larger sample shows more elements of the same size.

use glam::Vec3;
use rayon::prelude::*;

use crate::math;
use crate::rng::{derive, mix64, GOLDEN};

mod noise;
pub(crate) use noise::*;

/// The material family of a synthetic sample (`generate-btf --family`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Family {
    /// Running-bond brick wall with recessed mortar.
    Bricks,
    /// Plain-woven fabric (warp/weft over/under).
    Weave,
    /// Cracked paint flakes over a dark substrate (bark-like).
    Cracked,
    /// Rounded pebbles with dark gaps.
    Pebbles,
}

impl Family {
    /// All families, in a fixed order.
    pub const ALL: [Family; 4] = [Family::Bricks, Family::Weave, Family::Cracked, Family::Pebbles];

    /// Lower-case name used on the command line and in metadata.
    pub fn name(self) -> &'static str {
        match self {
            Family::Bricks => "bricks",
            Family::Weave => "weave",
            Family::Cracked => "cracked",
            Family::Pebbles => "pebbles",
        }
    }

    /// Inverse of [`Family::name`] (case-insensitive; the names clap accepts).
    pub fn parse(s: &str) -> Option<Family> {
        <Self as clap::ValueEnum>::from_str(s.trim(), true).ok()
    }
}

/// An imperfection layer painted over any family (`generate-btf --imperfection`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Imperfection {
    /// No imperfection (mask all zero).
    None,
    /// Thin meandering dark grooves.
    Cracks,
    /// Irregular discoloured blobs (albedo/roughness only).
    Stains,
    /// A few long, straight, thin shallow grooves.
    Scratches,
}

impl Imperfection {
    /// All imperfections, in a fixed order.
    pub const ALL: [Imperfection; 4] = [
        Imperfection::None,
        Imperfection::Cracks,
        Imperfection::Stains,
        Imperfection::Scratches,
    ];

    /// Lower-case name used on the command line and in metadata.
    pub fn name(self) -> &'static str {
        match self {
            Imperfection::None => "none",
            Imperfection::Cracks => "cracks",
            Imperfection::Stains => "stains",
            Imperfection::Scratches => "scratches",
        }
    }

    /// Inverse of [`Imperfection::name`] (case-insensitive; the names clap accepts).
    pub fn parse(s: &str) -> Option<Imperfection> {
        <Self as clap::ValueEnum>::from_str(s.trim(), true).ok()
    }
}

/// Everything that determines a generated mesostructure.
#[derive(Clone, Debug)]
pub struct MaterialParams {
    pub family: Family,
    pub imperfection: Imperfection,
    pub width: usize,
    pub height: usize,
    pub seed: u64,
}

/// Struct-of-arrays mesostructure, row-major `y * width + x`.
///
/// Sample `i = y * width + x` sits at the continuous position `(x, y)`;
/// [`Mesostructure::height_at`] interpolates between samples with toroidal wrap.
pub struct Mesostructure {
    pub width: usize,
    pub height: usize,
    /// Height in texel units (1.0 == one texel spacing), roughly `[0, 3]`.
    pub height_field: Vec<f32>,
    /// Linear RGB diffuse albedo, 0..1.
    pub albedo: Vec<[f32; 3]>,
    /// Specular weight ks, 0..1.
    pub specular: Vec<f32>,
    /// GGX alpha, ~0.05..1.
    pub roughness: Vec<f32>,
    /// Imperfection foreground, 0..1 (all 0 for [`Imperfection::None`]).
    pub mask: Vec<f32>,
    pub max_height: f32,
    pub min_height: f32,
}

impl Mesostructure {
    /// Generate the mesostructure for `p`. Deterministic: the same params give
    /// bit-identical fields whatever the rayon thread count.
    ///
    /// Panics if `width` or `height` is zero.
    pub fn generate(p: &MaterialParams) -> Mesostructure {
        assert!(p.width > 0 && p.height > 0, "mesostructure size must be positive");
        let (w, h) = (p.width, p.height);
        let gen = Gen::new(p);
        let mut texels = vec![Texel::default(); w * h];
        texels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, t) in row.iter_mut().enumerate() {
                *t = gen.texel(x as f32, y as f32);
            }
        });
        if p.imperfection == Imperfection::Stains {
            // `mask` holds the raw stain field here; threshold it at a quantile
            // so the coverage is controlled (and independent of the noise statistics).
            let mut vals: Vec<f32> = texels.iter().map(|t| t.m).collect();
            let cover = 0.07 + 0.1 * unit(hash2(gen.iseed, 11, 3));
            let k = (((1.0 - cover) * vals.len() as f32) as usize).min(vals.len() - 1);
            let (_, thr, _) = vals.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
            let thr = *thr;
            texels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                for (x, t) in row.iter_mut().enumerate() {
                    gen.apply_stain(t, x as f32, y as f32, thr);
                }
            });
        }
        let mut m = Mesostructure {
            width: w,
            height: h,
            height_field: Vec::with_capacity(w * h),
            albedo: Vec::with_capacity(w * h),
            specular: Vec::with_capacity(w * h),
            roughness: Vec::with_capacity(w * h),
            mask: Vec::with_capacity(w * h),
            max_height: f32::MIN,
            min_height: f32::MAX,
        };
        for t in &texels {
            let hh = t.h.max(0.0);
            m.max_height = m.max_height.max(hh);
            m.min_height = m.min_height.min(hh);
            m.height_field.push(hh);
            m.albedo.push(t.a.to_array().map(|c| c.clamp(0.0, 1.0)));
            m.specular.push(t.ks.clamp(0.0, 1.0));
            m.roughness.push(t.r.clamp(0.05, 1.0));
            m.mask.push(t.m.clamp(0.0, 1.0));
        }
        m
    }

    /// Bilinearly interpolated height at the continuous position `(x, y)`
    /// (sample `(i, j)` sits at `(i, j)`), wrapping toroidally.
    #[inline]
    pub fn height_at(&self, x: f32, y: f32) -> f32 {
        let (i0, i1, tx) = wrap_pair(x, self.width);
        let (j0, j1, ty) = wrap_pair(y, self.height);
        let r0 = j0 * self.width;
        let r1 = j1 * self.width;
        let hf = &self.height_field;
        let a = lerp(hf[r0 + i0], hf[r0 + i1], tx);
        let b = lerp(hf[r1 + i0], hf[r1 + i1], tx);
        lerp(a, b, ty)
    }
}

struct Gen {
    family: Family,
    imp: Imperfection,
    dom: Domain,
    /// Family seed.
    seed: u64,
    /// Imperfection seed.
    iseed: u64,
    cells: Cells,
    /// Grid for bricks / yarn cells.
    gx: i64,
    gy: i64,
    gw: f32,
    gh: f32,
    tone: usize,
    scratches: Vec<Scratch>,
    cracks: Vec<Crack>,
}

impl Gen {
    fn new(p: &MaterialParams) -> Gen {
        let dom = Domain {
            w: p.width as f32,
            h: p.height as f32,
        };
        let seed = derive(p.seed, 1 + p.family as u64);
        let iseed = derive(p.seed, 100 + p.imperfection as u64);
        let (fx, fy, even) = match p.family {
            Family::Bricks => (32.0, 14.0, true),
            Family::Weave => (8.0, 8.0, true),
            _ => (16.0, 16.0, false),
        };
        let mut gx = Domain::cells(dom.w, fx);
        let mut gy = Domain::cells(dom.h, fy);
        if even {
            // Running bond and plain weave repeat every two rows/columns.
            gx += gx & 1;
            gy += gy & 1;
        }
        let cell_feature = match p.family {
            Family::Cracked => 18.0,
            _ => 16.0,
        };
        let scratches = if p.imperfection == Imperfection::Scratches {
            Self::make_scratches(&dom, iseed)
        } else {
            Vec::new()
        };
        let cracks = if p.imperfection == Imperfection::Cracks {
            Self::make_cracks(&dom, iseed)
        } else {
            Vec::new()
        };
        Gen {
            cracks,
            family: p.family,
            imp: p.imperfection,
            dom,
            seed,
            iseed,
            cells: Cells::new(&dom, cell_feature, derive(seed, 7)),
            gx,
            gy,
            gw: dom.w / gx as f32,
            gh: dom.h / gy as f32,
            tone: (mix64(seed ^ 77) % 1000) as usize,
            scratches,
        }
    }

    fn make_scratches(dom: &Domain, seed: u64) -> Vec<Scratch> {
        let area = dom.w * dom.h / (128.0 * 128.0);
        let n = ((8.0 + 6.0 * unit(hash2(seed, -1, 0))) * area).round().max(3.0) as i64;
        let min_side = dom.w.min(dom.h);
        (0..n)
            .map(|k| {
                let a = hash2(seed, k, 1);
                let b = hash2(seed, k, 2);
                let ang = std::f32::consts::PI * unit(a);
                Scratch {
                    p: [dom.w * unit_lo(a), dom.h * unit(b)],
                    d: [math::cos(ang), math::sin(ang)],
                    len: (40.0 + 80.0 * unit_lo(b)).min(0.9 * min_side),
                    half_width: 0.55 + 0.4 * unit(hash2(seed, k, 3)),
                    bright: hash2(seed, k, 4) & 1 == 0,
                }
            })
            .collect()
    }

    fn texel(&self, x: f32, y: f32) -> Texel {
        let mut t = match self.family {
            Family::Bricks => self.bricks(x, y),
            Family::Weave => self.weave(x, y),
            Family::Cracked => self.cracked(x, y),
            Family::Pebbles => self.pebbles(x, y),
        };
        match self.imp {
            Imperfection::None => t.m = 0.0,
            Imperfection::Cracks => self.apply_cracks(&mut t, x, y),
            Imperfection::Stains => t.m = self.stain_field(x, y),
            Imperfection::Scratches => self.apply_scratches(&mut t, x, y),
        }
        t
    }

    fn bricks(&self, x: f32, y: f32) -> Texel {
        let d = &self.dom;
        let s = self.seed;
        let row = ((y / self.gh).floor() as i64).rem_euclid(self.gy);
        let y = y - ((y / self.gh).floor() as i64 - row) as f32 * self.gh;
        let shift = if row & 1 == 1 { 0.5 * self.gw } else { 0.0 };
        let xs = x + shift;
        let col = (xs / self.gw).floor() as i64;
        let u = xs - col as f32 * self.gw;
        let v = y - row as f32 * self.gh;
        let col = col.rem_euclid(self.gx);
        let hb = hash2(s, col, row);
        // Distance to the brick outline, roughened for chipped edges.
        let edge = u.min(self.gw - u).min(v).min(self.gh - v) + 1.2 * (d.fbm(x, y, 5.0, 3, s ^ 1) - 0.5);
        let mortar_half = 1.2;
        let t = smoothstep(mortar_half, mortar_half + 1.6, edge);

        let tilt =
            0.25 * (unit(hb) - 0.5) * (u / self.gw - 0.5) + 0.2 * (unit_lo(hb) - 0.5) * (v / self.gh - 0.5);
        let rough_surf = d.fbm(x, y, 6.0, 4, s ^ 2);
        let pits = smoothstep(0.32, 0.22, d.fbm(x, y, 2.5, 2, s ^ 3));
        let brick_h = 2.6 + 0.3 * (unit(hash2(s, col, row + 1000)) - 0.5) + tilt + 0.45 * (rough_surf - 0.5)
            - 0.3 * pits;
        let mortar_h = 0.35 + 0.35 * d.fbm(x, y, 3.0, 3, s ^ 4);

        let base = Vec3::from(BRICK_TONES[self.tone % BRICK_TONES.len()]);
        let other = Vec3::from(BRICK_TONES[(hb >> 3) as usize % BRICK_TONES.len()]);
        let mut brick = lerp3(base, other, 0.6 * unit(hash2(s, col, row + 2000)));
        let bright = 0.75 + 0.45 * unit(hash2(s, col, row + 3000));
        let burnt = if unit(hash2(s, col, row + 4000)) < 0.1 {
            0.55
        } else {
            1.0
        };
        brick *= bright * burnt * (0.8 + 0.4 * d.fbm(x, y, 4.0, 3, s ^ 5)) * (1.0 - 0.35 * pits);
        let mortar = Vec3::new(0.50, 0.48, 0.44) * (0.7 + 0.5 * d.fbm(x, y, 3.0, 2, s ^ 6));
        Texel {
            h: lerp(mortar_h, brick_h, t),
            a: lerp3(mortar, brick, t),
            ks: lerp(0.15, 0.45, t),
            r: lerp(0.9, 0.6 + 0.15 * rough_surf, t),
            m: 0.0,
        }
    }

    fn weave(&self, x: f32, y: f32) -> Texel {
        use std::f32::consts::PI;
        let d = &self.dom;
        let s = self.seed;
        let gu = x / self.gw; // continuous column coordinate
        let gv = y / self.gh; // continuous row coordinate
        let i = gu.floor();
        let j = gv.floor();
        let (u, v) = (gu - i, gv - j);
        let (ii, jj) = (i as i64, j as i64);
        let amp = 0.55;
        let half = 0.43;
        // Warp yarn `i` runs along y, weft yarn `j` along x; they swap
        // over/under every cell.
        let aw = (u - 0.5) / half;
        let af = (v - 0.5) / half;
        let pw = (1.0 - aw * aw).max(0.0).sqrt();
        let pf = (1.0 - af * af).max(0.0).sqrt();
        let zw = amp * math::cos(PI * (gv - 0.5 + ii as f32));
        let zf = -amp * math::cos(PI * (gu - 0.5 + jj as f32));
        // Twisted-ply stripes along each yarn and fibre streaks.
        let ply_w = math::cos(2.0 * PI * (1.5 * u + 2.0 * gv));
        let ply_f = math::cos(2.0 * PI * (1.5 * v + 2.0 * gu));
        let streak_w = d.fbm2(x, y, 1.0, 10.0, 2, s ^ 1);
        let streak_f = d.fbm2(x, y, 10.0, 1.0, 2, s ^ 2);
        let hw = 1.2 + zw + 0.9 * math::powf(pw, 0.7) + 0.08 * ply_w * pw + 0.1 * (streak_w - 0.5);
        let hf = 1.2 + zf + 0.9 * math::powf(pf, 0.7) + 0.08 * ply_f * pf + 0.1 * (streak_f - 0.5);
        let pair = YARN_PAIRS[(self.tone / 7) % YARN_PAIRS.len()].map(Vec3::from);
        let fuzz = 0.9 + 0.2 * d.fbm(x, y, 3.0, 2, s ^ 3);
        let yarn = |col: Vec3, id: i64, ply: f32, streak: f32, p: f32, salt: u64| {
            let var = 0.9 + 0.2 * unit(hash2(s ^ salt, id, 0));
            let shade = var * fuzz * (0.88 + 0.12 * ply) * (0.75 + 0.5 * streak);
            // Slightly darker towards the yarn flanks (fibre occlusion).
            col * (shade * (0.7 + 0.3 * p))
        };
        let floor_h = 0.15 + 0.1 * d.fbm(x, y, 2.0, 2, s ^ 4);
        let warp_vis = pw > 0.0 && (hw >= hf || pf <= 0.0);
        let (h, a, r) = if warp_vis {
            (
                hw,
                yarn(pair[0], ii.rem_euclid(self.gx), ply_w, streak_w, pw, 11),
                0.35,
            )
        } else if pf > 0.0 {
            (
                hf,
                yarn(pair[1], jj.rem_euclid(self.gy), ply_f, streak_f, pf, 12),
                0.35,
            )
        } else {
            (floor_h, lerp3(pair[0], pair[1], 0.5) * 0.3, 0.8)
        };
        let on_yarn = r < 0.5;
        Texel {
            h: h.max(floor_h),
            a,
            ks: if on_yarn { 0.8 } else { 0.1 },
            r: r + 0.1 * (streak_w - 0.5),
            m: 0.0,
        }
    }

    fn cracked(&self, x: f32, y: f32) -> Texel {
        let d = &self.dom;
        let s = self.seed;
        // Warp the lookup slightly so flake borders are not straight.
        let wx = x + 1.5 * (d.fbm(x, y, 7.0, 2, s ^ 1) - 0.5);
        let wy = y + 1.5 * (d.fbm(x, y, 7.0, 2, s ^ 2) - 0.5);
        let c = self.cells.query(wx, wy);
        let crack = 0.35 + 0.6 * d.fbm(x, y, 10.0, 2, s ^ 3);
        let e = c.edge - crack;
        let t = smoothstep(0.0, 0.7, e);
        let curl = 0.45 * math::exp(-(e.max(0.0)) / 1.3) * (0.5 + unit(c.id));
        let tilt_dir = 2.0 * std::f32::consts::PI * unit_lo(c.id);
        let tilt = 0.03 * ((wx - c.site[0]) * math::cos(tilt_dir) + (wy - c.site[1]) * math::sin(tilt_dir));
        let paint_h = 2.1 + 0.15 * d.fbm(x, y, 6.0, 3, s ^ 4) + curl + tilt;
        let sub_h = 0.3 + 0.25 * d.fbm(x, y, 3.0, 3, s ^ 5);
        let paint = Vec3::from(PAINTS[(self.tone / 3) % PAINTS.len()]);
        let grime = d.fbm(x, y, 12.0, 4, s ^ 6);
        let flake_var = 0.9 + 0.2 * unit(c.id >> 5);
        let edge_dirt = 1.0 - 0.3 * math::exp(-(e.max(0.0)) / 1.5);
        let paint_c = paint * (flake_var * (0.75 + 0.45 * grime) * edge_dirt);
        let sub_c = Vec3::new(0.12, 0.08, 0.05) * (0.8 + 0.4 * d.fbm(x, y, 2.0, 2, s ^ 7));
        Texel {
            h: lerp(sub_h, paint_h, t),
            a: lerp3(sub_c, paint_c, t),
            ks: lerp(0.1, 0.6, t),
            r: lerp(0.95, 0.3 + 0.25 * grime, t),
            m: 0.0,
        }
    }

    fn pebbles(&self, x: f32, y: f32) -> Texel {
        let d = &self.dom;
        let s = self.seed;
        let wx = x + 2.0 * (d.fbm(x, y, 9.0, 2, s ^ 1) - 0.5);
        let wy = y + 2.0 * (d.fbm(x, y, 9.0, 2, s ^ 2) - 0.5);
        let c = self.cells.query(wx, wy);
        let gap = 0.5 + 0.4 * d.fbm(x, y, 8.0, 2, s ^ 3);
        let e = c.edge - gap;
        // Radial coordinate adapted to the cell shape: 0 at the site, 1 at the
        // gap. Cutting it below 1 rounds off the polygon corners.
        let r = c.d1 / (c.d1 + e.max(0.0) + 1e-3);
        let rim = 0.8 + 0.12 * unit_lo(c.id >> 11);
        let rr = (r / rim).min(1.0);
        let dome = math::powf((1.0 - rr * rr).max(0.0).sqrt(), 0.7);
        let t = smoothstep(1.0, 0.93, r / rim) * smoothstep(0.0, 0.6, e);
        let ph = 1.6 + 1.1 * unit(c.id);
        let floor_h = 0.1 + 0.2 * d.fbm(x, y, 3.0, 2, s ^ 4);
        let grain = d.fbm(x, y, 3.0, 3, s ^ 5);
        let h = floor_h + t * (ph * dome + 0.12 * (grain - 0.5));
        let base = Vec3::from(STONES[(c.id >> 7) as usize % STONES.len()]);
        let other = Vec3::from(STONES[(c.id >> 17) as usize % STONES.len()]);
        let mut col = lerp3(base, other, 0.4 * unit_lo(c.id));
        let vein_n = d.fbm(x, y, 10.0, 3, s ^ (c.id & 0xffff));
        let vein = smoothstep(0.025, 0.0, (vein_n - 0.5).abs()) * if c.id & 3 == 0 { 1.0 } else { 0.0 };
        col *= (0.8 + 0.4 * grain) * (0.8 + 0.4 * unit(c.id >> 24));
        col = lerp3(col, Vec3::new(0.8, 0.78, 0.74), 0.6 * vein);
        let gap_c = Vec3::new(0.06, 0.05, 0.045) * (0.8 + 0.4 * grain);
        Texel {
            h,
            a: lerp3(gap_c, col, t),
            ks: lerp(0.05, 0.5, t),
            r: lerp(1.0, 0.25 + 0.45 * unit_lo(c.id >> 3), t),
            m: 0.0,
        }
    }

    fn make_cracks(dom: &Domain, seed: u64) -> Vec<Crack> {
        let area = dom.w * dom.h / (128.0 * 128.0);
        let n = ((5.0 + 4.0 * unit(hash2(seed, -1, 0))) * area).round().max(2.0) as i64;
        let min_side = dom.w.min(dom.h);
        let mut out = Vec::new();
        for k in 0..n {
            let a = hash2(seed, k, 1);
            let b = hash2(seed, k, 2);
            let ang = 2.0 * std::f32::consts::PI * unit(a);
            let parent = Crack {
                p: [dom.w * unit_lo(a), dom.h * unit(b)],
                d: [math::cos(ang), math::sin(ang)],
                len: (50.0 + 60.0 * unit_lo(b)).min(0.9 * min_side),
                half_width: 0.6 + 0.5 * unit(hash2(seed, k, 3)),
                amp: 4.0 + 5.0 * unit_lo(hash2(seed, k, 3)),
                seed: hash2(seed, k, 4),
            };
            let c = hash2(seed, k, 5);
            if unit(c) < 0.6 {
                // A thinner branch leaving the crack at a random point.
                let at = parent.len * (0.2 + 0.6 * unit_lo(c));
                let side = if c & 1 == 0 { 1.0 } else { -1.0 };
                let bang = ang + side * (0.5 + 0.6 * unit(hash2(seed, k, 6)));
                out.push(Crack {
                    p: parent.center(at),
                    d: [math::cos(bang), math::sin(bang)],
                    len: parent.len * (0.3 + 0.3 * unit_lo(hash2(seed, k, 6))),
                    half_width: 0.7 * parent.half_width,
                    amp: 0.6 * parent.amp,
                    seed: hash2(seed, k, 7),
                });
            }
            out.push(parent);
        }
        out
    }

    fn apply_cracks(&self, t: &mut Texel, x: f32, y: f32) {
        let (w, h) = (self.dom.w, self.dom.h);
        let (x, y) = (x.rem_euclid(w), y.rem_euclid(h));
        let mut m = 0.0f32;
        for c in &self.cracks {
            for oy in [-h, 0.0, h] {
                for ox in [-w, 0.0, w] {
                    let rx = x + ox - c.p[0];
                    let ry = y + oy - c.p[1];
                    let along = rx * c.d[0] + ry * c.d[1];
                    let across = -rx * c.d[1] + ry * c.d[0];
                    if across.abs() > c.amp + c.half_width + 4.0 || along < -3.0 || along > c.len + 3.0 {
                        continue;
                    }
                    let a = along.clamp(0.0, c.len);
                    let off = c.offset(a);
                    let slope = c.offset(a + 0.5) - c.offset(a - 0.5);
                    let dist =
                        ((along - a).powi(2) + (across - off).powi(2)).sqrt() / (1.0 + slope * slope).sqrt();
                    let u = 2.0 * a / c.len - 1.0;
                    let taper = (1.0 - u * u * u * u).max(0.0).sqrt();
                    let hw = c.half_width * (0.3 + 0.7 * taper);
                    m = m.max(1.0 - smoothstep(0.6 * hw, hw + 0.5, dist));
                }
            }
        }
        t.m = m;
        t.h -= 1.3 * m;
        t.a *= 1.0 - 0.75 * m;
        t.r = lerp(t.r, 0.95, m);
        t.ks *= 1.0 - 0.7 * m;
    }

    /// Raw (unthresholded) stain field.
    fn stain_field(&self, x: f32, y: f32) -> f32 {
        let d = &self.dom;
        let s = self.iseed;
        let wx = x + 10.0 * (d.fbm(x, y, 24.0, 2, s ^ 1) - 0.5);
        let wy = y + 10.0 * (d.fbm(x, y, 24.0, 2, s ^ 2) - 0.5);
        d.fbm(wx, wy, 40.0, 4, s ^ 3)
    }

    fn apply_stain(&self, t: &mut Texel, x: f32, y: f32, thr: f32) {
        let d = &self.dom;
        let s = self.iseed;
        let v = t.m;
        let m = smoothstep(thr - 0.015, thr + 0.015, v);
        // Darker "coffee ring" at the stain border.
        let ring = smoothstep(thr + 0.04, thr, v) * m;
        let tints: [[f32; 3]; 3] = [[0.55, 0.42, 0.25], [0.45, 0.45, 0.40], [0.60, 0.50, 0.30]];
        let tint = Vec3::from(tints[(mix64(s) % 3) as usize]);
        let inner = 0.8 + 0.3 * d.fbm(x, y, 6.0, 3, s ^ 4);
        let stained = t.a * tint * (inner * (1.0 - 0.35 * ring));
        t.a = lerp3(t.a, stained, m);
        t.r = lerp(t.r, t.r * 0.7, m);
        t.ks = lerp(t.ks, (t.ks + 0.2).min(1.0), m);
        t.m = m;
    }

    fn apply_scratches(&self, t: &mut Texel, x: f32, y: f32) {
        let (w, h) = (self.dom.w, self.dom.h);
        let (x, y) = (x.rem_euclid(w), y.rem_euclid(h));
        let mut best = 0.0f32;
        let mut bright = false;
        for sc in &self.scratches {
            let mut dist = f32::MAX;
            for oy in [-h, 0.0, h] {
                for ox in [-w, 0.0, w] {
                    let rx = x + ox - sc.p[0];
                    let ry = y + oy - sc.p[1];
                    let along = (rx * sc.d[0] + ry * sc.d[1]).clamp(0.0, sc.len);
                    let dx = rx - along * sc.d[0];
                    let dy = ry - along * sc.d[1];
                    dist = dist.min((dx * dx + dy * dy).sqrt());
                }
            }
            let m = 1.0 - smoothstep(0.5 * sc.half_width, sc.half_width + 0.4, dist);
            if m > best {
                best = m;
                bright = sc.bright;
            }
        }
        if best > 0.0 {
            t.h -= 0.35 * best;
            let target = if bright {
                (t.a * 1.5 + 0.12).map(|c| c.min(1.0))
            } else {
                t.a * 0.5
            };
            t.a = lerp3(t.a, target, best);
            t.r = lerp(t.r, 0.12, best);
            t.ks = lerp(t.ks, 0.9, best);
        }
        t.m = best;
    }
}

#[cfg(test)]
mod tests;
