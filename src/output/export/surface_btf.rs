//! The surface BTF of a .quilt: the synthesis map, the factors and
//! appearance functions of its samples, and FORMAT.md describing them.

use super::*;
use crate::math;

/// Channel or column names `prefix00` … for `n` terms (at least two digits).
pub fn term_names(prefix: &str, n: usize) -> Vec<String> {
    let digits = n.saturating_sub(1).to_string().len().max(2);
    (0..n).map(|i| format!("{prefix}{i:0digits$}")).collect()
}

/// A value in the shortest decimal that reads back to the same f32.
fn num(v: f32) -> String {
    format!("{v:?}")
}

/// A sample's file name: `stem.ext` for sample 0, `stem_K.ext` for K ≥ 1.
pub fn sample_file(stem: &str, k: usize, ext: &str) -> String {
    if k == 0 {
        format!("{stem}.{ext}")
    } else {
        format!("{stem}_{k}.{ext}")
    }
}

/// Writes the surface BTF of a decorated mesh into the stage: `svds` and
/// `paths` are its samples in [`Quilt::samples`] order (sharing one direction
/// set, as [`open_samples`](crate::output::open_samples) checks).
pub(super) fn stage_surface_btf(
    quilt_path: &Path,
    quilt: &Quilt,
    svds: &[&SvdArtifact],
    paths: &[PathBuf],
    stage: &mut Stage,
) -> Result<()> {
    let r = quilt.resolution;
    let svd0 = svds[0];
    let (views, lights) = (&svd0.views, &svd0.lights);
    let several = svds.len() > 1;
    let samples: Vec<SampleFacts> = svds
        .iter()
        .zip(paths)
        .map(|(svd, path)| SampleFacts {
            path,
            w: svd.width,
            h: svd.height,
            n: svd.terms,
            tileable: svd.tileable(),
        })
        .collect();

    // synthesis.exr: per atlas texel the sample coordinate and frame (and,
    // with several samples, which one); a first pass over bands checks the
    // samples' extent, the second writes the bands the EXR writer asks for
    let mut covered = 0usize;
    let mut reach = vec![[0f32; 2]; svds.len()];
    for y0 in (0..r).step_by(BAND_ROWS) {
        let h = BAND_ROWS.min(r - y0);
        let coords = quilt.coord_region(0, y0, r, h)?;
        let patches = quilt.patch_region(0, y0, r, h)?;
        let index = quilt.sample_region(0, y0, r, h)?;
        for t in 0..r * h {
            if patches[t] == NO_PATCH {
                continue;
            }
            covered += 1;
            let ([x, y], k) = (coords[t], index[t] as usize);
            reach[k] = [reach[k][0].max(x.abs()), reach[k][1].max(y.abs())];
        }
    }
    for (k, s) in samples.iter().enumerate() {
        if !s.tileable && (reach[k][0] > s.w as f32 || reach[k][1] > s.h as f32) {
            let whose = if several {
                format!(" for its texels of sample {k}")
            } else {
                String::new()
            };
            return Err(Error::input(
                s.path,
                format!(
                    "is {}×{} but {} has sample coordinates up to ({}, {}){whose}: not the sample it was tiled with",
                    s.w,
                    s.h,
                    quilt_path.display(),
                    reach[k][0],
                    reach[k][1]
                ),
            ));
        }
    }
    let path = stage.publish("synthesis.exr");
    let names = ["u", "v", "angle", "dudX", "dvdX", "dudY", "dvdY", "sample"];
    if several {
        write_synthesis(quilt, &path, names)?;
    } else {
        write_synthesis(quilt, &path, std::array::from_fn::<_, 7, _>(|c| names[c]))?;
    }

    for (k, svd) in svds.iter().enumerate() {
        stage_factors(svd, k, views, lights, stage)?;
    }

    // directions.csv: both lists, with unit vectors in the sample frame
    let out = stage.publish("directions.csv");
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        writeln!(f, "set,index,theta,phi,x,y,z").map_err(io)?;
        for (set, list) in [("view", views), ("light", lights)] {
            for (i, a) in list.iter().enumerate() {
                let (st, ct) = math::sin_cos((a.theta as f64).to_radians());
                let (sp, cp) = math::sin_cos((a.phi as f64).to_radians());
                writeln!(
                    f,
                    "{set},{i},{},{},{},{},{}",
                    num(a.theta),
                    num(a.phi),
                    num((st * cp) as f32),
                    num((st * sp) as f32),
                    num(ct as f32)
                )
                .map_err(io)?;
            }
        }
        Ok(())
    })?;

    let facts = Facts {
        quilt: quilt_path,
        samples,
        r,
        views: views.len(),
        lights: lights.len(),
        covered,
    };
    let out = stage.publish("FORMAT.md");
    let text = format_md(&facts);
    imageio::write_atomic(&out, |f| {
        f.write_all(text.as_bytes()).map_err(|e| Error::io(&out, e))
    })
}

/// Rows of a band of the synthesis image: one block of its EXR (ZIP
/// compression packs 16 scanlines a block), which the writer asks for
/// pixel by pixel, block after block.
const SYNTHESIS_ROWS: usize = 16;

/// Bands of the synthesis image held while its EXR is written.
const HELD_BANDS: usize = 2;

/// Blocks the EXR writer holds at once (its uncompressed and compressed
/// copies of the blocks in flight).
const WRITER_BLOCKS: usize = 2;

/// What writing the surface BTF of an `r`² quilt holds besides its caches:
/// [`HELD_BANDS`] bands and [`WRITER_BLOCKS`] blocks of up to 8 f32 channels.
pub(super) fn held_bytes(r: usize) -> u64 {
    ((HELD_BANDS + WRITER_BLOCKS) * SYNTHESIS_ROWS * r * 8 * 4) as u64
}

/// `synthesis.exr` of `quilt`: per covered texel its sample coordinate, the
/// frame's angle and Jacobian (and, with 8 channels, its sample index); NaN
/// elsewhere. Computed by bands of rows as the EXR writer asks for them, the
/// last [`HELD_BANDS`] held.
fn write_synthesis<const N: usize>(quilt: &Quilt, path: &Path, names: [&str; N]) -> Result<()> {
    let r = quilt.resolution;
    let band = |y0: usize| -> Result<Vec<f32>> {
        let h = SYNTHESIS_ROWS.min(r - y0);
        let coords = quilt.coord_region(0, y0, r, h)?;
        let patches = quilt.patch_region(0, y0, r, h)?;
        let index = quilt.sample_region(0, y0, r, h)?;
        let jac = quilt
            .jacobian_region(0, y0, r, h)?
            .ok_or_else(|| Error::input(quilt.container().path(), "it stores no 'jacobian' array"))?;
        let mut out = vec![f32::NAN; r * h * N];
        for t in 0..r * h {
            if patches[t] == NO_PATCH {
                continue;
            }
            let ([x, y], j) = (coords[t], jac[t]);
            let values = [
                x,
                y,
                math::atan2(j[1], j[0]).to_degrees(),
                j[0],
                j[1],
                j[2],
                j[3],
                index[t] as f32,
            ];
            out[t * N..(t + 1) * N].copy_from_slice(&values[..N]);
        }
        Ok(out)
    };
    let held = Mutex::new(BoundedCache::<usize, Vec<f32>>::new(MemoryBudget(
        (HELD_BANDS * SYNTHESIS_ROWS * r * N * 4) as u64,
    )));
    imageio::write_exr_f32_fn(path, r, r, names, |x, y| {
        let mut cache = crate::lock(&held);
        let b = y / SYNTHESIS_ROWS;
        if !cache.contains(&b) {
            let values = band(b * SYNTHESIS_ROWS)?;
            let bytes = (values.len() * 4) as u64;
            cache.insert(b, values, bytes);
        }
        let values = cache.get(&b).expect("just inserted");
        let i = ((y - b * SYNTHESIS_ROWS) * r + x) * N;
        Ok(std::array::from_fn(|c| values[i + c]))
    })
}

/// Writes sample `k`'s factorization: its geometry maps (one f32 channel
/// per term), its appearance table (one row per direction pair of the
/// shared `views` × `lights`) and its singular values, under
/// [`sample_file`] names.
fn stage_factors(
    svd: &SvdArtifact,
    k: usize,
    views: &[crate::artifact::btf::Angles],
    lights: &[crate::artifact::btf::Angles],
    stage: &mut Stage,
) -> Result<()> {
    let (w, h, n) = (svd.width, svd.height, svd.terms);
    let pairs = views.len() * lights.len();

    // geometry_maps.exr: the n maps of the sample, one f32 channel each
    let g = svd.geometry_maps()?;
    let gnames = term_names("g", n);
    let channels: Vec<(String, Vec<f32>)> = gnames
        .iter()
        .enumerate()
        .map(|(i, name)| (name.clone(), g.iter().skip(i).step_by(n).copied().collect()))
        .collect();
    drop(g);
    let out = stage.publish(&sample_file("geometry_maps", k, "exr"));
    imageio::write_exr_channels(&out, w, h, &channels, false)?;
    drop(channels);

    // appearance.csv: p_i(pair, c), one row per pair
    let p = svd.appearance()?;
    let out = stage.publish(&sample_file("appearance", k, "csv"));
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        let mut head = String::from("pair,view_theta,view_phi,light_theta,light_phi");
        for c in ["r", "g", "b"] {
            for name in term_names(c, n) {
                head.push(',');
                head += &name;
            }
        }
        writeln!(f, "{head}").map_err(io)?;
        let mut line = String::new();
        for (pair, row) in p.chunks_exact(3 * n).enumerate().take(pairs) {
            let (v, l) = (views[pair / lights.len()], lights[pair % lights.len()]);
            line.clear();
            let _ = write!(
                line,
                "{pair},{},{},{},{}",
                num(v.theta),
                num(v.phi),
                num(l.theta),
                num(l.phi)
            );
            for &x in row {
                line.push(',');
                line += &num(x);
            }
            writeln!(f, "{line}").map_err(io)?;
        }
        Ok(())
    })?;
    drop(p);

    let sigma = svd.singular_values()?;
    let out = stage.publish(&sample_file("singular_values", k, "csv"));
    imageio::write_atomic(&out, |f| {
        let io = |e| Error::io(&out, e);
        writeln!(f, "term,sigma").map_err(io)?;
        for (i, s) in sigma.iter().enumerate() {
            writeln!(f, "{i},{}", num(*s)).map_err(io)?;
        }
        Ok(())
    })
}

/// What FORMAT.md says about one sample.
struct SampleFacts<'a> {
    pub(super) path: &'a Path,
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) n: usize,
    tileable: bool,
}

struct Facts<'a> {
    quilt: &'a Path,
    /// In [`Quilt::samples`] order.
    samples: Vec<SampleFacts<'a>>,
    pub(super) r: usize,
    views: usize,
    pub(super) lights: usize,
    pub(super) covered: usize,
}

/// The description written beside a surface BTF export.
fn format_md(f: &Facts) -> String {
    let s0 = &f.samples[0];
    let several = f.samples.len() > 1;
    let last = |c: &str| term_names(c, s0.n).pop().unwrap_or_default();
    let (gl, rl, bl) = (last("g"), last("r"), last("b"));
    let pairs = f.views * f.lights;
    let sample = if several {
        let paths: Vec<String> = f
            .samples
            .iter()
            .map(|s| format!("`{}`", s.path.display()))
            .collect();
        format!("samples {}", paths.join(", "))
    } else {
        format!("sample `{}`", s0.path.display())
    };
    let intro = if several {
        format!(
            "A decorated surface: every covered atlas texel of the mesh shows a point of\n\
             one of {count} BTF samples (channel `sample` of `synthesis.exr`), and each\n\
             sample is given as its own rank-n factorization. Here: atlas R×R = {r}×{r}\n\
             ({covered} of {texels} texels covered), {views} views × {lights} lights =\n\
             {pairs} direction pairs shared by all samples:\n\n{samples}\n",
            count = f.samples.len(),
            r = f.r,
            covered = f.covered,
            texels = f.r * f.r,
            samples = f
                .samples
                .iter()
                .enumerate()
                .map(|(k, s)| format!(
                    "- sample {k} (`{}`): W×H = {}×{}, n = {} terms",
                    s.path.display(),
                    s.w,
                    s.h,
                    s.n
                ))
                .collect::<Vec<_>>()
                .join("\n"),
            views = f.views,
            lights = f.lights,
        )
    } else {
        format!(
            "A decorated surface: every covered atlas texel of the mesh shows a point of\n\
             a BTF sample, and the sample is given as its rank-n factorization. Here:\n\
             atlas R×R = {r}×{r} ({covered} of {texels} texels covered), sample W×H =\n\
             {w}×{h}, n = {n} terms, {views} views × {lights} lights = {pairs} direction pairs.",
            r = f.r,
            covered = f.covered,
            texels = f.r * f.r,
            w = s0.w,
            h = s0.h,
            n = s0.n,
            views = f.views,
            lights = f.lights,
        )
    };
    let sample_channel = if several { ", `sample`" } else { "" };
    let mut more_files = String::new();
    for k in 1..f.samples.len() {
        let _ = writeln!(
            more_files,
            "| `{}`, `{}`, `{}` | sample {k}'s, laid out as sample 0's (its own W×H and n) |",
            sample_file("geometry_maps", k, "exr"),
            sample_file("appearance", k, "csv"),
            sample_file("singular_values", k, "csv"),
        );
    }
    let wrap = "coordinates may lie outside it and wrap (x mod W, y mod H, also for the +1 neighbour of the bilinear lookup)";
    let clamp =
        "coordinates lie in [0, W−1]×[0, H−1]; clamp the +1 neighbour of the bilinear lookup at the border";
    let edge = if !several {
        if s0.tileable {
            format!("the sample was factorized `--tileable`: {wrap}")
        } else {
            clamp.to_string()
        }
    } else {
        let tileable: Vec<String> = (0..f.samples.len())
            .filter(|&k| f.samples[k].tileable)
            .map(|k| k.to_string())
            .collect();
        if tileable.is_empty() {
            format!("in every sample {clamp}")
        } else {
            format!(
                "in a sample factorized `--tileable` (here: sample {}) {wrap}; in the others {clamp}",
                tileable.join(", ")
            )
        }
    };
    let sample_texel = if several {
        "\n\n`sample` = the index of the sample the texel shows (0, 1, …, a whole\n\
         number stored as f32): `u`, `v` and the Jacobian are in that sample's pixels."
    } else {
        ""
    };
    let reconstruct_several = if several {
        "\n\nWith several samples, take everything from the texel's own sample s\n\
         (channel `sample`): g_i from `geometry_maps.exr` for s = 0, else\n\
         `geometry_maps_s.exr`; p_i from `appearance.csv`, else `appearance_s.csv`;\n\
         n its number of terms. The g of one sample mean nothing in another's basis:\n\
         never mix one sample's g with another's p, nor blend g vectors of texels\n\
         from different samples; filter across such texels by blending their\n\
         values. The pairs (rows) are the same in every appearance table."
    } else {
        ""
    };
    format!(
        r#"# Surface BTF export

Written by btfquilt {version} from `{quilt}` ({sample}).

{intro}
The mesh with the same atlas uvs: `btfquilt export FILE --format gltf -o DIR`
(`mesh.glb`, `TEXCOORD_0`) or `--format obj` (OBJ's `vt` is y-up: 1 − v).

| file | contents |
|---|---|
| `synthesis.exr` | R×R, f32 channels `u`, `v`, `angle`, `dudX`, `dvdX`, `dudY`, `dvdY`{sample_channel} |
| `geometry_maps.exr` | W×H, f32 channels `g00` … `{gl}`: g_i = σ_i u_i |
| `appearance.csv` | one row per pair: `pair,view_theta,view_phi,light_theta,light_phi,r00..{rl},g00..{gl},b00..{bl}` |
| `directions.csv` | `set,index,theta,phi,x,y,z`: the view list, then the light list |
| `singular_values.csv` | `term,sigma`: σ_i (already folded into g_i; for information) |
{more_files}
CSV: a header row, comma separated, numbers in the shortest decimal that
reads back to the same f32. EXR: scanlines, ZIP compression, lossless f32;
channels are stored in name order, look them up by name.

## Coordinates

- Atlas texel (X, Y): column X, row Y, row 0 at the top. Its centre is uv
  ((X + 0.5)/R, (Y + 0.5)/R) in glTF's convention (origin top left, v down).
- Sample pixel coordinate (x, y): column x, row y, y down, *pixel centres at
  integers* (pixel (i, j) is the point (i, j), not (i + 0.5, j + 0.5)); {edge}.

## synthesis.exr

For a covered texel: `u`, `v` = the sample pixel coordinate (x, y) it shows
(in the unrotated sample); `dudX`, `dvdX` = the sample offset, in pixels, for
one texel step along atlas +X, `dudY`, `dvdY` along +Y (the Jacobian
J = [[dudX, dudY], [dvdX, dvdY]]); `angle` = atan2(dvdX, dudX) in degrees,
[−180, 180]: the direction in the sample that the atlas +X axis points to
(so the sample's +x axis lies at −angle from atlas +X when J is a rotation
and scale). **Empty texels** (the gutter between charts) are **NaN in every
channel**. Look texels up with nearest filtering: neighbouring texels may come
from different patches of the sample.{sample_texel}

## Reconstruction

The BTF value of covered texel (X, Y), direction pair `pair`, colour c ∈
{{r, g, b}}, linear (scene-referred, not sRGB):

    value = Σ_{{i<n}} g_i(u, v) · p_i(pair, c)

with (u, v) from `synthesis.exr` at (X, Y), g_i(u, v) bilinear in
`geometry_maps.exr` (x0 = ⌊u⌋, fx = u − x0, x1 = x0 + 1, likewise y; top =
g(x0,y0) + (g(x1,y0) − g(x0,y0))·fx, bottom the same on row y1, value = top +
(bottom − top)·fy), and p_i(pair, c) in row `pair` of `appearance.csv`,
column c followed by i zero-padded as in the header (`r07`: red, term 7). pair = view · {lights} + light,
both 0-based indices into `directions.csv`. The sum is linear, so summing the
sample first and interpolating afterwards gives the same value.{reconstruct_several}

## Directions and the frame

θ (from the surface normal) and φ (azimuth) are in degrees; `x,y,z` =
(sinθ cosφ, sinθ sinφ, cosθ) in the *sample frame*: x along sample +x
(columns), y along sample +y (rows, down the image), z the outward surface
normal. Directions point away from the surface (to the eye, to the light).

To shade a surface point with outward unit normal N: take the atlas tangents
T_X = ∂P/∂X and T_Y = ∂P/∂Y (position per texel; from a triangle's positions
and uvs, with X = R·u, Y = R·v), and J⁻¹ = [[a, b], [c, d]] from the texel's
Jacobian. The sample axes on the surface are e_x = a·T_X + c·T_Y and
e_y = b·T_X + d·T_Y; make them tangent (subtract their N component) and unit.
A unit world direction ω then has sample-frame components (ω·e_x, ω·e_y,
ω·N): θ = acos(ω·N), φ = atan2(ω·e_y, ω·e_x). Use the components as they are
even where (e_x, e_y, N) is left-handed (a mirrored chart). Take the nearest
listed view and light (or blend neighbours) to find `pair`.
"#,
        version = env!("CARGO_PKG_VERSION"),
        quilt = f.quilt.display(),
        sample = sample,
        intro = intro,
        sample_channel = sample_channel,
        more_files = more_files,
        gl = gl,
        rl = rl,
        bl = bl,
        edge = edge,
        lights = f.lights,
        sample_texel = sample_texel,
        reconstruct_several = reconstruct_several,
    )
}
