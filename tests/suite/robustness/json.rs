//! JSON inputs: a strokes file (`paint --region strokes.json`) and a field
//! keys file (`atlas --field keys.json`). Deep nesting (which overflowed the
//! stack of the old recursive reader), wrong types, missing fields, trailing
//! junk, out-of-range numbers, an empty file and bytes that are not UTF-8 are
//! refused naming the file and the place; nothing is written at `-o`. Plus
//! seeded mutation loops over a valid file of each kind.

use std::path::{Path, PathBuf};

use crate::common;
use crate::robustness::{fuzz_cases, mutate, refuses, Rng};

/// A valid strokes file.
const STROKES: &str =
    "[{\"point\": [0.5, 0.5, 0], \"radius\": 0.2},\n {\"point\": [0.1, 0.8, 0.0], \"radius\": 0.05}]\n";

/// A valid keys file for the square (128 faces).
const KEYS: &str = "[{\"face\": 12, \"dir\": [1, 0, 0]},\n {\"face\": 100, \"dir\": [0.5, 0.5, 0]}]\n";

/// Bad JSON for both readers, each with what the message must say;
/// `valid_item` is one valid element whose first "0." is replaced to make
/// out-of-range and non-JSON numbers.
fn bad_documents(valid_item: &str) -> Vec<(&'static str, Vec<u8>, Vec<&'static str>)> {
    let deep = "[".repeat(50_000) + &"]".repeat(50_000);
    vec![
        // refused by type at the first inner '[' (a typed reader does not
        // descend into what cannot be a stroke or key; see also
        // `deep_unknown_fields_are_skipped`)
        ("deep", deep.into_bytes(), vec!["invalid type", "line 1"]),
        ("deep_open", "[".repeat(50_000).into_bytes(), vec!["line 1"]),
        ("empty", Vec::new(), vec!["EOF"]),
        ("object", b"{\"a\": 1}".to_vec(), vec!["expected a sequence"]),
        ("number", b"[1, 2]".to_vec(), vec!["line 1 column"]),
        (
            "trailing",
            format!("[{valid_item}] junk").into_bytes(),
            vec!["trailing characters"],
        ),
        (
            "inf",
            format!("[{}]", valid_item.replacen("0.", "1e999", 1)).into_bytes(),
            vec!["out of range"],
        ),
        (
            "nan",
            format!("[{}]", valid_item.replacen("0.", "NaN", 1)).into_bytes(),
            vec!["line 1"],
        ),
        ("not_utf8", b"[{\"\xff\xfe\": 1}]".to_vec(), vec!["line 1"]),
        (
            "wrong_type",
            format!("[{}]", valid_item.replacen('[', "\"", 1).replacen(']', "\"", 1)).into_bytes(),
            vec!["invalid type"],
        ),
    ]
}

/// The square's atlas (64²), its tiling with a 32² brick crop, and a full
/// foreground mask for painting.
struct Fixture {
    dir: tempfile::TempDir,
    obj: PathBuf,
    quilt: PathBuf,
    mask: PathBuf,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let obj = common::square_obj(dir.path());
    let brick = common::brick_crop(dir.path(), 32, None);
    let gim = dir.path().join("sq.gim");
    let quilt = dir.path().join("q.quilt");
    let mask = dir.path().join("all32.png");
    common::write_mask_png(&mask, 32, 32, |_, _| true);
    common::ok(&[
        "atlas",
        common::s(&obj),
        "--resolution",
        "64",
        "-o",
        common::s(&gim),
    ]);
    common::ok(&[
        "tile",
        "--gim",
        common::s(&gim),
        "--sample",
        common::s(&brick),
        "-o",
        common::s(&quilt),
    ]);
    Fixture {
        dir,
        obj,
        quilt,
        mask,
    }
}

fn paint_args<'a>(f: &'a Fixture, strokes: &'a Path, out: &'a Path) -> [&'a str; 8] {
    [
        "paint",
        common::s(&f.quilt),
        "--sample-mask",
        common::s(&f.mask),
        "--region",
        common::s(strokes),
        "-o",
        common::s(out),
    ]
}

fn atlas_args<'a>(f: &'a Fixture, keys: &'a Path, out: &'a Path) -> [&'a str; 8] {
    [
        "atlas",
        common::s(&f.obj),
        "--resolution",
        "64",
        "--field",
        common::s(keys),
        "-o",
        common::s(out),
    ]
}

#[test]
fn valid_strokes_and_keys_are_read() {
    // the fixtures the refusals below are variations of do work
    let f = fixture();
    let (strokes, keys) = (f.dir.path().join("s.json"), f.dir.path().join("k.json"));
    std::fs::write(&strokes, STROKES).unwrap();
    std::fs::write(&keys, KEYS).unwrap();
    let (po, ao) = (f.dir.path().join("p.quilt"), f.dir.path().join("k.gim"));
    common::ok(&paint_args(&f, &strokes, &po));
    common::ok(&atlas_args(&f, &keys, &ao));
    assert!(po.exists() && ao.exists());
}

#[test]
fn deep_unknown_fields_are_skipped() {
    // an unknown field is skipped (as the old reader ignored extra fields):
    // serde_json skips a value without recursing, so 50,000 levels there
    // neither overflow the stack nor hit its recursion limit
    let f = fixture();
    let deep = "[".repeat(50_000) + &"]".repeat(50_000);
    let (strokes, keys) = (f.dir.path().join("s.json"), f.dir.path().join("k.json"));
    std::fs::write(&strokes, format!("[{{\"extra\": {deep}, {}", &STROKES[2..])).unwrap();
    std::fs::write(&keys, format!("[{{\"extra\": {deep}, {}", &KEYS[2..])).unwrap();
    let (po, ao) = (f.dir.path().join("p.quilt"), f.dir.path().join("k.gim"));
    common::ok(&paint_args(&f, &strokes, &po));
    common::ok(&atlas_args(&f, &keys, &ao));
    assert!(po.exists() && ao.exists());
}

#[test]
fn bad_strokes_files_are_refused_naming_file_and_place() {
    let f = fixture();
    let out = f.dir.path().join("out.quilt");
    for (name, bytes, needles) in bad_documents("{\"point\": [0.5, 0.5, 0], \"radius\": 0.2}") {
        let p = f.dir.path().join(format!("{name}.json"));
        std::fs::write(&p, &bytes).unwrap();
        let file = format!("{name}.json");
        let mut want = vec![file.as_str(), "is not a stroke list"];
        want.extend(needles);
        refuses(&paint_args(&f, &p, &out), &want, Some(&out));
    }
    for (name, text, needle) in [
        (
            "no_radius",
            "[{\"point\": [0.5, 0.5, 0]}]",
            "missing field `radius`",
        ),
        (
            "short_point",
            "[{\"point\": [0.5, 0.5], \"radius\": 0.2}]",
            "array of length 3",
        ),
        (
            "zero_radius",
            "[{\"point\": [0.5, 0.5, 0], \"radius\": 0}]",
            "stroke 0 has no positive \"radius\"",
        ),
        ("none", "[]", "the list is empty"),
    ] {
        let p = f.dir.path().join(format!("{name}.json"));
        std::fs::write(&p, text).unwrap();
        refuses(
            &paint_args(&f, &p, &out),
            &[&format!("{name}.json"), needle],
            Some(&out),
        );
    }
}

#[test]
fn bad_field_keys_are_refused_naming_file_and_place() {
    let f = fixture();
    let out = f.dir.path().join("out.gim");
    for (name, bytes, needles) in bad_documents("{\"face\": 12, \"dir\": [0.5, 0, 0]}") {
        let p = f.dir.path().join(format!("{name}.json"));
        std::fs::write(&p, &bytes).unwrap();
        let file = format!("{name}.json");
        let mut want = vec![file.as_str(), "not valid JSON field keys"];
        want.extend(needles);
        refuses(&atlas_args(&f, &p, &out), &want, Some(&out));
    }
    for (name, text, needle) in [
        ("no_dir", "[{\"face\": 3}]", "missing field `dir`"),
        (
            "string_face",
            "[{\"face\": \"3\", \"dir\": [1, 0, 0]}]",
            "invalid type: string",
        ),
        (
            "far_face",
            "[{\"face\": 4000000000, \"dir\": [1, 0, 0]}]",
            "face 4000000000 is not a face index",
        ),
        ("zero_dir", "[{\"face\": 3, \"dir\": [0, 0, 0]}]", "non-zero"),
    ] {
        let p = f.dir.path().join(format!("{name}.json"));
        std::fs::write(&p, text).unwrap();
        refuses(
            &atlas_args(&f, &p, &out),
            &[&format!("{name}.json"), needle],
            Some(&out),
        );
    }
}

/// Mutates `valid` `cases` times through `run`, asserting each run either
/// succeeds or refuses cleanly naming the file, never a signal or panic.
fn mutation_loop(label: &str, valid: &str, seed: u64, file: &Path, out: &Path, args: &[&str]) {
    let mut rng = Rng(seed);
    let cases = fuzz_cases(40);
    let (mut read, mut refused) = (0, 0);
    for case in 0..cases {
        std::fs::write(file, mutate(valid.as_bytes(), &mut rng)).unwrap();
        if crate::robustness::read_or_refused(&format!("{label} case {case}"), args, file, out) {
            read += 1;
        } else {
            refused += 1;
        }
    }
    eprintln!("mutated {label}: {cases} cases, {read} read, {refused} refused");
}

#[test]
fn mutated_strokes_and_keys_are_read_or_refused_cleanly() {
    let f = fixture();
    let (strokes, keys) = (
        f.dir.path().join("m_strokes.json"),
        f.dir.path().join("m_keys.json"),
    );
    let (po, ao) = (f.dir.path().join("m.quilt"), f.dir.path().join("m.gim"));
    mutation_loop(
        "strokes",
        STROKES,
        0x5eed_0001,
        &strokes,
        &po,
        &paint_args(&f, &strokes, &po),
    );
    mutation_loop(
        "field keys",
        KEYS,
        0x5eed_0002,
        &keys,
        &ao,
        &atlas_args(&f, &keys, &ao),
    );
}
