//! The BTF data layer: generator determinism, ingest/export round trips, and
//! a clear error for each kind of bad input folder.

use std::path::{Path, PathBuf};

use btfquilt::artifact::btf::{self, Angles, Btf};
use btfquilt::container::MemoryBudget;
use btfquilt::generate::{self, Family, GenerateConfig, Imperfection};
use btfquilt::ingest::{self, ImageFormat, IngestConfig};
use btfquilt::io::imageio::{self, RgbImage};
use btfquilt::io::naming;
use btfquilt::progress::Silent;

fn small_config(family: Family, size: usize) -> GenerateConfig {
    GenerateConfig {
        family,
        imperfection: Imperfection::Cracks,
        width: size,
        height: size,
        seed: 11,
        ..GenerateConfig::default()
    }
}

fn generate_with_threads(cfg: &GenerateConfig, path: &Path, threads: usize) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| generate::generate_btf(cfg, path, &Silent))
        .unwrap();
}

fn file_hash(path: &Path) -> u64 {
    xxhash_rust::xxh3::xxh3_64(&std::fs::read(path).unwrap())
}

#[test]
fn generated_btf_is_byte_identical_across_thread_counts() {
    let dir = tempfile::tempdir().unwrap();
    // 40×40 is not a multiple of the tile or block: ragged edges included;
    // the paper's full 12×8×12×8 grid.
    let mut cfg = small_config(Family::Bricks, 40);
    cfg.block = 32;
    let (a, b) = (dir.path().join("a.btf"), dir.path().join("b.btf"));
    generate_with_threads(&cfg, &a, 1);
    generate_with_threads(&cfg, &b, 2);
    assert_eq!(file_hash(&a), file_hash(&b));
    let masks = (generate::mask_path(&a), generate::mask_path(&b));
    assert_eq!(std::fs::read(&masks.0).unwrap(), std::fs::read(&masks.1).unwrap());
    // the block size is an implementation detail: it must not change values
    let mut cfg64 = cfg.clone();
    cfg64.block = 64;
    let c = dir.path().join("c.btf");
    generate_with_threads(&cfg64, &c, 2);
    let (ba, bc) = (
        Btf::open(&a, MemoryBudget::default()).unwrap(),
        Btf::open(&c, MemoryBudget::default()).unwrap(),
    );
    assert_eq!(
        ba.read_pair_images(0..200).unwrap(),
        bc.read_pair_images(0..200).unwrap()
    );
    // another seed gives another BTF
    let mut other = cfg.clone();
    other.seed = 12;
    let d = dir.path().join("d.btf");
    generate_with_threads(&other, &d, 2);
    assert_ne!(file_hash(&a), file_hash(&d));
}

#[test]
fn generated_btf_has_the_paper_grid_and_responds_to_light() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bricks.btf");
    generate_with_threads(&small_config(Family::Bricks, 48), &path, 2);
    let b = Btf::open(&path, MemoryBudget::default()).unwrap();
    let l = b.layout();
    assert_eq!((l.views.len(), l.lights.len(), l.pairs()), (96, 96, 9216));
    let view = l.views[0];
    let img = |theta, phi| ingest::pair_image(&b, view, Angles { theta, phi }).unwrap().data;
    let head_on = img(5.0, 0.0);
    let grazing = img(75.0, 0.0);
    let opposite = img(75.0, 180.0);
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(head_on.iter().chain(&grazing).all(|v| v.is_finite() && *v >= 0.0));
    // less irradiance at grazing incidence
    assert!(
        mean(&grazing) < mean(&head_on),
        "{} vs {}",
        mean(&grazing),
        mean(&head_on)
    );
    // shadows move: lights from opposite sides give different images
    let diff: f32 = grazing
        .iter()
        .zip(&opposite)
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>()
        / grazing.len() as f32;
    assert!(
        diff > 0.01 * mean(&head_on),
        "grazing lights from opposite sides look the same"
    );
    // tiles hold the same values as the direction images
    let (tile, w, h) = b.read_tile(1, 0).unwrap();
    let p = b
        .find_pair(
            view,
            Angles {
                theta: 75.0,
                phi: 0.0,
            },
        )
        .unwrap();
    assert_eq!((w, h), (16, 16));
    let (x, y) = (16 + 3, 5);
    let t = (y * 16 + 3) * l.pairs() * 3 + p * 3;
    assert_eq!(tile[t].to_f32(), grazing[(y * 48 + x) * 3]);
    // a direction that is not in the grid is named in the error
    let err = b
        .find_pair(
            view,
            Angles {
                theta: 33.0,
                phi: 1.0,
            },
        )
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("bricks.btf") && err.contains("33"), "{err}");
}

/// A small generated BTF with ragged tiles and a small direction grid.
fn small_btf(dir: &Path) -> PathBuf {
    let path = dir.join("small.btf");
    let cfg = GenerateConfig {
        family: Family::Weave,
        imperfection: Imperfection::None,
        width: 21,
        height: 13,
        views: btf::grid(3, 2, 60.0),
        lights: btf::grid(4, 2, 60.0),
        seed: 3,
        ..GenerateConfig::default()
    };
    generate_with_threads(&cfg, &path, 2);
    path
}

fn all_values(path: &Path) -> Vec<f32> {
    let b = Btf::open(path, MemoryBudget::default()).unwrap();
    b.read_pair_images(0..b.layout().pairs()).unwrap()
}

#[test]
fn exr_export_then_ingest_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_btf(dir.path());
    let b = Btf::open(&src, MemoryBudget::default()).unwrap();
    let folder = dir.path().join("images");
    // a small budget forces several groups per band
    let n = ingest::export_all(&b, &folder, ImageFormat::Exr, MemoryBudget(4096), &Silent).unwrap();
    assert_eq!(n, 6 * 8);
    let back = dir.path().join("back.btf");
    let r = ingest::ingest(&folder, &back, &IngestConfig::default(), &Silent).unwrap();
    assert_eq!((r.width, r.height, r.views, r.lights), (21, 13, 6, 8));
    let rb = Btf::open(&back, MemoryBudget::default()).unwrap();
    assert_eq!(rb.layout().views, b.layout().views);
    assert_eq!(rb.layout().lights, b.layout().lights);
    assert_eq!(all_values(&src), all_values(&back));
    // the manifest written beside the images gives the same BTF
    let via_manifest = dir.path().join("manifest.btf");
    ingest::ingest(
        &folder.join("manifest.csv"),
        &via_manifest,
        &IngestConfig::default(),
        &Silent,
    )
    .unwrap();
    assert_eq!(all_values(&src), all_values(&via_manifest));
    // a tiny budget (one image per band) streams and still gives the same values
    let tiny = dir.path().join("tiny.btf");
    let cfg = IngestConfig {
        memory: MemoryBudget(2000),
        tile: 8,
        ..IngestConfig::default()
    };
    ingest::ingest(&folder, &tiny, &cfg, &Silent).unwrap();
    let t = Btf::open(&tiny, MemoryBudget::default()).unwrap();
    assert_eq!((t.layout().band, t.layout().tile), (1, 8));
    assert_eq!(all_values(&src), all_values(&tiny));
}

#[test]
fn png_export_then_ingest_is_close() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_btf(dir.path());
    let b = Btf::open(&src, MemoryBudget::default()).unwrap();
    let folder = dir.path().join("png");
    ingest::export_all(&b, &folder, ImageFormat::Png, MemoryBudget::default(), &Silent).unwrap();
    let back = dir.path().join("back.btf");
    ingest::ingest(&folder, &back, &IngestConfig::default(), &Silent).unwrap();
    for (a, b) in all_values(&src).iter().zip(all_values(&back)) {
        // 16-bit sRGB quantisation plus f16 storage; values above 1 clip
        let a = a.min(1.0);
        assert!((a - b).abs() <= 2e-3 * a.max(0.05), "{a} vs {b}");
    }
}

fn write_png(path: &Path, w: usize, h: usize) {
    let img = RgbImage {
        width: w,
        height: h,
        data: (0..w * h * 3).map(|i| (i % 7) as f32 / 7.0).collect(),
    };
    imageio::write_png(path, &img, imageio::PngDepth::Eight).unwrap();
}

/// A folder with 2 views × 2 lights; returns its path.
fn folder_2x2(dir: &Path) -> PathBuf {
    let folder = dir.join("in");
    std::fs::create_dir_all(&folder).unwrap();
    for (tv, pv) in [(0.0, 0.0), (30.0, 90.0)] {
        for (tl, pl) in [(15.0, 0.0), (45.0, 180.0)] {
            let name = naming::format_pair_name(
                "m",
                Angles { theta: tv, phi: pv },
                Angles { theta: tl, phi: pl },
                "png",
            );
            write_png(&folder.join(name), 6, 5);
        }
    }
    folder
}

fn ingest_error(folder: &Path, out: &Path) -> String {
    let err = ingest::ingest(folder, out, &IngestConfig::default(), &Silent)
        .err()
        .expect("ingest must fail");
    assert!(!out.exists(), "no output may be left after an error");
    let leftovers: Vec<_> = std::fs::read_dir(out.parent().unwrap())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("partial"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    err.to_string()
}

#[test]
fn good_folder_ingests() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    let out = dir.path().join("ok.btf");
    let r = ingest::ingest(&folder, &out, &IngestConfig::default(), &Silent).unwrap();
    assert_eq!((r.width, r.height, r.views, r.lights), (6, 5, 2, 2));
}

#[test]
fn images_of_differing_sizes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    let odd = folder.join("m_tl045_pl180_tv030_pv090.png");
    write_png(&odd, 7, 5);
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(
        msg.contains("m_tl045_pl180_tv030_pv090.png") && msg.contains("7×5"),
        "{msg}"
    );
}

#[test]
fn duplicate_directions_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    write_png(&folder.join("copy_tl15_pl0_tv0_pv0.png"), 6, 5);
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(msg.contains("copy_tl15_pl0_tv0_pv0.png"), "{msg}");
    assert!(msg.to_lowercase().contains("duplicate"), "{msg}");
}

#[test]
fn missing_directions_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    std::fs::remove_file(folder.join("m_tl045_pl180_tv030_pv090.png")).unwrap();
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(msg.to_lowercase().contains("missing"), "{msg}");
}

#[test]
fn unparseable_names_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    write_png(&folder.join("m_tl0x5_pl0_tv0_pv0.png"), 6, 5);
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(msg.contains("m_tl0x5_pl0_tv0_pv0.png"), "{msg}");
}

#[test]
fn corrupt_image_is_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    let victim = folder.join("m_tl015_pl000_tv030_pv090.png");
    let mut bytes = std::fs::read(&victim).unwrap();
    let n = bytes.len();
    bytes.truncate(n - 20);
    std::fs::write(&victim, bytes).unwrap();
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(msg.contains("m_tl015_pl000_tv030_pv090.png"), "{msg}");
    // cut inside the image data: said to end early
    let mut bytes = std::fs::read(&victim).unwrap();
    bytes.truncate(n / 2);
    std::fs::write(&victim, bytes).unwrap();
    let msg = ingest_error(&folder, &dir.path().join("o.btf"));
    assert!(
        msg.contains("m_tl015_pl000_tv030_pv090.png") && msg.contains("ends early"),
        "{msg}"
    );
}

#[test]
fn bad_manifests_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = folder_2x2(dir.path());
    let manifest = folder.join("list.csv");
    std::fs::write(
        &manifest,
        "file,theta_v,phi_v,theta_l,phi_l\nm_tl015_pl000_tv000_pv000.png,0,0,abc,0\n",
    )
    .unwrap();
    let msg = ingest_error(&manifest, &dir.path().join("o.btf"));
    assert!(msg.contains("list.csv") && msg.contains('2'), "{msg}");
}

#[test]
fn a_btf_is_not_read_as_another_kind_and_vice_versa() {
    let dir = tempfile::tempdir().unwrap();
    let text = dir.path().join("plain.btf");
    std::fs::write(&text, "not a btf").unwrap();
    let msg = Btf::open(&text, MemoryBudget::default())
        .err()
        .unwrap()
        .to_string();
    assert!(msg.contains("plain.btf"), "{msg}");
}
