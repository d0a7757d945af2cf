//! Entire-patch matching (Kwatra et al. 2003) per match, sample spectra
//! cached (the steady state of synthesis, which matches many work images
//! against the same rotated copy), plus one cold match that also transforms
//! the sample.
//!
//! `warm/64x64_vs_192x192/n3`, `warm/64x64_vs_192x192/n40`,
//! `warm/128x128_vs_256x256/n40`, `cold/64x64_vs_192x192/n40`; and the
//! fine step of coarse-to-fine matching, direct sums over the known pixels
//! for 8 windows of 3×3 placements: `direct/192x192_vs_384x384/n3`.

use btfquilt::quilt::matching::{direct_costs, Image, MatchConfig, Matcher, Sample, Work};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

fn values(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed;
    (0..len)
        .map(|_| {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

struct Case {
    work: usize,
    sample: usize,
    n: usize,
    w: Vec<f32>,
    s: Vec<f32>,
    known: Vec<f32>,
    valid: Vec<f32>,
}

impl Case {
    fn new(work: usize, sample: usize, n: usize) -> Case {
        // an L-shaped known region, as when a patch extends the synthesized area
        let known = (0..work * work)
            .map(|i| {
                if i / work < work / 3 || i % work < work / 3 {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        // a disc of valid texels, as in a rotated copy
        let c = (sample as f32 - 1.0) / 2.0;
        let valid = (0..sample * sample)
            .map(|i| {
                let (x, y) = ((i % sample) as f32 - c, (i / sample) as f32 - c);
                if x * x + y * y <= c * c {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        Case {
            work,
            sample,
            n,
            w: values(work * work * n, 1),
            s: values(sample * sample * n, 2),
            known,
            valid,
        }
    }

    fn inputs(&self) -> (Work<'_>, Sample<'_>) {
        (
            Work {
                image: Image::new(self.work, self.work, self.n, &self.w).unwrap(),
                known: &self.known,
                constraint: None,
            },
            Sample {
                image: Image::new(self.sample, self.sample, self.n, &self.s).unwrap(),
                valid: &self.valid,
                constraint: None,
                key: 0,
            },
        )
    }

    fn name(&self) -> String {
        format!("{0}x{0}_vs_{1}x{1}", self.work, self.sample)
    }
}

fn benches(c: &mut Criterion) {
    let cfg = MatchConfig::default();
    let mut group = c.benchmark_group("warm");
    group.sample_size(20);
    for (work, sample, n) in [(64, 192, 3), (64, 192, 40), (128, 256, 40)] {
        let case = Case::new(work, sample, n);
        let (w, s) = case.inputs();
        let mut m = Matcher::new();
        m.match_patch(&w, &s, &cfg).unwrap();
        group.bench_function(BenchmarkId::new(case.name(), format!("n{n}")), |b| {
            b.iter(|| m.match_patch(&w, &s, &cfg).unwrap())
        });
    }
    group.finish();
    let mut group = c.benchmark_group("cold");
    group.sample_size(10);
    let case = Case::new(64, 192, 40);
    let (w, s) = case.inputs();
    let mut m = Matcher::new();
    group.bench_function(BenchmarkId::new(case.name(), "n40"), |b| {
        b.iter(|| {
            m.clear_cache();
            m.match_patch(&w, &s, &cfg).unwrap()
        })
    });
    group.finish();
    let mut group = c.benchmark_group("direct");
    group.sample_size(20);
    let case = Case::new(192, 384, 3);
    let (w, s) = case.inputs();
    // 3×3 windows around 8 coarse minima, some near the sample's edge
    let placements: Vec<(i32, i32)> = [
        (10, 40),
        (-60, 5),
        (100, 100),
        (150, -20),
        (0, 0),
        (190, 190),
        (33, 77),
        (-180, 120),
    ]
    .iter()
    .flat_map(|&(x, y)| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dx| (x + dx, y + dy))))
    .collect();
    group.bench_function(BenchmarkId::new(case.name(), "n3"), |b| {
        b.iter(|| direct_costs(&w, &s, &cfg, &placements).unwrap())
    });
    group.finish();
}

criterion_group!(matching, benches);
criterion_main!(matching);
