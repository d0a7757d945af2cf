//! The FFT side of entire-patch matching: the transform layout, the lanes
//! of the module table packed two by two, 2D transforms that skip padding,
//! and the cached sample spectra.

use super::*;

/// Everything a match needs to know about the shapes involved.
#[derive(Clone, Copy, Debug)]
pub(super) struct Layout {
    pub(super) n: usize,
    pub(super) nc: usize,
    pub(super) lanes: usize,
    pub(super) pairs: usize,
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) dx: (i32, i32),
    pub(super) dy: (i32, i32),
    pub(super) key: CacheKey,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct CacheKey {
    pub(super) key: u64,
    pub(super) width: usize,
    pub(super) height: usize,
    channels: usize,
    pub(super) constraint: Option<usize>,
    pub(super) nx: usize,
    pub(super) ny: usize,
}

/// Lane of M (work side) and of V (sample side), see the module table.
pub(super) fn m_lane(n: usize) -> usize {
    n + 1
}
pub(super) fn v_lane(n: usize) -> usize {
    n
}

/// Placement range and minimal transform length along one axis.
pub(super) fn axis(work: usize, sample: usize, span: Span) -> ((i32, i32), usize) {
    let (w, s) = (work as i32, sample as i32);
    match span {
        Span::Contained => (((w - s).min(0), (w - s).max(0)), work.max(sample)),
        Span::Overlapping => ((-(s - 1), w - 1), work + sample - 1),
    }
}

/// Smallest 2^a·3^b·5^c ≥ n.
pub fn fast_size(n: usize) -> usize {
    let mut best = n.max(1).next_power_of_two();
    let mut p5 = 1;
    while p5 < best {
        let mut p35 = p5;
        while p35 < best {
            let mut v = p35;
            while v < n {
                v *= 2;
            }
            best = best.min(v);
            p35 *= 3;
        }
        p5 *= 5;
    }
    best
}

impl Layout {
    pub(super) fn new(work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<Layout> {
        Layout::with_values(work, sample, sample.image.data.len(), cfg)
    }

    /// [`Layout::new`] for a sample whose values (`values` of them) may be
    /// held apart from its image ([`SampleIn`]).
    pub(super) fn with_values(
        work: &Work,
        sample: &Sample,
        values: usize,
        cfg: &MatchConfig,
    ) -> Result<Layout> {
        let (wi, si) = (&work.image, &sample.image);
        wi.check("work image")?;
        si.check_len("sample", values)?;
        if wi.channels != si.channels {
            return Err(Error::Config(format!(
                "work image has {} channels, sample {}",
                wi.channels, si.channels
            )));
        }
        if work.known.len() != wi.pixels() {
            return Err(Error::Config(format!(
                "known mask: {} values for {}×{}",
                work.known.len(),
                wi.width,
                wi.height
            )));
        }
        if sample.valid.len() != si.pixels() {
            return Err(Error::Config(format!(
                "sample validity: {} values for {}×{}",
                sample.valid.len(),
                si.width,
                si.height
            )));
        }
        let nc = match (&work.constraint, &sample.constraint) {
            (None, None) => None,
            (Some(a), Some(b)) => {
                a.check("work constraint")?;
                b.check("sample constraint")?;
                if (a.width, a.height) != (wi.width, wi.height)
                    || (b.width, b.height) != (si.width, si.height)
                {
                    return Err(Error::Config(
                        "constraint channels differ in size from their images".into(),
                    ));
                }
                if a.channels != b.channels {
                    return Err(Error::Config(format!(
                        "work constraint has {} channels, sample constraint {}",
                        a.channels, b.channels
                    )));
                }
                Some(a.channels)
            }
            _ => {
                return Err(Error::Config(
                    "constraint channels given for only one of work image and sample".into(),
                ))
            }
        };
        if !(cfg.min_overlap.is_finite() && cfg.constraint_weight.is_finite()) || cfg.tolerance.is_nan() {
            return Err(Error::Config(
                "match config: non-finite min_overlap, weight or tolerance".into(),
            ));
        }
        let n = wi.channels;
        let lanes = n + 2 + nc.map_or(0, |c| c + 1);
        let (dx, lx) = axis(wi.width, si.width, cfg.span);
        let (dy, ly) = axis(wi.height, si.height, cfg.span);
        let (nx, ny) = (fast_size(lx), fast_size(ly));
        Ok(Layout {
            n,
            nc: nc.unwrap_or(0),
            lanes,
            pairs: lanes.div_ceil(2),
            nx,
            ny,
            dx,
            dy,
            key: CacheKey {
                key: sample.key,
                width: si.width,
                height: si.height,
                channels: n,
                constraint: nc,
                nx,
                ny,
            },
        })
    }
}

/// Value of work-side lane `c` at pixel `i` (see the module table);
/// `energy[i]` = M(‖I‖² + w‖m0‖²).
#[inline]
pub(super) fn work_lane(work: &Work, lay: &Layout, w: f64, energy: &[f64], c: usize, i: usize) -> f64 {
    let n = lay.n;
    let m = work.known[i] as f64;
    if c < n {
        -2.0 * m * work.image.data[i * n + c] as f64
    } else if c == n {
        energy[i]
    } else if c == n + 1 {
        m
    } else if c == n + 2 {
        w * m
    } else {
        let k = c - n - 3;
        -2.0 * w * m * work.constraint.unwrap().data[i * lay.nc + k] as f64
    }
}

/// A sample's feature values as a match reads them: f32, or the f16 a
/// rotated copy is stored in, widened as they are read (the same values).
#[derive(Clone, Copy)]
pub(super) enum Values<'a> {
    F32(&'a [f32]),
    F16(&'a [half::f16]),
}

impl Values<'_> {
    pub(super) fn len(&self) -> usize {
        match self {
            Values::F32(d) => d.len(),
            Values::F16(d) => d.len(),
        }
    }

    /// Value `k`, as f64.
    #[inline]
    pub(super) fn at(&self, k: usize) -> f64 {
        match self {
            Values::F32(d) => d[k] as f64,
            Values::F16(d) => d[k].to_f32() as f64,
        }
    }

    /// ‖values `range`‖² ([`sum_of_squares`], as [`sq_norm`] sums).
    #[inline]
    pub(super) fn sq_norm(&self, range: std::ops::Range<usize>) -> f64 {
        match self {
            Values::F32(d) => sq_norm(&d[range]),
            Values::F16(d) => sum_of_squares(d[range].iter().map(|x| x.to_f32() as f64)),
        }
    }
}

/// A sample with its feature values ([`Values`]): `sample.image.data` is
/// not read.
#[derive(Clone, Copy)]
pub(super) struct SampleIn<'a> {
    pub(super) sample: Sample<'a>,
    pub(super) values: Values<'a>,
}

/// Value of sample-side lane `c` at pixel `i`; `energy[i]` = V‖S‖²,
/// `cenergy[i]` = V‖mP‖².
#[inline]
pub(super) fn sample_lane(
    sample: &SampleIn,
    lay: &Layout,
    energy: &[f64],
    cenergy: &[f64],
    c: usize,
    i: usize,
) -> f64 {
    let (n, values, sample) = (lay.n, sample.values, &sample.sample);
    let v = sample.valid[i] as f64;
    if c < n {
        v * values.at(i * n + c)
    } else if c == n {
        v
    } else if c == n + 1 {
        energy[i]
    } else if c == n + 2 {
        cenergy[i]
    } else {
        let k = c - n - 3;
        v * sample.constraint.unwrap().data[i * lay.nc + k] as f64
    }
}

pub(super) fn sq_norm(v: &[f32]) -> f64 {
    sum_of_squares(v.iter().map(|&x| x as f64))
}

/// Σ x², in order: the one sum every energy of a match uses, so that
/// f32 and f16 values give the same bits.
#[inline]
fn sum_of_squares(v: impl Iterator<Item = f64>) -> f64 {
    v.map(|x| x * x).sum()
}

/// Packs lanes (2j, 2j+1) of a `width`×`height` image into the first
/// `height` rows (of length `nx`) of `rows`, zero-padded.
pub(super) fn pack_pair(
    rows: &mut [C64],
    nx: usize,
    width: usize,
    height: usize,
    lanes: usize,
    j: usize,
    lane: impl Fn(usize, usize) -> f64,
) {
    let (a, b) = (2 * j, 2 * j + 1);
    for (y, row) in rows[..height * nx].chunks_exact_mut(nx).enumerate() {
        for (x, v) in row[..width].iter_mut().enumerate() {
            let i = y * width + x;
            *v = C64::new(lane(a, i), if b < lanes { lane(b, i) } else { 0.0 });
        }
        row[width..].fill(ZERO);
    }
}

/// FFT plans of one transform size.
pub(super) struct Plans {
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) fx: Arc<dyn Fft<f64>>,
    pub(super) fy: Arc<dyn Fft<f64>>,
    pub(super) ix: Arc<dyn Fft<f64>>,
    pub(super) iy: Arc<dyn Fft<f64>>,
}

/// In-place FFTs of consecutive length-`len` rows of `buf`, in parallel.
pub(super) fn fft_rows(fft: &Arc<dyn Fft<f64>>, len: usize, buf: &mut [C64]) {
    let per = (TASK_ELEMS / len).max(1) * len;
    let scratch = fft.get_inplace_scratch_len();
    buf.par_chunks_mut(per).for_each_init(
        || vec![ZERO; scratch],
        |s, chunk| fft.process_with_scratch(chunk, s),
    );
}

/// Columns `kx0..` of the row-transformed `rows` (`h` rows of `nx`) into the
/// spectrum chunk `out` (`[kx][ky]`, columns of `ny`), zero-padded and
/// transformed along y.
fn column_stage(p: &Plans, rows: &[C64], h: usize, kx0: usize, out: &mut [C64], scratch: &mut [C64]) {
    let (nx, ny) = (p.nx, p.ny);
    let cols = out.len() / ny;
    for y in 0..h {
        let src = &rows[y * nx + kx0..y * nx + kx0 + cols];
        for (j, v) in src.iter().enumerate() {
            out[j * ny + y] = *v;
        }
    }
    for col in out.chunks_exact_mut(ny) {
        col[h..].fill(ZERO);
    }
    p.fy.process_with_scratch(out, scratch);
}

/// Columns per parallel task of the column stage.
pub(super) fn cols_per_task(ny: usize) -> usize {
    (TASK_ELEMS / ny).max(1)
}

/// 2D forward FFT of `h` packed rows into `spec` (`[kx][ky]`); then, if
/// `acc` is given, `acc += spec · conj(ys)`.
pub(super) fn forward_2d(
    p: &Plans,
    rows: &mut [C64],
    h: usize,
    spec: &mut [C64],
    acc: Option<(&mut [C64], &[C64])>,
) {
    let (nx, ny) = (p.nx, p.ny);
    fft_rows(&p.fx, nx, &mut rows[..h * nx]);
    let rows: &[C64] = rows;
    let per = cols_per_task(ny);
    let scratch = p.fy.get_inplace_scratch_len();
    let spec = &mut spec[..nx * ny];
    match acc {
        None => spec.par_chunks_mut(per * ny).enumerate().for_each_init(
            || vec![ZERO; scratch],
            |s, (ci, out)| column_stage(p, rows, h, ci * per, out, s),
        ),
        Some((acc, ys)) => spec
            .par_chunks_mut(per * ny)
            .zip(acc[..nx * ny].par_chunks_mut(per * ny))
            .zip(ys[..nx * ny].par_chunks(per * ny))
            .enumerate()
            .for_each_init(
                || vec![ZERO; scratch],
                |s, (ci, ((out, acc), ys))| {
                    column_stage(p, rows, h, ci * per, out, s);
                    accumulate(acc, out, ys);
                },
            ),
    }
}

/// `acc += zs · conj(ys)`, element by element.
#[inline]
pub(super) fn accumulate(acc: &mut [C64], zs: &[C64], ys: &[C64]) {
    for ((a, z), y) in acc.iter_mut().zip(zs).zip(ys) {
        *a += z * y.conj();
    }
}

/// Index of the spectrum entry at −k.
#[inline]
pub(super) fn neg_index(nx: usize, ny: usize, i: usize) -> usize {
    let (kx, ky) = (i / ny, i % ny);
    ((nx - kx) % nx) * ny + (ny - ky) % ny
}

/// The spectrum of the real (`part` 0) or imaginary (`part` 1) lane of a
/// packed spectrum z: (z(k) + conj z(−k))/2 or (z(k) − conj z(−k))/(2i).
pub(super) fn unpack_lane(nx: usize, ny: usize, z: &[C64], part: usize, out: &mut [C64]) {
    let per = cols_per_task(ny) * ny;
    out[..nx * ny]
        .par_chunks_mut(per)
        .enumerate()
        .for_each(|(ci, chunk)| {
            for (o, v) in chunk.iter_mut().enumerate() {
                let i = ci * per + o;
                let (a, b) = (z[i], z[neg_index(nx, ny, i)].conj());
                *v = if part == 0 {
                    (a + b) * 0.5
                } else {
                    (a - b) * C64::new(0.0, -0.5)
                };
            }
        });
}

/// The sample side of one (key, transform size): packed lane spectra and
/// F(V).
pub(super) struct SampleSpectra {
    pub(super) pairs: Vec<C64>,
    pub(super) fv: Vec<C64>,
    pub(super) max_valid: f64,
}

impl SampleSpectra {
    pub(super) fn bytes(&self) -> usize {
        (self.pairs.len() + self.fv.len()) * std::mem::size_of::<C64>()
    }
}

/// What the kept work spectra were computed for: the caller's key and the
/// transform layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct WorkTag {
    pub(super) key: u64,
    pub(super) nx: usize,
    pub(super) ny: usize,
    /// Feature channels and all lanes (features, constraint, energy, mask).
    pub(super) n: usize,
    pub(super) lanes: usize,
    /// The constraint weight's bits (it scales the work's lanes).
    pub(super) weight: u64,
}
