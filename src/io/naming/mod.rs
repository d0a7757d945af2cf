//! BTF image folders: Bonn/UTIA style file names, CSV manifests, and
//! organising (view, light) pairs into a full view × light grid.

use std::io::Write;
use std::path::{Component, Path, PathBuf};

use crate::io::imageio::{write_atomic, IMAGE_EXTENSIONS};
use crate::{Error, Result};

/// A direction: polar angle θ and azimuth φ, in degrees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Angles {
    pub theta: f32,
    pub phi: f32,
}

/// One BTF image: the file and its view and light directions.
#[derive(Clone, Debug, PartialEq)]
pub struct PairFile {
    pub path: PathBuf,
    pub view: Angles,
    pub light: Angles,
}

/// Angular tolerance (degrees) under which two directions are the same.
const SAME_DIR_EPS: f32 = 1e-3;

/// The manifest header, field by field.
const MANIFEST_HEADER: [&str; 5] = ["file", "theta_v", "phi_v", "theta_l", "phi_l"];

/// Parses a non-negative decimal `digits[.digits]`.
fn parse_decimal(s: &str) -> Option<f32> {
    let (int, frac) = match s.split_once('.') {
        Some((i, f)) => (i, Some(f)),
        None => (s, None),
    };
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    if !digits(int) || frac.is_some_and(|f| !digits(f)) {
        return None;
    }
    s.parse::<f32>().ok().filter(|v| v.is_finite())
}

/// Parse a Bonn/UTIA style name like `bricks_tl015_pl000_tv030_pv045.png`; returns (view, light).
///
/// Tokens separated by `_` that start with `tl`, `pl`, `tv` or `pv`
/// (case-insensitive) followed by a digit or `.` must be non-negative decimals;
/// all four are required exactly once. Other tokens (the prefix) are ignored.
/// A trailing `.ext` is stripped when it starts with a letter.
pub fn parse_pair_name(file_name: &str) -> std::result::Result<(Angles, Angles), String> {
    let stem = match file_name.rsplit_once('.') {
        Some((stem, ext)) if ext.starts_with(|c: char| c.is_ascii_alphabetic()) => stem,
        _ => file_name,
    };
    const KEYS: [&str; 4] = ["tl", "pl", "tv", "pv"];
    let mut found: [Option<f32>; 4] = [None; 4];
    for token in stem.split('_') {
        let lower = token.to_ascii_lowercase();
        let Some(k) = KEYS.iter().position(|key| lower.starts_with(key)) else {
            continue;
        };
        let rest = &token[2..];
        if !rest.starts_with(|c: char| c.is_ascii_digit() || c == '.' || c == '-' || c == '+') {
            // An ordinary word such as "plaster" or "tvshow".
            continue;
        }
        let value = parse_decimal(rest).ok_or_else(|| {
            format!(
                "'{token}' in '{file_name}': {} angle '{rest}' is not a non-negative decimal number",
                KEYS[k]
            )
        })?;
        if found[k].is_some() {
            return Err(format!("'{file_name}': {} appears more than once", KEYS[k]));
        }
        found[k] = Some(value);
    }
    match found {
        [Some(tl), Some(pl), Some(tv), Some(pv)] => {
            Ok((Angles { theta: tv, phi: pv }, Angles { theta: tl, phi: pl }))
        }
        _ => {
            let missing: Vec<&str> = KEYS
                .iter()
                .zip(&found)
                .filter(|(_, v)| v.is_none())
                .map(|(k, _)| *k)
                .collect();
            Err(format!(
                "'{file_name}': missing {} (expected a name like prefix_tl015_pl000_tv030_pv045.png)",
                missing.join(", ")
            ))
        }
    }
}

/// Formats one angle: `{:03}` when integral, else up to 3 fraction digits (`007.5`).
fn format_angle(v: f32) -> String {
    if !v.is_finite() || v < 0.0 {
        return format!("{v}");
    }
    if v.fract() == 0.0 && v < 1e15 {
        return format!("{:03}", v as u64);
    }
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    match s.split_once('.') {
        Some((int, frac)) => format!("{int:0>3}.{frac}"),
        None => format!("{s:0>3}"),
    }
}

/// Format the canonical name `{prefix}_tl{θl}_pl{φl}_tv{θv}_pv{φv}.{ext}`.
///
/// Angles are `{:03}` integers when integral, otherwise decimals with up to
/// 3 fraction digits (`tl007.5`); angles with at most 3 decimals parse back
/// exactly. An empty prefix or extension is left out with its separator.
pub fn format_pair_name(prefix: &str, view: Angles, light: Angles, ext: &str) -> String {
    let mut s = String::new();
    if !prefix.is_empty() {
        s.push_str(prefix);
        s.push('_');
    }
    s.push_str(&format!(
        "tl{}_pl{}_tv{}_pv{}",
        format_angle(light.theta),
        format_angle(light.phi),
        format_angle(view.theta),
        format_angle(view.phi)
    ));
    let ext = ext.trim_start_matches('.');
    if !ext.is_empty() {
        s.push('.');
        s.push_str(ext);
    }
    s
}

/// True if the path has one of the BTF image extensions (case-insensitive).
fn has_image_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// Scan a directory for BTF image files whose names parse, sorted by file name.
///
/// Files with other extensions, hidden files (names starting with `.`) and
/// subdirectories are ignored; an image file whose name does not parse is an
/// error, as is a folder without images.
pub fn scan_folder(dir: &Path) -> Result<Vec<PairFile>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut named = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let path = entry.path();
        if path.is_dir() || !has_image_extension(&path) {
            continue;
        }
        let Some(name) = entry.file_name().to_str().map(str::to_owned) else {
            return Err(Error::input(&path, "file name is not valid UTF-8"));
        };
        if name.starts_with('.') {
            continue;
        }
        named.push((name, path));
    }
    named.sort();
    if named.is_empty() {
        return Err(Error::input(
            dir,
            "no BTF images found (expected .png/.exr/.jpg/.jpeg/.tif/.tiff files named like prefix_tl015_pl000_tv030_pv045.png)",
        ));
    }
    let files: Vec<PairFile> = named
        .into_iter()
        .map(|(name, path)| match parse_pair_name(&name) {
            Ok((view, light)) => Ok(PairFile { path, view, light }),
            Err(reason) => Err(Error::input(&path, reason)),
        })
        .collect::<Result<_>>()?;
    // one BTF per folder: images of two formats are two exports mixed
    let ext = |p: &Path| {
        p.extension()
            .map(|e| match e.to_string_lossy().to_ascii_lowercase().as_str() {
                "jpeg" => "jpg".to_string(),
                "tiff" => "tif".to_string(),
                e => e.to_string(),
            })
            .unwrap_or_default()
    };
    let first = ext(&files[0].path);
    if let Some(other) = files.iter().find(|f| ext(&f.path) != first) {
        return Err(Error::input(
            dir,
            format!(
                "holds BTF images of more than one format (.{first} and {}): one BTF per folder",
                other.path.display()
            ),
        ));
    }
    Ok(files)
}

/// `line` without the spaces and tabs around its fields (outside quotes), so
/// that a quote after such space still opens a quoted field for csv.
fn tighten(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut in_quotes = false;
    for c in line.chars() {
        match c {
            '"' => in_quotes = !in_quotes,
            ',' if !in_quotes => {
                let kept = out.trim_end_matches([' ', '\t']).len();
                out.truncate(kept);
            }
            ' ' | '\t' if !in_quotes && (out.is_empty() || out.ends_with([',', '"'])) => continue,
            _ => {}
        }
        out.push(c);
    }
    let kept = out.trim_end_matches([' ', '\t']).len();
    out.truncate(kept);
    out
}

/// Splits one CSV line (csv crate) into fields, without the spaces and tabs
/// around them; `"..."` quoting with `""` escapes.
fn split_csv(line: &str) -> std::result::Result<Vec<String>, String> {
    // csv reads an unterminated quote to the end of the line; refuse it
    if line.matches('"').count() % 2 == 1 {
        return Err("unterminated quoted field".into());
    }
    let line = tighten(line);
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .from_reader(line.as_bytes());
    let mut record = csv::StringRecord::new();
    match reader.read_record(&mut record) {
        Ok(true) => Ok(record.iter().map(str::to_string).collect()),
        Ok(false) => Ok(vec![String::new()]),
        Err(e) => Err(e.to_string()),
    }
}

/// A manifest writer: fields quoted only when needed (a comma, a quote, a
/// `#`, a line break).
fn manifest_writer(out: Vec<u8>) -> csv::Writer<Vec<u8>> {
    csv::WriterBuilder::new()
        .quote_style(csv::QuoteStyle::Necessary)
        .comment(Some(b'#'))
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(out)
}

/// Parses one manifest angle field.
fn parse_manifest_angle(field: &str, name: &str) -> std::result::Result<f32, String> {
    let v: f32 = field
        .parse()
        .map_err(|_| format!("{name} '{field}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("{name} '{field}' is not finite"));
    }
    if v < 0.0 {
        return Err(format!("{name} {v} is negative"));
    }
    if name.starts_with("theta") && v > 90.0 {
        return Err(format!("{name} {v} is outside [0, 90]"));
    }
    Ok(v)
}

/// Read a CSV manifest with header `file,theta_v,phi_v,theta_l,phi_l`.
///
/// Whitespace around fields is allowed, blank lines and `#` lines are
/// ignored, and files are relative to the manifest's directory. Errors name
/// the manifest and the line number.
pub fn read_manifest(path: &Path) -> Result<Vec<PairFile>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = String::from_utf8(bytes).map_err(|_| Error::input(path, "manifest is not valid UTF-8"))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let base = path.parent().unwrap_or(Path::new(""));
    let mut header_seen = false;
    let mut files = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let bad = |reason: String| Error::input(path, format!("line {n}: {reason}"));
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let fields = split_csv(line).map_err(bad)?;
        if !header_seen {
            let ok = fields.len() == MANIFEST_HEADER.len()
                && fields
                    .iter()
                    .zip(MANIFEST_HEADER)
                    .all(|(f, h)| f.eq_ignore_ascii_case(h));
            if !ok {
                return Err(bad(format!(
                    "bad header '{trimmed}', expected '{}'",
                    MANIFEST_HEADER.join(",")
                )));
            }
            header_seen = true;
            continue;
        }
        if fields.len() != MANIFEST_HEADER.len() {
            return Err(bad(format!(
                "expected {} fields (file,theta_v,phi_v,theta_l,phi_l), found {}",
                MANIFEST_HEADER.len(),
                fields.len()
            )));
        }
        if fields[0].is_empty() {
            return Err(bad("empty file name".into()));
        }
        let mut a = [0.0f32; 4];
        for (k, v) in a.iter_mut().enumerate() {
            *v = parse_manifest_angle(&fields[k + 1], MANIFEST_HEADER[k + 1]).map_err(bad)?;
        }
        files.push(PairFile {
            path: base.join(&fields[0]),
            view: Angles {
                theta: a[0],
                phi: a[1],
            },
            light: Angles {
                theta: a[2],
                phi: a[3],
            },
        });
    }
    if !header_seen {
        return Err(Error::input(
            path,
            format!(
                "empty manifest: expected the header '{}'",
                MANIFEST_HEADER.join(",")
            ),
        ));
    }
    if files.is_empty() {
        return Err(Error::input(path, "manifest lists no images"));
    }
    Ok(files)
}

/// True if the path has no `.` or `..` components.
fn is_normal(path: &Path) -> bool {
    !path
        .components()
        .any(|c| matches!(c, Component::CurDir | Component::ParentDir))
}

/// `file` relative to `base`, or `file` unchanged when that is not possible.
fn relative_to(file: &Path, base: &Path) -> PathBuf {
    if let Ok(rel) = file.strip_prefix(base) {
        return rel.to_path_buf();
    }
    let (Ok(f), Ok(b)) = (std::path::absolute(file), std::path::absolute(base)) else {
        return file.to_path_buf();
    };
    if !is_normal(&f) || !is_normal(&b) {
        return f;
    }
    let fc: Vec<Component> = f.components().collect();
    let bc: Vec<Component> = b.components().collect();
    let common = fc.iter().zip(&bc).take_while(|(x, y)| x == y).count();
    // Only climb out of the base directory within the same root.
    if common == 0 || matches!(fc.get(common), Some(Component::Prefix(_))) {
        return f;
    }
    let mut rel = PathBuf::new();
    for _ in common..bc.len() {
        rel.push("..");
    }
    for c in &fc[common..] {
        rel.push(c);
    }
    rel
}

/// Write a manifest (atomically) listing files relative to its directory.
///
/// Angles are written in the shortest form that reads back exactly.
pub fn write_manifest(path: &Path, files: &[PairFile]) -> Result<()> {
    let base = path.parent().unwrap_or(Path::new(""));
    let csv_error = |e: csv::Error| Error::input(path, format!("cannot write the manifest: {e}"));
    let mut w = manifest_writer(Vec::new());
    w.write_record(MANIFEST_HEADER).map_err(csv_error)?;
    for f in files {
        let rel = relative_to(&f.path, base);
        let name = rel.to_str().ok_or_else(|| {
            Error::input(
                &f.path,
                "file name is not valid UTF-8; cannot list it in a manifest",
            )
        })?;
        if name.contains(['\n', '\r']) {
            return Err(Error::input(
                &f.path,
                "file name contains a line break; cannot list it in a manifest",
            ));
        }
        if name.trim_matches([' ', '\t']) != name {
            return Err(Error::input(
                &f.path,
                "file name starts or ends with a space; cannot list it in a manifest",
            ));
        }
        let angles = [f.view.theta, f.view.phi, f.light.theta, f.light.phi].map(|v| v.to_string());
        w.write_record(std::iter::once(name).chain(angles.iter().map(String::as_str)))
            .map_err(csv_error)?;
    }
    let text = w
        .into_inner()
        .map_err(|e| Error::input(path, format!("cannot write the manifest: {e}")))?;
    write_atomic(path, |w| w.write_all(&text).map_err(|e| Error::io(path, e)))
}

/// True if `a` and `b` are the same direction (within tolerance; φ wraps; the pole ignores φ).
fn same_direction(a: Angles, b: Angles) -> bool {
    if a.theta.abs() < SAME_DIR_EPS && b.theta.abs() < SAME_DIR_EPS {
        return true;
    }
    let dphi = (a.phi - b.phi).abs();
    (a.theta - b.theta).abs() < SAME_DIR_EPS && dphi.min(360.0 - dphi) < SAME_DIR_EPS
}

/// Index of the direction in `dirs` (sorted by θ) that is the same as `a`.
fn find_direction(dirs: &[Angles], a: Angles) -> Option<usize> {
    let start = dirs.partition_point(|d| d.theta <= a.theta - SAME_DIR_EPS);
    dirs[start..]
        .iter()
        .take_while(|d| d.theta < a.theta + SAME_DIR_EPS)
        .position(|d| same_direction(*d, a))
        .map(|i| start + i)
}

/// The distinct directions, in order of first appearance after sorting by (θ, φ).
fn distinct_directions(all: impl Iterator<Item = Angles>) -> Vec<Angles> {
    let mut sorted: Vec<Angles> = all.collect();
    sorted.sort_by(|a, b| a.theta.total_cmp(&b.theta).then(a.phi.total_cmp(&b.phi)));
    let mut dirs: Vec<Angles> = Vec::new();
    for a in sorted {
        if find_direction(&dirs, a).is_none() {
            dirs.push(a);
        }
    }
    dirs
}

/// Short text for a direction.
fn show(a: Angles) -> String {
    format!("(θ={}, φ={})", a.theta, a.phi)
}

/// Checks a direction's range for `organise_pairs`.
fn check_range(file: &PairFile, what: &str, a: Angles) -> Result<()> {
    if !(0.0..=90.0).contains(&a.theta) {
        return Err(Error::input(
            &file.path,
            format!("{what} θ = {} is outside [0, 90] degrees", a.theta),
        ));
    }
    if !(0.0..360.0).contains(&a.phi) {
        return Err(Error::input(
            &file.path,
            format!("{what} φ = {} is outside [0, 360) degrees", a.phi),
        ));
    }
    Ok(())
}

/// Organise pairs into a full view × light product: returns (views, lights, grid).
///
/// `views`/`lights` are the distinct directions in order of first appearance
/// after sorting by (θ, φ); `grid[v * lights.len() + l]` indexes `files`.
/// Directions closer than 1e-3° in θ and φ are the same, and all directions
/// with θ ≈ 0 are the pole. Errors: angles out of range, duplicate pairs
/// (both files named), and missing pairs (up to 5 listed, with the count).
pub fn organise_pairs(origin: &Path, files: &[PairFile]) -> Result<(Vec<Angles>, Vec<Angles>, Vec<usize>)> {
    if files.is_empty() {
        return Err(Error::input(origin, "no BTF images"));
    }
    for f in files {
        check_range(f, "view", f.view)?;
        check_range(f, "light", f.light)?;
    }
    let views = distinct_directions(files.iter().map(|f| f.view));
    let lights = distinct_directions(files.iter().map(|f| f.light));
    let nl = lights.len();
    let mut grid = vec![usize::MAX; views.len() * nl];
    for (i, f) in files.iter().enumerate() {
        // Every direction was inserted above, so the lookups succeed.
        let (Some(v), Some(l)) = (find_direction(&views, f.view), find_direction(&lights, f.light)) else {
            return Err(Error::input(&f.path, "internal error: direction not found"));
        };
        let slot = &mut grid[v * nl + l];
        if *slot != usize::MAX {
            return Err(Error::input(
                &f.path,
                format!(
                    "duplicate pair: view {} light {} is also given by {}",
                    show(f.view),
                    show(f.light),
                    files[*slot].path.display()
                ),
            ));
        }
        *slot = i;
    }
    let missing: Vec<usize> = (0..grid.len()).filter(|&s| grid[s] == usize::MAX).collect();
    if !missing.is_empty() {
        let examples: Vec<String> = missing
            .iter()
            .take(5)
            .map(|&s| format!("view {} light {}", show(views[s / nl]), show(lights[s % nl])))
            .collect();
        return Err(Error::input(
            origin,
            format!(
                "{} of the {} × {} view × light pairs are missing, e.g. {}",
                missing.len(),
                views.len(),
                nl,
                examples.join("; ")
            ),
        ));
    }
    Ok((views, lights, grid))
}

#[cfg(test)]
mod tests;
