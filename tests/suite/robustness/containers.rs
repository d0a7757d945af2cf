//! Crafted containers with valid checksums (bug 7), files truncated while
//! mapped (bug 11), and seeded mutations of small valid artifacts: every
//! reader refuses cleanly, naming the file and what is wrong.

use std::path::{Path, PathBuf};

use btfquilt::container::{
    self, codec, ArraySpec, Container, DType, EncodedChunk, MemoryBudget, Metadata, Param,
};

use crate::common::{self, s};
use crate::robustness::{fuzz_cases, mutate, refuses, run_bounded, Rng};

/// `atlas square.obj --resolution 64` → `dir/sq.gim`.
fn gim(dir: &Path) -> PathBuf {
    let obj = common::square_obj(dir);
    let p = dir.join("sq.gim");
    common::ok(&["atlas", s(&obj), "--resolution", "64", "-o", s(&p), "-q"]);
    p
}

/// `factorize brick32.png --rotations 8` → (`dir/brick32.png`, `dir/s.svd`).
fn svd(dir: &Path) -> (PathBuf, PathBuf) {
    let png = common::brick_crop(dir, 32, None);
    let p = dir.join("s.svd");
    common::ok(&["factorize", s(&png), "-o", s(&p), "--rotations", "8", "-q"]);
    (png, p)
}

/// A tiled square: (`sq.gim`, `brick32.png`, `s.svd`, `q.quilt`).
fn quilt(dir: &Path) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let g = gim(dir);
    let (png, sv) = svd(dir);
    let q = dir.join("q.quilt");
    common::ok(&["tile", "--gim", s(&g), "--sample", s(&png), "-o", s(&q), "-q"]);
    (g, png, sv, q)
}

/// `generate-btf --size 16 --views 2x2 --lights 2x2` → `dir/t.btf`.
fn btf(dir: &Path) -> PathBuf {
    let p = dir.join("t.btf");
    common::ok(&[
        "generate-btf",
        "--size",
        "16",
        "--views",
        "2x2",
        "--lights",
        "2x2",
        "-o",
        s(&p),
        "-q",
    ]);
    p
}

/// Copies the container `src` to `dst` with its metadata and stored chunks
/// edited by `edit`, with valid checksums and no validation.
fn rewrite(src: &Path, dst: &Path, edit: impl FnOnce(&mut Metadata, &mut Vec<Vec<EncodedChunk>>)) {
    let c = Container::open(src, MemoryBudget::default()).unwrap();
    let mut meta = c.metadata().clone();
    let mut chunks = c.stored_chunks().unwrap();
    drop(c);
    edit(&mut meta, &mut chunks);
    container::write_unchecked(dst, &meta, &chunks).unwrap();
}

fn array_index(meta: &Metadata, name: &str) -> usize {
    meta.arrays.iter().position(|a| a.name == name).unwrap()
}

fn set_param(meta: &mut Metadata, name: &str, value: Param) {
    meta.params.iter_mut().find(|(k, _)| k == name).unwrap().1 = value;
}

/// Replaces a single-chunk u32 array's values by `f(values)`.
fn edit_u32(src: &Path, dst: &Path, name: &str, f: impl FnOnce(&mut Vec<u32>)) {
    let c = Container::open(src, MemoryBudget::default()).unwrap();
    let id = c.array(name).unwrap();
    assert_eq!(c.spec(id).chunk_count(), 1, "'{name}' is one chunk");
    let mut v: Vec<u32> = c.read_array(id).unwrap();
    drop(c);
    f(&mut v);
    rewrite(src, dst, |meta, chunks| {
        chunks[array_index(meta, name)][0] = codec::encode(&v, 3);
    });
}

#[test]
fn zero_chunk_extent_is_refused_by_info_verify_and_typed_readers() {
    let dir = tempfile::tempdir().unwrap();
    let (g, _, sv, q) = quilt(dir.path());
    let bad_gim = dir.path().join("zero.gim");
    rewrite(&g, &bad_gim, |meta, _| {
        let a = array_index(meta, "chart");
        meta.arrays[a].chunk_shape[0] = 0;
    });
    let bad_quilt = dir.path().join("zero.quilt");
    rewrite(&q, &bad_quilt, |meta, _| {
        let a = array_index(meta, "coord");
        meta.arrays[a].chunk_shape[1] = 0;
    });
    let what = "chunk extents must be positive";
    for bad in [&bad_gim, &bad_quilt] {
        let name = bad.file_name().unwrap().to_str().unwrap();
        refuses(&["info", s(bad)], &[name, what], None);
        refuses(&["info", "--verify", s(bad)], &[name, what], None);
    }
    let out = dir.path().join("out.png");
    refuses(
        &["show", s(&bad_gim), "-o", s(&out)],
        &["zero.gim", "array 'chart'", what],
        Some(&out),
    );
    refuses(
        &["bake", s(&bad_quilt), "--sample", s(&sv), "-o", s(&out)],
        &["zero.quilt", "array 'coord'", what],
        Some(&out),
    );
}

#[test]
fn huge_declared_chunks_are_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let craft = |name: &str, side: u64| {
        let p = dir.path().join(name);
        let meta = Metadata {
            kind: "btf".into(),
            producer: "test".into(),
            seed: None,
            inputs: Vec::new(),
            params: Vec::new(),
            arrays: vec![ArraySpec {
                name: "big".into(),
                dtype: DType::U8,
                shape: vec![side, side],
                chunk_shape: vec![side, side],
            }],
        };
        container::write_unchecked(&p, &meta, &[vec![codec::encode(&[0u8; 16], 3)]]).unwrap();
        p
    };
    // 2^20 × 2^20 bytes in one chunk: 1 TiB, over the chunk bound
    let tera = craft("tera.btf", 1 << 20);
    refuses(
        &["info", "--verify", s(&tera)],
        &["tera.btf", "array 'big'", "a decoded chunk may hold"],
        None,
    );
    refuses(&["info", s(&tera)], &["tera.btf", "array 'big'"], None);
    // 2^14 × 2^14 bytes: 256 MiB, within the chunk bound but far more than
    // the one small stored chunk can decode to
    let big = craft("big.btf", 1 << 14);
    refuses(
        &["info", "--verify", s(&big)],
        &["big.btf", "array 'big'", "more than zstd can expand to"],
        None,
    );
    let out = dir.path().join("out.png");
    refuses(
        &[
            "export-btf",
            s(&big),
            "--view",
            "0,0",
            "--light",
            "0,0",
            "-o",
            s(&out),
        ],
        &["big.btf", "array 'big'"],
        Some(&out),
    );
}

#[test]
fn quilt_resolution_that_disagrees_with_its_arrays_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (g, _, sv, q) = quilt(dir.path());
    let bad = dir.path().join("res.quilt");
    rewrite(&q, &bad, |meta, _| {
        set_param(meta, "resolution", Param::Int(100_000))
    });
    let needles = [
        "res.quilt",
        "parameter 'resolution' is 100000",
        "array 'coord' is 64×64×2",
    ];
    let out = dir.path().join("out.png");
    refuses(
        &["bake", s(&bad), "--sample", s(&sv), "-o", s(&out)],
        &needles,
        Some(&out),
    );
    refuses(
        &["evaluate", s(&bad), "--gim", s(&g), "--sample", s(&sv)],
        &needles,
        None,
    );
    let folder = dir.path().join("exported");
    refuses(
        &["export", s(&bad), "--sample", s(&sv), "-o", s(&folder)],
        &needles,
        Some(&folder),
    );
    assert!(!folder.exists(), "export created {}", folder.display());
    // consistent arrays, but a resolution beyond any atlas
    let huge = dir.path().join("huge.quilt");
    rewrite(&q, &huge, |meta, _| {
        set_param(meta, "resolution", Param::Int(100_000));
        for a in &mut meta.arrays {
            a.shape[0] = 100_000;
            a.shape[1] = 100_000;
        }
    });
    refuses(
        &["bake", s(&huge), "--sample", s(&sv), "-o", s(&out)],
        &["huge.quilt", "array '"],
        Some(&out),
    );
}

#[test]
fn gim_index_arrays_out_of_range_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let g = gim(dir.path());
    let png = common::brick_crop(dir.path(), 32, None);
    // a covered texel naming a face the mesh does not have
    let chart: Vec<u32> = {
        let c = Container::open(&g, MemoryBudget::default()).unwrap();
        c.read_array(c.array("chart").unwrap()).unwrap()
    };
    let covered = chart.iter().position(|&c| c != u32::MAX).unwrap();
    let bad_face = dir.path().join("face.gim");
    edit_u32(&g, &bad_face, "face", |v| v[covered] = 1_000_000);
    let out = dir.path().join("out.quilt");
    refuses(
        &[
            "tile",
            "--gim",
            s(&bad_face),
            "--sample",
            s(&png),
            "-o",
            s(&out),
            "-q",
        ],
        &["face.gim", "array 'face' holds face 1000000"],
        Some(&out),
    );
    // a triangle naming a vertex the mesh does not have
    let bad_tri = dir.path().join("tri.gim");
    edit_u32(&g, &bad_tri, "mesh_triangles", |v| v[4] = 77_777);
    refuses(
        &[
            "tile",
            "--gim",
            s(&bad_tri),
            "--sample",
            s(&png),
            "-o",
            s(&out),
            "-q",
        ],
        &["tri.gim", "array 'mesh_triangles' holds index 77777"],
        Some(&out),
    );
    let folder = dir.path().join("mesh");
    refuses(
        &["export", s(&bad_tri), "-o", s(&folder)],
        &["tri.gim", "mesh_triangles"],
        Some(&folder),
    );
    // a texel chart beyond the chart count
    let bad_chart = dir.path().join("chart.gim");
    edit_u32(&g, &bad_chart, "chart", |v| v[covered] = 500);
    let png_out = dir.path().join("show.png");
    refuses(
        &["show", s(&bad_chart), "-o", s(&png_out)],
        &["chart.gim", "array 'chart' holds index 500"],
        Some(&png_out),
    );
}

#[test]
fn file_truncated_while_mapped_is_an_error_not_sigbus() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.btf");
    common::ok(&[
        "generate-btf",
        "--size",
        "64",
        "--views",
        "4x2",
        "--lights",
        "4x2",
        "-o",
        s(&p),
        "-q",
    ]);
    let c = Container::open(&p, MemoryBudget(1 << 20)).unwrap();
    let len = c.file_len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    let mut errors = Vec::new();
    let mut reads = 0;
    for (a, spec) in c.metadata().arrays.clone().iter().enumerate() {
        let id = container::ArrayId(a as u32);
        for k in 0..spec.chunk_count() {
            reads += 1;
            let r = match spec.dtype {
                DType::F16 => c.read_chunk::<half::f16>(id, k).map(|_| ()),
                DType::F32 => c.read_chunk::<f32>(id, k).map(|_| ()),
                DType::U32 => c.read_chunk::<u32>(id, k).map(|_| ()),
                DType::U8 => c.read_chunk::<u8>(id, k).map(|_| ()),
            };
            if let Err(e) = r {
                errors.push(e.to_string());
            }
        }
    }
    assert!(
        !errors.is_empty(),
        "{reads} chunk reads of a halved file all succeeded"
    );
    for e in &errors {
        assert!(e.contains("x.btf"), "error does not name the file: {e}");
    }
    if c.is_mapped() {
        // every read through the map checks the length first
        assert_eq!(errors.len(), reads, "some mapped reads went through: {errors:?}");
        let want = format!("changed size while being read (was {len} bytes, now {})", len / 2);
        assert!(errors[0].contains(&want), "{}", errors[0]);
    }
    let err = c.verify().unwrap_err().to_string();
    assert!(err.contains("x.btf"), "{err}");
}

/// Runs `args` on a mutated artifact: it must succeed or refuse cleanly (an
/// exit code, no signal, no panic, an `error:` line naming `name`); a
/// refusal leaves nothing at `output`. Returns whether it refused.
fn clean(args: &[&str], name: &str, output: Option<&Path>) -> bool {
    if let Some(o) = output {
        let _ = std::fs::remove_file(o);
        let _ = std::fs::remove_dir_all(o);
    }
    let out = run_bounded(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let code = out.status.code();
    assert!(
        code.is_some(),
        "btfquilt {args:?} killed by a signal: {:?} {stderr}",
        out.status
    );
    assert!(
        !stderr.contains("panicked"),
        "btfquilt {args:?} panicked: {stderr}"
    );
    if code == Some(0) {
        return false;
    }
    assert!(
        stderr.contains("error:") && stderr.contains(name),
        "btfquilt {args:?} refused without naming {name}: {stderr}"
    );
    if let Some(o) = output {
        assert!(!o.exists(), "btfquilt {args:?} refused but left {}", o.display());
    }
    true
}

/// The mutation loop over one valid artifact: `info --verify` and one
/// consuming command (`consume(mutated path)` → args, output) per case.
fn fuzz(valid: &Path, seed: u64, consume: impl Fn(&str) -> (Vec<String>, Option<PathBuf>)) {
    let bytes = std::fs::read(valid).unwrap();
    let ext = valid.extension().unwrap().to_str().unwrap();
    let name = format!("mutated.{ext}");
    let m = valid.with_file_name(&name);
    let cases = fuzz_cases(40);
    let mut rng = Rng(seed);
    let (mut refused, mut consumed_refused) = (0, 0);
    for _ in 0..cases {
        std::fs::write(&m, mutate(&bytes, &mut rng)).unwrap();
        refused += clean(&["info", "--verify", s(&m)], &name, None) as usize;
        let (args, output) = consume(s(&m));
        let args: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
        consumed_refused += clean(&args, &name, output.as_deref()) as usize;
    }
    eprintln!(
        "{ext}: {cases} mutated cases: info --verify refused {refused}, consumer refused {consumed_refused}"
    );
}

#[test]
fn mutated_gim_is_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let g = gim(dir.path());
    let out = dir.path().join("out.png");
    fuzz(&g, 0x9e37_79b9_7f4a_7c15, |m| {
        (
            ["show", m, "--what", "field", "-o", s(&out)]
                .map(String::from)
                .to_vec(),
            Some(out.clone()),
        )
    });
}

#[test]
fn mutated_svd_is_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, sv, q) = quilt(dir.path());
    let _ = sv;
    let out = dir.path().join("out.png");
    fuzz(&dir.path().join("s.svd"), 0x2545_f491_4f6c_dd1d, |m| {
        (
            ["bake", s(&q), "--sample", m, "-o", s(&out)]
                .map(String::from)
                .to_vec(),
            Some(out.clone()),
        )
    });
}

#[test]
fn mutated_quilt_is_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, sv, q) = quilt(dir.path());
    let out = dir.path().join("out.png");
    fuzz(&q, 0xd1b5_4a32_d192_ed03, |m| {
        (
            ["bake", m, "--sample", s(&sv), "-o", s(&out)]
                .map(String::from)
                .to_vec(),
            Some(out.clone()),
        )
    });
}

#[test]
fn mutated_btf_is_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let b = btf(dir.path());
    let out = dir.path().join("out.svd");
    fuzz(&b, 0x8cb9_2ba7_2f3d_8dd7, |m| {
        (
            ["factorize", m, "-o", s(&out), "--terms", "2", "-q"]
                .map(String::from)
                .to_vec(),
            Some(out.clone()),
        )
    });
}

/// Metadata mutations that keep every checksum valid: a random extent of a
/// random array's shape or chunk shape, or a random integer parameter, set to
/// a hostile value; `info --verify` and a consuming command must still
/// succeed or refuse cleanly, naming the file.
#[test]
fn crafted_metadata_with_valid_checksums_is_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (g, _, sv, q) = quilt(dir.path());
    let out = dir.path().join("out.png");
    let values = [0u64, 1, 2, 3, 63, 65, 100_000, 1 << 20, 1 << 32, u64::MAX];
    let cases = fuzz_cases(40);
    let mut rng = Rng(0x5851_f42d_4c95_7f2d);
    let mut refused = 0;
    for case in 0..cases {
        let (src, name) = if case % 2 == 0 {
            (&g, "crafted.gim")
        } else {
            (&q, "crafted.quilt")
        };
        let m = dir.path().join(name);
        let v = values[rng.below(values.len())];
        rewrite(src, &m, |meta, _| {
            let ints: Vec<usize> = (0..meta.params.len())
                .filter(|&i| matches!(meta.params[i].1, Param::Int(_)))
                .collect();
            match rng.below(3) {
                0 if !ints.is_empty() => {
                    let i = ints[rng.below(ints.len())];
                    meta.params[i].1 = Param::Int(v as i64);
                }
                k => {
                    let a = rng.below(meta.arrays.len());
                    let spec = &mut meta.arrays[a];
                    let dims = if k == 1 {
                        &mut spec.shape
                    } else {
                        &mut spec.chunk_shape
                    };
                    let d = rng.below(dims.len());
                    dims[d] = v;
                }
            }
        });
        let mut r = clean(&["info", "--verify", s(&m)], name, None);
        r |= if case % 2 == 0 {
            clean(
                &["show", s(&m), "--what", "field", "-o", s(&out)],
                name,
                Some(&out),
            )
        } else {
            clean(
                &["bake", s(&m), "--sample", s(&sv), "-o", s(&out)],
                name,
                Some(&out),
            )
        };
        refused += r as usize;
    }
    eprintln!("crafted metadata: {cases} cases, {refused} refused");
}

#[test]
fn a_damaged_chunk_far_into_the_atlas_is_refused_by_the_streaming_outputs() {
    // bake, evaluate and render read the atlas in bands or tiles: a chunk
    // that only the last band/tile reaches must still end in a clean error
    // naming the quilt, with nothing written
    let dir = tempfile::tempdir().unwrap();
    let obj = common::square_obj(dir.path());
    let g = dir.path().join("sq.gim");
    common::ok(&["atlas", s(&obj), "--resolution", "128", "-o", s(&g), "-q"]);
    let (png, _) = svd(dir.path());
    let q = dir.path().join("q.quilt");
    common::ok(&["tile", "--gim", s(&g), "--sample", s(&png), "-o", s(&q), "-q"]);
    // and a BTF surface, whose render looks texels up tile by tile
    let b = btf(dir.path());
    let bsvd = dir.path().join("t.svd");
    common::ok(&["factorize", s(&b), "--rotations", "8", "-o", s(&bsvd), "-q"]);
    let bq = dir.path().join("b.quilt");
    common::ok(&["tile", "--gim", s(&g), "--sample", s(&bsvd), "-o", s(&bq), "-q"]);
    let damage = |from: &Path, name: &str| {
        let bad = dir.path().join(name);
        rewrite(from, &bad, |meta, chunks| {
            let coord = &mut chunks[array_index(meta, "coord")];
            assert_eq!(coord.len(), 4, "128² in 64² chunks");
            // a frame that decodes to the wrong size
            coord[3] = codec::encode(&[0f32; 10], 3);
        });
        bad
    };
    let (bad, bad_btf) = (damage(&q, "bad.quilt"), damage(&bq, "bad_btf.quilt"));
    let out = dir.path().join("out.png");
    let needle = "array 'coord', chunk 3";
    let render = |q: &Path| -> Vec<String> {
        let q = s(q).to_string();
        ["render", &q, "--width", "64", "--height", "48", "-o", s(&out)]
            .map(String::from)
            .to_vec()
    };
    let exr = dir.path().join("out.exr");
    refuses(
        &["bake", s(&bad), "-o", s(&exr)],
        &["bad.quilt", needle],
        Some(&exr),
    );
    assert!(!exr.exists(), "bake wrote {}", exr.display());
    for args in [
        ["bake", s(&bad), "-o", s(&out)].map(String::from).to_vec(),
        render(&bad),
        render(&bad_btf),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refuses(&args, &[args[1], needle], Some(&out));
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
    refuses(&["evaluate", s(&bad)], &["bad.quilt", needle], None);
}
