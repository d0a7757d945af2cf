//! The sample on the surface: its geometry maps and rotated copies, read
//! through the `.svd` (section III-A), and the factorization of a colour image
//! on the fly.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::coarse::Coarse;
use super::matching::Image;
use crate::artifact::svd::SvdArtifact;
use crate::container::{BoundedCache, MemoryBudget, Scratch};
use crate::factorize::FactorizeConfig;
use crate::progress::Progress;
use crate::{factorize, Error, Result};

/// A rotated copy of the sample: its maps and validity as f32.
pub(super) type RotatedCopy = (Vec<f32>, Vec<f32>);

/// A whole rotated copy to match against ([`Sample::rotation_to_match`]).
pub(super) enum WholeCopy {
    F32(Arc<RotatedCopy>),
    /// The stored f16 maps and the validity as f32.
    F16(Vec<half::f16>, Vec<f32>),
}

/// The "downsampling factor" under which the rotated copies' cache keeps
/// the foreground mask's copies (its maps the mask, one channel).
const MASK: usize = 0;

/// The sample: unrotated geometry maps, and rotated copies on demand.
pub(super) struct Sample {
    pub(super) svd: SvdArtifact,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) n: usize,
    /// The leading geometry-map terms matching reads ([`Sample::set_match_terms`]);
    /// every stored term unless fewer were asked for.
    pub(super) match_terms: usize,
    pub(super) maps: Vec<f32>,
    pub(super) tileable: bool,
    /// How many rotated copies there are (5° steps for 72).
    pub(super) rotations: usize,
    /// Rotated copies as f32 (maps, validity), loaded lazily into a cache
    /// bounded by the budget given in [`Sample::from_svd`] (shared by the
    /// work patches computed at once), keyed by (rotation, downsampling
    /// factor): factor 1 is the copy itself, f > 1 its f×f block means
    /// ([`Sample::coarse_rotation`]), [`MASK`] the foreground mask's copy.
    rotated: Mutex<BoundedCache<(usize, usize), Arc<RotatedCopy>>>,
    /// The largest whole rotated copy loaded that its cache could not
    /// hold: the match that loaded it holds it alone
    /// ([`Sample::uncached_bytes`]).
    uncached: AtomicU64,
    /// Coarse copies made from rectangles of the copies, kept on disk
    /// ([`Sample::spill_beside`]) so that making one again is a read.
    spill: Mutex<Spill>,
    /// Matched coarse to fine: no whole rotated copy is loaded
    /// ([`Sample::read_by_rectangles`]).
    by_rectangles: bool,
    /// The foreground mask m_P (`[y][x]`, 0..1), if painting or keeping the
    /// foreground out.
    pub(super) mask: Option<Vec<f32>>,
    /// The weighted structure channel (`[y][x]`), when it is on: the last of
    /// the `n` feature channels of `maps` and of every rotated copy.
    pub(super) structure: Option<Vec<f32>>,
    /// The sample's courses, when its features run in rows and they were
    /// looked for ([`Sample::find_courses`]).
    pub(super) courses: Option<super::courses::Courses>,
}

impl Sample {
    /// Reads the unrotated geometry maps; rotated copies and the mask come
    /// later, on demand.
    pub(super) fn from_svd(svd: SvdArtifact, rotated_budget: MemoryBudget) -> Result<Sample> {
        let tileable = svd.tileable();
        let rotations = if svd.rotations > 0 {
            svd.rotations
        } else {
            factorize::DEFAULT_ROTATIONS
        };
        Ok(Sample {
            courses: None,
            width: svd.width,
            height: svd.height,
            n: svd.terms,
            match_terms: svd.terms,
            maps: svd.geometry_maps()?,
            tileable,
            rotations,
            rotated: Mutex::new(BoundedCache::new(rotated_budget)),
            uncached: AtomicU64::new(0),
            spill: Mutex::new(Spill::default()),
            by_rectangles: false,
            mask: None,
            structure: None,
            svd,
        })
    }

    /// Looks for the sample's courses in its preview's row profile, read
    /// in bands ([`SvdArtifact::preview_row_means`]); a preview that
    /// cannot be read only means none are found.
    pub(super) fn find_courses(&mut self) {
        self.courses = self
            .svd
            .preview_row_means()
            .ok()
            .and_then(|rows| super::courses::Courses::from_profile(&rows));
    }

    /// Looks for the courses of the original sample `sized` was resampled
    /// from (where a quilt's stored rows are judged, `evaluate`), in this
    /// resampled copy's rows; the same as [`Sample::find_courses`] when
    /// the sample was not resampled.
    pub(super) fn find_original_courses(&mut self, sized: &SizedSample) -> Result<()> {
        let rows = SvdArtifact::open(&sized.original, MemoryBudget(1 << 20))?.preview_row_means()?;
        self.courses = super::courses::Courses::from_profile(&rows).map(|c| c.scaled(sized.scale[1]));
        Ok(())
    }

    /// Appends the structure channel ([`super::structure`]) × `weight` to
    /// the feature channels: matching, the cut cost and seam refinement see
    /// it from then on. Call it before anything is matched.
    pub(super) fn add_structure(&mut self, weight: f32) {
        let (w, h, n) = (self.width, self.height, self.n);
        let channel: Vec<f32> = super::structure::structure_channel(&self.maps, w, h, n)
            .into_iter()
            .map(|v| v * weight)
            .collect();
        self.maps = interleave(&self.maps, n, &channel);
        self.n = n + 1;
        self.structure = Some(channel);
        crate::lock(&self.rotated).clear();
        crate::lock(&self.spill).keys.clear();
    }

    /// Matching reads the leading `terms` geometry-map terms (0, or as many
    /// as the sample has: all of them), plus the structure channel when it
    /// is on; the cut cost and seam refinement read every term. The terms
    /// are g_i = σ_i u_i in decreasing σ_i, so the leading ones carry most
    /// of a BTF's variation (§III-A) and the placement search costs a
    /// fraction of all 40. Call it before anything is matched.
    pub(super) fn set_match_terms(&mut self, terms: usize) {
        let stored = self.svd.terms;
        self.match_terms = if terms == 0 { stored } else { terms.min(stored) };
        crate::lock(&self.rotated).clear();
        crate::lock(&self.spill).keys.clear();
    }

    /// The channels matching reads: the leading terms, then the structure
    /// channel when it is on.
    pub(super) fn match_channels(&self) -> usize {
        self.match_terms + usize::from(self.structure.is_some())
    }

    /// Features of `n` channels per pixel (the sample's own) as matching
    /// reads them ([`Sample::match_channels`]): `features` itself when that
    /// is every channel.
    pub(super) fn match_features<'a>(&self, features: &'a [f32]) -> std::borrow::Cow<'a, [f32]> {
        if self.match_terms == self.svd.terms {
            return std::borrow::Cow::Borrowed(features);
        }
        let mut out = Vec::new();
        select_channels(
            features,
            self.n,
            self.match_terms,
            self.structure.is_some(),
            &mut out,
        );
        std::borrow::Cow::Owned(out)
    }

    /// The largest whole rotated copy a match loaded that the copies'
    /// cache could not hold (0 if none): each work patch matching at full
    /// resolution then holds one of its own while it matches.
    pub(super) fn uncached_bytes(&self) -> u64 {
        self.uncached.load(Ordering::Relaxed)
    }

    /// Empties the rotated copies' cache.
    pub(super) fn drop_rotations(&self) {
        crate::lock(&self.rotated).clear();
    }

    /// The rotated copies' cache: its budget and the bytes it holds.
    #[cfg(test)]
    pub(super) fn rotated_cache(&self) -> (u64, u64) {
        let cache = crate::lock(&self.rotated);
        (cache.budget(), cache.bytes())
    }

    /// Sets the budget of the rotated copies' cache, evicting down to it.
    pub(super) fn set_rotated_budget(&self, budget: MemoryBudget) {
        crate::lock(&self.rotated).set_budget(budget);
    }

    /// Rotated copy `r` (maps, validity), loaded on first use (two threads
    /// may both load it; they get equal copies).
    pub(super) fn rotation(&self, r: usize) -> Result<Arc<RotatedCopy>> {
        match self.cached_or_room(r) {
            Ok(copy) => Ok(copy),
            Err(room) => self.load_rotation(r, room),
        }
    }

    /// Rotated copy `r` for a match at full resolution: the f32 copy if
    /// its cache holds it or has room for it (or the structure channel is
    /// on); otherwise the f16 copy as the `.svd` stores it, half the
    /// bytes, held by the match alone (the same values).
    pub(super) fn rotation_to_match(&self, r: usize) -> Result<WholeCopy> {
        match self.cached_or_room(r) {
            Ok(copy) => Ok(WholeCopy::F32(copy)),
            Err(room) if room || self.structure.is_some() => Ok(WholeCopy::F32(self.load_rotation(r, room)?)),
            Err(_) => {
                let (maps, valid) = self.stored_f16(r)?;
                let valid: Vec<f32> = valid.iter().map(|&v| v as f32).collect();
                self.uncached
                    .fetch_max((maps.len() * 2 + valid.len() * 4) as u64, Ordering::Relaxed);
                Ok(WholeCopy::F16(maps, valid))
            }
        }
    }

    /// Whole copy `r` from the cache, or else whether room for one was
    /// reserved there.
    fn cached_or_room(&self, r: usize) -> std::result::Result<Arc<RotatedCopy>, bool> {
        let mut cache = crate::lock(&self.rotated);
        if let Some(copy) = cache.get(&(r, 1)) {
            return Ok(Arc::clone(copy));
        }
        Err(cache.reserve(self.whole_bytes()))
    }

    /// Loads whole copy `r` in f32, into the room reserved for it if
    /// `room`.
    fn load_rotation(&self, r: usize, room: bool) -> Result<Arc<RotatedCopy>> {
        let whole = self.whole_bytes();
        let load = || -> Result<Arc<RotatedCopy>> {
            let (mut m, valid) = self.stored_rect(r, (0, 0, self.width, self.height))?;
            if let Some(channel) = &self.structure {
                // turned like the stored copies (factorize's rotate_maps)
                let degrees = r as f64 * 360.0 / self.rotations as f64;
                let (turned, _) =
                    factorize::rotate_maps(channel, self.width, self.height, 1, degrees, self.tileable);
                m = interleave(&m, self.match_terms, &turned);
            }
            Ok(Arc::new((m, valid)))
        };
        let copy = match load() {
            Ok(copy) => copy,
            Err(e) => {
                if room {
                    crate::lock(&self.rotated).unreserve(whole);
                }
                return Err(e);
            }
        };
        let bytes = ((copy.0.len() + copy.1.len()) * 4) as u64;
        let kept =
            room && crate::lock(&self.rotated).insert_reserved((r, 1), Arc::clone(&copy), whole, bytes);
        if !kept {
            self.uncached.fetch_max(bytes, Ordering::Relaxed);
        }
        Ok(copy)
    }

    /// The rectangle `(x, y, w, h)` of rotated copy `r` (maps, validity):
    /// cut from the whole copy if its cache holds it, or loads it there
    /// first if the sample is matched at full resolution and the copy fits
    /// (or the structure channel is on: it is turned whole); read from the
    /// `.svd` chunk by chunk otherwise. A sample matched coarse to fine
    /// ([`Sample::read_by_rectangles`]) so holds no whole copy.
    pub(super) fn rotation_rect(&self, r: usize, rect: (usize, usize, usize, usize)) -> Result<RotatedCopy> {
        let (cached, fits) = {
            let mut cache = crate::lock(&self.rotated);
            (cache.get(&(r, 1)).cloned(), cache.fits(self.whole_bytes()))
        };
        let whole = match cached {
            Some(copy) => Some(copy),
            None if self.structure.is_some() || (fits && !self.by_rectangles) => Some(self.rotation(r)?),
            None => None,
        };
        if let Some(copy) = whole {
            let whole = super::matching::Sample {
                image: Image {
                    width: self.width,
                    height: self.height,
                    channels: self.match_channels(),
                    data: &copy.0,
                },
                valid: &copy.1,
                constraint: None,
                key: 0,
            };
            let window = super::coarse::cut(&whole)(rect)?;
            return Ok((window.maps, window.valid));
        }
        self.stored_rect(r, rect)
    }

    /// The rectangle `(x, y, w, h)` of rotated copy `r` as the `.svd` stores
    /// it (without the structure channel), its leading terms matching reads,
    /// in f32: read and widened a band of chunk rows at a time, so that the
    /// stored f16 values are never held whole beside their f32 copy.
    fn stored_rect(&self, r: usize, rect: (usize, usize, usize, usize)) -> Result<RotatedCopy> {
        let (w, h) = (rect.2, rect.3);
        let (terms, k) = (self.svd.terms, self.match_terms);
        let mut m = vec![0f32; w * h * k];
        let mut valid = Vec::with_capacity(w * h);
        self.stored_bands(r, rect, |rows, maps, v| {
            let out = &mut m[rows.start * w * k..rows.end * w * k];
            if k == terms {
                half::slice::HalfFloatSliceExt::convert_to_f32_slice(maps, out);
            } else {
                for (px, o) in maps.chunks_exact(terms).zip(out.chunks_exact_mut(k)) {
                    half::slice::HalfFloatSliceExt::convert_to_f32_slice(&px[..k], o);
                }
            }
            valid.extend(v.iter().map(|&v| v as f32));
        })?;
        Ok((m, valid))
    }

    /// Whole rotated copy `r` as the `.svd` stores it, in f16, its leading
    /// terms matching reads, and its validity.
    fn stored_f16(&self, r: usize) -> Result<(Vec<half::f16>, Vec<u8>)> {
        let (terms, k) = (self.svd.terms, self.match_terms);
        let whole = (0, 0, self.width, self.height);
        if k == terms {
            return self.svd.rotated_rect(r, whole);
        }
        let (mut m, mut valid) = (Vec::with_capacity(self.width * self.height * k), Vec::new());
        self.stored_bands(r, whole, |_, maps, v| {
            select_channels(maps, terms, k, false, &mut m);
            valid.extend_from_slice(v);
        })?;
        Ok((m, valid))
    }

    /// Reads the rectangle `(x, y, w, h)` of stored copy `r` a band of
    /// chunk rows at a time: `each(rows, maps, validity)` with the band's
    /// rows counted from `y`.
    fn stored_bands(
        &self,
        r: usize,
        rect: (usize, usize, usize, usize),
        mut each: impl FnMut(std::ops::Range<usize>, &[half::f16], &[u8]),
    ) -> Result<()> {
        let (x, y, w, h) = rect;
        let band = self.svd.rotated_band_rows()?;
        let mut y0 = y;
        while y0 < y + h {
            let y1 = ((y0 / band + 1) * band).min(y + h);
            let (maps, v) = self.svd.rotated_rect(r, (x, y0, w, y1 - y0))?;
            each(y0 - y..y1 - y, &maps, &v);
            y0 = y1;
        }
        Ok(())
    }

    /// Bytes of one whole rotated copy as f32 (maps and validity).
    fn whole_bytes(&self) -> u64 {
        (self.width * self.height * (self.match_channels() + 1) * 4) as u64
    }

    /// The sample is matched coarse to fine: its rotated copies are read
    /// by rectangles ([`Sample::rotation_rect`]), and the coarse copies made
    /// from them are kept in the scratch store ([`Sample::spill_beside`]).
    /// (Loaded whole, a large sample's copies fit only a few to a cache's
    /// share, and a patch turned to one the cache has let go would decode
    /// it again.)
    pub(super) fn read_by_rectangles(&mut self) {
        self.by_rectangles = true;
    }

    /// Keeps the coarse copies made from rectangles in a scratch store
    /// beside `output` (made on the first one, removed with the sample), so
    /// that one evicted is read back instead of made again from the whole
    /// copy: those of a sample read by rectangles, and those of a copy too
    /// large for its cache.
    pub(super) fn spill_beside(&mut self, output: &Path) {
        let name = output
            .file_name()
            .map_or("output".into(), |n| n.to_string_lossy());
        self.spill.get_mut().unwrap_or_else(|e| e.into_inner()).beside =
            Some(output.with_file_name(format!("{name}.coarse")));
    }

    /// Rotated copy `r` box-averaged by `f` ([`Coarse`]): its maps and mean
    /// validity, `⌈width/f⌉ × ⌈height/f⌉`, made on first use from bands of
    /// the copy ([`Sample::rotation_rect`]) a multiple of f rows high, or
    /// read back from the scratch store ([`Sample::spill_beside`]).
    pub(super) fn coarse_rotation(&self, r: usize, f: usize) -> Result<Arc<RotatedCopy>> {
        if f == 1 {
            return self.rotation(r);
        }
        if let Some(copy) = crate::lock(&self.rotated).get(&(r, f)) {
            return Ok(Arc::clone(copy));
        }
        let (cw, ch) = (self.width.div_ceil(f), self.height.div_ceil(f));
        let pixels = cw * ch;
        let n = self.match_channels();
        if let Some(bytes) = crate::lock(&self.spill).get((r, f), pixels * (n + 1) * 4)? {
            let values: Vec<f32> = bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
                .collect();
            let (features, weight) = values.split_at(pixels * n);
            let copy = Arc::new((features.to_vec(), weight.to_vec()));
            crate::lock(&self.rotated).insert_if_fits((r, f), Arc::clone(&copy), (values.len() * 4) as u64);
            return Ok(copy);
        }
        let band = f * 64usize.div_ceil(f);
        let (mut features, mut weight) = (Vec::new(), Vec::new());
        for y0 in (0..self.height).step_by(band) {
            let rows = band.min(self.height - y0);
            let part = self.rotation_rect(r, (0, y0, self.width, rows))?;
            let image = Image {
                width: self.width,
                height: rows,
                channels: n,
                data: &part.0,
            };
            let c = Coarse::new(&image, &part.1, &[], 0, f);
            features.extend_from_slice(&c.features);
            weight.extend_from_slice(&c.weight);
        }
        let copy = Arc::new((features, weight));
        let bytes = ((copy.0.len() + copy.1.len()) * 4) as u64;
        let whole_fits = {
            let mut cache = crate::lock(&self.rotated);
            cache.insert_if_fits((r, f), Arc::clone(&copy), bytes);
            cache.fits(self.whole_bytes())
        };
        // (made from rectangles: making it again would read the whole copy)
        if (self.by_rectangles || !whole_fits) && self.structure.is_none() {
            let values = copy.0.iter().chain(&copy.1).flat_map(|v| v.to_le_bytes());
            // (the climb's factor and the match's: two per rotation)
            crate::lock(&self.spill).put((r, f), &values.collect::<Vec<u8>>(), 2 * self.rotations)?;
        }
        Ok(copy)
    }

    /// Rotated copy `r` of the foreground mask (turned like the maps), in
    /// the rotated copies' cache: its maps are the mask.
    pub(super) fn rotation_mask(&self, r: usize) -> Option<Arc<RotatedCopy>> {
        let mask = self.mask.as_ref()?;
        if let Some(copy) = crate::lock(&self.rotated).get(&(r, MASK)) {
            return Some(Arc::clone(copy));
        }
        let degrees = r as f64 * 360.0 / self.rotations as f64;
        let (m, _) = factorize::rotate_maps(mask, self.width, self.height, 1, degrees, self.tileable);
        let copy = Arc::new((m, Vec::new()));
        let bytes = (copy.0.len() * 4) as u64;
        crate::lock(&self.rotated).insert_if_fits((r, MASK), Arc::clone(&copy), bytes);
        Some(copy)
    }

    /// Bilinear foreground mask at unrotated sample coordinates (0 where
    /// there is no mask or outside the sample).
    pub(super) fn mask_at(&self, c: [f64; 2]) -> f32 {
        let Some(mask) = &self.mask else { return 0.0 };
        crate::io::imageio::mask_bilinear(mask, self.width, self.height, c, self.tileable)
    }

    /// Bilinear geometry-map vector at unrotated sample coordinates (pixel
    /// indices); `None` outside the sample (unless tileable).
    pub(super) fn lookup(&self, c: [f64; 2], out: &mut [f32]) -> bool {
        let (w, h) = (self.width as f64, self.height as f64);
        let (mut x, mut y) = (c[0], c[1]);
        if self.tileable {
            x = x.rem_euclid(w);
            y = y.rem_euclid(h);
        } else if !(x >= 0.0 && y >= 0.0 && x <= w - 1.0 && y <= h - 1.0) {
            return false;
        }
        // (x, y ≥ 0 here: truncation is the floor, without a call to libm)
        let (x0, y0) = (x as usize, y as usize);
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let wrap = |v: usize, n: usize| if self.tileable { v % n } else { v.min(n - 1) };
        let (x0, y0) = (wrap(x0, self.width), wrap(y0, self.height));
        let (x1, y1) = (wrap(x0 + 1, self.width), wrap(y0 + 1, self.height));
        let n = self.n;
        let at = |x: usize, y: usize| (y * self.width + x) * n;
        let (a, b, cc, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        for i in 0..n {
            let top = self.maps[a + i] + (self.maps[b + i] - self.maps[a + i]) * fx;
            let bottom = self.maps[cc + i] + (self.maps[d + i] - self.maps[cc + i]) * fx;
            out[i] = top + (bottom - top) * fy;
        }
        true
    }

    /// Mean ‖g(x) − g(x + 1)‖ over horizontal and vertical neighbours: the
    /// sample's own seam scale, the unit of T_c.
    pub(super) fn neighbour_difference(&self) -> f64 {
        neighbour_difference(&self.maps, self.width, self.height, self.n)
    }
}

/// The scratch store of [`Sample::spill_beside`]: where it goes, and once
/// made, the store and its record key per (rotation, factor).
#[derive(Default)]
struct Spill {
    beside: Option<PathBuf>,
    store: Option<Scratch>,
    keys: std::collections::HashMap<(usize, usize), usize>,
}

impl Spill {
    /// The record of coarse copy `key`, `len` bytes, if it was stored.
    fn get(&mut self, key: (usize, usize), len: usize) -> Result<Option<Vec<u8>>> {
        match (self.keys.get(&key), &mut self.store) {
            (Some(&k), Some(store)) => store.get(k, len).map(Some),
            _ => Ok(None),
        }
    }

    /// Stores coarse copy `key` (of at most `capacity` records: beyond it,
    /// or without a place, nothing is stored).
    fn put(&mut self, key: (usize, usize), bytes: &[u8], capacity: usize) -> Result<()> {
        let Some(beside) = &self.beside else { return Ok(()) };
        if self.keys.contains_key(&key) || self.keys.len() >= capacity {
            return Ok(());
        }
        if self.store.is_none() {
            self.store = Some(Scratch::create_beside(beside, capacity)?);
        }
        let k = self.keys.len();
        self.store.as_mut().expect("made above").put(k, bytes)?;
        self.keys.insert(key, k);
        Ok(())
    }
}

/// `n`-channel pixels with one more channel from `extra` after each.
fn interleave(maps: &[f32], n: usize, extra: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(maps.len() + extra.len());
    for (px, &e) in maps.chunks_exact(n).zip(extra) {
        out.extend_from_slice(px);
        out.push(e);
    }
    out
}

/// Appends to `out` the leading `k` of each pixel's `n` values, and its
/// last one too if `last`.
fn select_channels<T: Copy>(values: &[T], n: usize, k: usize, last: bool, out: &mut Vec<T>) {
    out.reserve(values.len() / n * (k + usize::from(last)));
    for px in values.chunks_exact(n) {
        out.extend_from_slice(&px[..k]);
        if last {
            out.push(px[n - 1]);
        }
    }
}

/// Mean ‖g(x) − g(x + 1)‖ over horizontal and vertical neighbours of `n`-term
/// maps `w`×`h`.
fn neighbour_difference(maps: &[f32], w: usize, h: usize, n: usize) -> f64 {
    let (mut s, mut c) = (0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            let a = (y * w + x) * n;
            for (dx, dy) in [(1, 0), (0, 1)] {
                if x + dx < w && y + dy < h {
                    let b = ((y + dy) * w + x + dx) * n;
                    s += dist(&maps[a..a + n], &maps[b..b + n]);
                    c += 1;
                }
            }
        }
    }
    (s / c.max(1) as f64).max(1e-12)
}

/// Whether two paths name the same file (textually equal when either is
/// missing).
pub(crate) fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    }
}

pub(super) fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// C = P_aᵀ P_k (`n_a × n_k`, row-major) for appearance functions stored
/// `[pair][rgb][i]` over the same direction pairs: it takes sample k's
/// geometry-map vectors into sample a's basis.
pub(super) fn basis_projection(pa: &[f32], na: usize, pk: &[f32], nk: usize) -> Vec<f32> {
    let rows = pa.len() / na.max(1);
    let mut c = vec![0f64; na * nk];
    for row in 0..rows {
        let (ra, rk) = (&pa[row * na..(row + 1) * na], &pk[row * nk..(row + 1) * nk]);
        for (a, &x) in ra.iter().enumerate() {
            for (k, &y) in rk.iter().enumerate() {
                c[a * nk + k] += x as f64 * y as f64;
            }
        }
    }
    c.into_iter().map(|v| v as f32).collect()
}

pub(super) fn dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The sample's `.svd`: the file itself, or a colour image factorized into a
/// temporary directory (kept alive by the returned guard), with the rotated
/// copies only if `matching` needs them (they are most of the cost),
/// within `memory`.
pub(crate) fn sample_svd(
    sample_path: &Path,
    matching: bool,
    memory: MemoryBudget,
    progress: &dyn Progress,
) -> Result<(PathBuf, Option<tempfile::TempDir>)> {
    if factorize::is_image_path(sample_path) {
        let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
        let p = dir.path().join("sample.svd");
        let cfg = FactorizeConfig {
            rotations: if matching { factorize::DEFAULT_ROTATIONS } else { 0 },
            memory,
            ..FactorizeConfig::default()
        };
        factorize::factorize(sample_path, &p, &cfg, progress)?;
        Ok((p, Some(dir)))
    } else {
        Ok((sample_path.to_path_buf(), None))
    }
}

/// [`sample_at_density`] as the tiling's tests use it: one sample pixel per
/// texel, rotated copies for matching, the default budget.
#[cfg(test)]
pub(crate) fn sample_as_is(sample_path: &Path, texel_size: f64) -> SizedSample {
    let silent = crate::progress::Silent;
    sample_at_density(
        sample_path,
        texel_size,
        None,
        true,
        MemoryBudget::default(),
        &silent,
    )
    .unwrap()
}

/// A sample's size in pixels, from an image's header or an `.svd`'s
/// metadata (nothing is decoded).
pub(crate) fn sample_pixel_size(sample_path: &Path) -> Result<[usize; 2]> {
    Ok(sample_shape(sample_path)?.0)
}

/// What a sample other than the one quilting holds while a surface that
/// draws from it is painted: its unrotated maps and its preview, f32
/// ([`Synthesis::load`](super::Synthesis::load)).
pub(crate) fn foreign_sample_bytes(sample_path: &Path) -> Result<u64> {
    let ([w, h], terms) = sample_shape(sample_path)?;
    Ok(4 * (w * h * (terms + 3)) as u64)
}

/// A sample's size in pixels and its number of geometry maps (3 for a
/// colour image), from an image's header or an `.svd`'s metadata.
fn sample_shape(sample_path: &Path) -> Result<([usize; 2], usize)> {
    if factorize::is_image_path(sample_path) {
        let (w, h) = crate::io::imageio::image_size(sample_path)?;
        Ok(([w, h], 3))
    } else {
        let svd = SvdArtifact::open(sample_path, MemoryBudget(0))?;
        Ok(([svd.width, svd.height], svd.terms))
    }
}

/// A sample brought to the atlas's texel density (section III-A samples the
/// texture at the dense mesh's resolution): its `.svd`, kept alive by the
/// temporary directories, and the scale from the resampled pixels to the
/// original ones.
pub(crate) struct SizedSample {
    /// The `.svd` to quilt with.
    pub(crate) svd: PathBuf,
    /// The original sample's `.svd` (`svd` itself when the sample is used
    /// as it is).
    pub(crate) original: PathBuf,
    /// Original sample pixels per resampled pixel, along x and y (`[1, 1]`
    /// when the sample is used as it is).
    pub(crate) scale: [f64; 2],
    /// The original sample's size in pixels.
    pub(crate) size: [usize; 2],
    /// Mesh units the sample's width spans on the surface.
    pub(crate) width_units: f64,
    /// The original sample's neighbour difference (the unit of T_c at its
    /// own resolution), exactly when a size was given and the sample
    /// resampled: an enlarged sample is smoother than the material, so seams
    /// are judged against the original's scale.
    pub(crate) native_reference: Option<f64>,
    _tmp: Vec<tempfile::TempDir>,
}

/// The sample at `sample_path` sized for an atlas of `texel_size` mesh units
/// per texel: with a size `on_surface`, resampled so one pixel is one
/// texel ([`factorize::resample_svd`]); without, as it is. A colour image
/// is factorized, and the sample resampled, within `memory`.
pub(crate) fn sample_at_density(
    sample_path: &Path,
    texel_size: f64,
    on_surface: Option<super::config::SampleSize>,
    matching: bool,
    memory: MemoryBudget,
    progress: &dyn Progress,
) -> Result<SizedSample> {
    let mut tmp = Vec::new();
    let (svd_path, dir) = sample_svd(sample_path, matching && on_surface.is_none(), memory, progress)?;
    tmp.extend(dir);
    let svd = SvdArtifact::open(&svd_path, MemoryBudget(0))?;
    let size = [svd.width, svd.height];
    let Some(on_surface) = on_surface else {
        return Ok(SizedSample {
            original: svd_path.clone(),
            svd: svd_path,
            scale: [1.0, 1.0],
            size,
            width_units: svd.width as f64 * texel_size,
            native_reference: None,
            _tmp: tmp,
        });
    };
    let units = on_surface.width_units(svd.width);
    // texels the sample's width covers on the surface
    let texels = units / texel_size;
    let to_w = texels.round().max(1.0);
    let to_h = (texels * svd.height as f64 / svd.width as f64).round().max(1.0);
    if !(to_w <= crate::artifact::gim::MAX_RESOLUTION as f64
        && to_h <= crate::artifact::gim::MAX_RESOLUTION as f64)
    {
        return Err(Error::Config(format!(
            "{}: the sample would span {texels:.0} texels of this atlas (texel {texel_size:.3e} units), more than {}",
            on_surface.flag(),
            crate::artifact::gim::MAX_RESOLUTION
        )));
    }
    let (to_w, to_h) = (to_w as usize, to_h as usize);
    if to_w < 8 || to_h < 8 {
        return Err(Error::Config(format!(
            "{}: the sample would span only {to_w}×{to_h} texels of this atlas (texel {texel_size:.3e} units); give a larger width or a finer atlas",
            on_surface.flag()
        )));
    }
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    let out = dir.path().join("sized.svd");
    let rotations = if matching { factorize::DEFAULT_ROTATIONS } else { 0 };
    let maps = svd.geometry_maps()?;
    factorize::resample_svd(&svd, &maps, &out, (to_w, to_h), rotations, memory, progress)?;
    tmp.push(dir);
    let native_reference = neighbour_difference(&maps, svd.width, svd.height, svd.terms);
    Ok(SizedSample {
        svd: out,
        original: svd_path,
        scale: [size[0] as f64 / to_w as f64, size[1] as f64 / to_h as f64],
        size,
        width_units: units,
        native_reference: Some(native_reference),
        _tmp: tmp,
    })
}
