//! Exact order statistics of a stream of figures in bounded memory, for
//! `evaluate`, whose seam steps and continuations are one or two per seam
//! edge (millions on a large atlas). A [`Ranked`] keeps a stream's values
//! while they fit its cap; past it only a histogram of their leading bits.
//! [`at_ranks`] then finds the values at the wanted ranks by reading the
//! stream again (`evaluate` reads the atlas's bands again): a radix
//! select over the values' order keys, 16 bits a pass, that sorts a
//! rank's candidates once they are down to [`COLLECT`]. The same values at
//! any cap: a smaller `--memory` costs passes, not results.

use crate::Result;

/// Candidates [`at_ranks`] sorts once it has narrowed a rank down to this many.
pub(super) const COLLECT: usize = 1 << 16;

/// Bits a pass narrows a rank by (a histogram of `1 << DIGIT` counts).
const DIGIT: u32 = 16;

/// The key whose unsigned order is `f64::total_cmp`'s order.
fn key(v: f64) -> u64 {
    let bits = v.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | 1 << 63
    }
}

/// The value of a [`key`].
fn value(key: u64) -> f64 {
    f64::from_bits(if key >> 63 == 1 { key & !(1 << 63) } else { !key })
}

/// A stream's values, kept (in order) while at most `cap`, else counted by
/// their keys' leading [`DIGIT`] bits; and their count and sum.
pub(super) struct Ranked {
    cap: usize,
    kept: Vec<f64>,
    /// Counts by leading digit, once the values passed `cap`.
    first: Option<Vec<u32>>,
    len: usize,
    /// The sum in push order, from −0.0 as `Iterator::sum` of floats
    /// (the sum of none is −0.0).
    sum: f64,
}

impl Ranked {
    /// Keeps at most `cap` values.
    pub(super) fn new(cap: usize) -> Ranked {
        Ranked {
            cap,
            kept: Vec::new(),
            first: None,
            len: 0,
            sum: -0.0,
        }
    }

    /// Kept values at most for `bytes` of them (at least one).
    pub(super) fn within(bytes: u64) -> Ranked {
        Ranked::new((bytes / 8).max(1) as usize)
    }

    pub(super) fn push(&mut self, v: f64) {
        self.len += 1;
        self.sum += v;
        match &mut self.first {
            Some(counts) => counts[(key(v) >> (64 - DIGIT)) as usize] += 1,
            None if self.kept.len() < self.cap => self.kept.push(v),
            None => {
                let mut counts = vec![0u32; 1 << DIGIT];
                for &k in self.kept.iter().chain([&v]) {
                    counts[(key(k) >> (64 - DIGIT)) as usize] += 1;
                }
                self.kept = Vec::new();
                self.first = Some(counts);
            }
        }
    }

    pub(super) fn len(&self) -> usize {
        self.len
    }

    /// The values' sum in push order (as `Iterator::sum`, also after
    /// [`at_ranks`] sorted the kept values).
    pub(super) fn sum(&self) -> f64 {
        self.sum
    }

    /// The mean, 0 for none.
    pub(super) fn mean(&self) -> f64 {
        self.sum() / self.len.max(1) as f64
    }

    /// The values in push order, if all were kept.
    pub(super) fn kept(&self) -> Option<&[f64]> {
        self.first.is_none().then_some(&self.kept[..])
    }
}

/// The index of the `q` quantile in `n` ascending values by nearest rank
/// (the smallest value with at least `q n` values at or below it).
pub(super) fn nearest_rank_index(n: usize, q: f64) -> usize {
    ((q * n as f64).ceil() as usize).clamp(1, n.max(1)) - 1
}

/// How many values `stream` yields (the same ones on every call) and the
/// one at rank `rank(count)` in `f64::total_cmp` order (0 when there are
/// none), holding at most [`COLLECT`] of them ([`at_ranks`]).
pub(super) fn rank_of(
    mut stream: impl FnMut(&mut dyn FnMut(f64)) -> Result<()>,
    rank: impl Fn(usize) -> usize,
) -> Result<(usize, f64)> {
    let mut list = Ranked::new(COLLECT);
    stream(&mut |v| list.push(v))?;
    let n = list.len();
    let found = at_ranks(&mut [&mut list], &[(0, rank(n))], |f| stream(&mut |v| f(0, v)))?;
    Ok((n, found[0]))
}

/// One wanted rank while it is narrowed.
struct Target {
    list: usize,
    /// The rank among the values whose keys start with `prefix`.
    k: usize,
    prefix: u64,
    /// Leading key bits fixed (0..=64).
    known: u32,
    /// Values with that prefix.
    count: usize,
    found: Option<f64>,
}

impl Target {
    fn matches(&self, key: u64) -> bool {
        self.known == 0 || key >> (64 - self.known) == self.prefix
    }

    /// Narrows by a histogram of the next digit of the matching keys.
    fn narrow(&mut self, hist: &[u32]) {
        let (mut below, mut bucket) = (0usize, 0usize);
        for (i, &c) in hist.iter().enumerate() {
            if below + c as usize > self.k {
                bucket = i;
                break;
            }
            below += c as usize;
        }
        self.prefix = (self.prefix << DIGIT) | bucket as u64;
        self.known += DIGIT;
        self.k -= below;
        self.count = hist[bucket] as usize;
        if self.known == 64 {
            self.found = Some(value(self.prefix));
        }
    }
}

/// The values at `wanted` ranks `(list, k)`: `k` in ascending
/// `f64::total_cmp` order of `lists[list]`'s values (0 for a list with
/// none). `stream` yields every list's values again, as `(list, value)`,
/// the same ones on every call; it is called only when some list's values
/// were not all kept, at most three times. Kept values are sorted in place.
pub(super) fn at_ranks(
    lists: &mut [&mut Ranked],
    wanted: &[(usize, usize)],
    mut stream: impl FnMut(&mut dyn FnMut(usize, f64)) -> Result<()>,
) -> Result<Vec<f64>> {
    let mut targets: Vec<Target> = wanted
        .iter()
        .map(|&(list, k)| Target {
            list,
            k,
            prefix: 0,
            known: 0,
            count: lists[list].len,
            found: None,
        })
        .collect();
    for (l, list) in lists.iter_mut().enumerate() {
        let mine = targets.iter_mut().filter(|t| t.list == l);
        match &list.first {
            None => {
                list.kept.sort_by(f64::total_cmp);
                for t in mine {
                    t.found = Some(list.kept.get(t.k).copied().unwrap_or(0.0));
                }
            }
            Some(counts) => mine.for_each(|t| t.narrow(counts)),
        }
    }
    while targets.iter().any(|t| t.found.is_none()) {
        // each open target collects its candidates or counts their next digit
        let mut hists: Vec<Option<Vec<u32>>> = Vec::new();
        let mut collected: Vec<Option<Vec<f64>>> = Vec::new();
        for t in &targets {
            let open = t.found.is_none();
            let collect = open && t.count <= COLLECT;
            hists.push((open && !collect).then(|| vec![0u32; 1 << DIGIT]));
            collected.push(collect.then(|| Vec::with_capacity(t.count)));
        }
        stream(&mut |list, v| {
            let k = key(v);
            for (i, t) in targets.iter().enumerate() {
                if t.list != list || t.found.is_some() || !t.matches(k) {
                    continue;
                }
                if let Some(c) = &mut collected[i] {
                    c.push(v);
                } else if let Some(h) = &mut hists[i] {
                    h[((k >> (64 - t.known - DIGIT)) & ((1 << DIGIT) - 1)) as usize] += 1;
                }
            }
        })?;
        for (i, t) in targets.iter_mut().enumerate() {
            if let Some(mut c) = collected[i].take() {
                c.sort_by(f64::total_cmp);
                t.found = Some(c[t.k]);
            } else if let Some(h) = &hists[i] {
                t.narrow(h);
            }
        }
    }
    Ok(targets.iter().map(|t| t.found.unwrap_or(0.0)).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values with many repeats, zeros of both signs, infinities and a
    /// spread over many octaves.
    fn values(n: usize, seed: u64) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let h = crate::rng::mix64(i as u64 ^ seed << 32);
                match h % 7 {
                    0 => 1.0,
                    1 => 0.0,
                    2 if i % 1000 == 0 => f64::INFINITY,
                    3 if i % 500 == 0 => -0.0,
                    4 => (h >> 8) as f64 * 1e-12,
                    _ => (crate::rng::mix64(h) % 1_000_000) as f64 * 1e-3,
                }
            })
            .collect()
    }

    #[test]
    fn keys_order_as_total_cmp() {
        let mut v = values(20_000, 3);
        v.extend([f64::NEG_INFINITY, -1.5, -0.0, 0.0, 1e-300, f64::MAX]);
        for w in v.windows(2) {
            assert_eq!(
                key(w[0]).cmp(&key(w[1])),
                w[0].total_cmp(&w[1]),
                "{} {}",
                w[0],
                w[1]
            );
            assert_eq!(value(key(w[0])).to_bits(), w[0].to_bits());
        }
    }

    #[test]
    fn ranks_equal_sorting_at_every_cap() {
        // two lists read in one stream; caps that keep all, some or none
        for (n0, n1) in [(0usize, 5usize), (1, 1), (7, 300_001), (200_000, 90_000)] {
            let (a, b) = (values(n0, 1), values(n1, 2));
            let mut sa = a.clone();
            sa.sort_by(f64::total_cmp);
            let mut sb = b.clone();
            sb.sort_by(f64::total_cmp);
            let ranks = |n: usize| [0, n / 2, n.saturating_sub(1), nearest_rank_index(n, 0.95)];
            for cap in [0usize, 1, 1000, 1 << 20] {
                let mut lists = [Ranked::new(cap), Ranked::new(cap)];
                a.iter().for_each(|&v| lists[0].push(v));
                b.iter().for_each(|&v| lists[1].push(v));
                assert_eq!(lists[0].len(), n0);
                assert_eq!(lists[0].sum().to_bits(), a.iter().sum::<f64>().to_bits());
                assert_eq!(lists[1].sum().to_bits(), b.iter().sum::<f64>().to_bits());
                let wanted: Vec<(usize, usize)> = ranks(n0)
                    .map(|k| (0, k))
                    .into_iter()
                    .chain(ranks(n1).map(|k| (1, k)))
                    .collect();
                let mut passes = 0;
                let [l0, l1] = &mut lists;
                let got = at_ranks(&mut [l0, l1], &wanted, |f| {
                    passes += 1;
                    a.iter().for_each(|&v| f(0, v));
                    b.iter().for_each(|&v| f(1, v));
                    Ok(())
                })
                .unwrap();
                let want: Vec<f64> = wanted
                    .iter()
                    .map(|&(l, k)| [&sa, &sb][l].get(k).copied().unwrap_or(0.0))
                    .collect();
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "{n0}/{n1} values, cap {cap}");
                assert!(passes <= 3, "{passes} passes");
                if cap >= n0.max(n1) {
                    assert_eq!(passes, 0, "all kept: no pass");
                }
            }
        }
    }
}
