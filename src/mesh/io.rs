//! Reading OBJ and PLY meshes (repaired on load, see [`repair`]) and writing
//! OBJ (with atlas UVs) and ASCII PLY (with paint).

use super::repair::{self, RepairReport};
use super::Mesh;
use crate::io::imageio::write_atomic;
use crate::{Error, Result};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Property, PropertyAccess, PropertyAccessResult, PropertyType};
use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

/// How [`load`] cleans up a mesh.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Weld vertices closer than this fraction of the median edge length
    /// (0 = exact duplicates only). Default 1e-6.
    pub weld_tolerance: f32,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { weld_tolerance: 1e-6 }
    }
}

/// Loads an OBJ or PLY mesh (chosen by extension, case-insensitive) and
/// repairs it with [`repair::repair`].
///
/// OBJ: polygons are triangulated, materials, normals and UVs ignored, vertex
/// colours (`v x y z r g b`) kept. PLY (ASCII or binary): element `vertex` with
/// `x`, `y`, `z`, optional `red`/`green`/`blue` (uchar 0..255 or float 0..1) and
/// an optional scalar `quality`, `weight`, `value` or `confidence`; element
/// `face` with a `vertex_indices` (or `vertex_index`) list, fan-triangulated.
/// Errors name the file and the problem: unknown extension, unreadable or
/// unparseable file, non-finite coordinates, out-of-range indices, or no usable
/// triangles.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<(Mesh, RepairReport)> {
    if !(opts.weld_tolerance.is_finite() && (0.0..=0.5).contains(&opts.weld_tolerance)) {
        return Err(Error::Config(format!(
            "--weld {}: must be a finite number in 0..=0.5 (a fraction of the median edge length; \
             0 welds exact duplicates only)",
            opts.weld_tolerance
        )));
    }
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
    let mut mesh = match ext.as_deref() {
        Some("obj") => read_obj(path)?,
        Some("ply") => read_ply(path)?,
        Some(other) => {
            return Err(Error::input(
                path,
                format!("unknown mesh format '.{other}': expected a .obj or .ply file"),
            ))
        }
        None => {
            return Err(Error::input(
                path,
                "no file extension: expected a .obj or .ply file",
            ))
        }
    };
    validate(path, &mesh)?;
    if mesh.triangles.is_empty() {
        return Err(Error::input(
            path,
            format!(
                "no usable triangles: the file has {} vertices and no faces",
                mesh.positions.len()
            ),
        ));
    }
    let report = repair::repair(&mut mesh, opts.weld_tolerance);
    if mesh.triangles.is_empty() {
        return Err(Error::input(
            path,
            format!(
                "no usable triangles: {} degenerate (repeated vertices or zero area), so the mesh has no surface",
                if report.input_faces == 1 {
                    "its only triangle is".to_string()
                } else {
                    format!("all {} triangles are", report.input_faces)
                }
            ),
        ));
    }
    Ok((mesh, report))
}

/// Checks finite coordinates and in-range indices (0-based numbers).
fn validate(path: &Path, mesh: &Mesh) -> Result<()> {
    if let Some(v) = mesh
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        let p = mesh.positions[v];
        return Err(Error::input(
            path,
            format!(
                "vertex {v} (counting from 0) has a non-finite coordinate ({} {} {})",
                p[0], p[1], p[2]
            ),
        ));
    }
    let n = mesh.positions.len();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if let Some(&v) = t.iter().find(|&&v| v as usize >= n) {
            return Err(Error::input(
                path,
                format!("triangle {f} refers to vertex {v}, but there are only {n} vertices"),
            ));
        }
    }
    Ok(())
}

fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    if bytes.iter().all(|b| b.is_ascii_whitespace()) {
        return Err(Error::input(path, "empty file: no usable triangles"));
    }
    Ok(bytes)
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        s.to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "internal error".to_string()
    }
}

fn read_obj(path: &Path) -> Result<Mesh> {
    let bytes = read_bytes(path)?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        Error::input(
            path,
            format!("not a text OBJ file: invalid UTF-8 at byte {}", e.valid_up_to()),
        )
    })?;
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    // Without object, group and material lines tobj returns one model, so
    // vertices shared between groups are not duplicated.
    let mut body = String::with_capacity(text.len());
    for line in text.lines() {
        if !matches!(
            line.split_whitespace().next(),
            Some("o" | "g" | "usemtl" | "mtllib")
        ) {
            body.push_str(line);
            body.push('\n');
        }
    }
    let parsed = catch_unwind(AssertUnwindSafe(|| {
        tobj::load_obj_buf(&mut body.as_bytes(), &options, |_| Ok(Default::default()))
    }));
    let models = match parsed {
        Ok(Ok((models, _materials))) => models,
        Ok(Err(e)) => {
            let reason = diagnose_obj(text).unwrap_or_else(|| match e {
                tobj::LoadError::FaceColorOutOfBounds => {
                    "some vertices have colours (v x y z r g b) and others do not".to_string()
                }
                _ => format!("cannot parse OBJ: {e}"),
            });
            return Err(Error::input(path, reason));
        }
        Err(p) => {
            let reason = diagnose_obj(text)
                .unwrap_or_else(|| format!("cannot parse OBJ: the parser failed ({})", panic_message(&*p)));
            return Err(Error::input(path, reason));
        }
    };
    let has_colors = models.iter().any(|m| !m.mesh.vertex_color.is_empty());
    let mut mesh = Mesh::default();
    let mut colors = Vec::new();
    for m in &models {
        let m = &m.mesh;
        let offset = mesh.positions.len() as u32;
        mesh.positions
            .extend(m.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        if has_colors {
            let n = m.positions.len() / 3;
            colors.extend(
                m.vertex_color
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .chain(std::iter::repeat([0.0; 3]).take(n.saturating_sub(m.vertex_color.len() / 3))),
            );
            colors.truncate(mesh.positions.len());
        }
        mesh.triangles.extend(
            m.indices
                .chunks_exact(3)
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }
    if has_colors {
        mesh.vertex_colors = Some(colors);
    }
    if mesh.triangles.is_empty() {
        return Err(Error::input(path, diagnose_no_triangles(text)));
    }
    if mesh.positions.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        let reason =
            locate_nonfinite_obj(text).unwrap_or_else(|| "a vertex has a non-finite coordinate".into());
        return Err(Error::input(path, reason));
    }
    Ok(mesh)
}

/// Says why an OBJ the parser read gave no triangles, counting its own
/// `v` and `f` lines.
fn diagnose_no_triangles(text: &str) -> String {
    let (mut vertices, mut faces, mut short) = (0usize, 0usize, 0usize);
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => vertices += 1,
            Some("f") => {
                faces += 1;
                if words.count() < 3 {
                    short += 1;
                }
            }
            _ => {}
        }
    }
    if faces == 0 {
        format!("no usable triangles: the file has {vertices} vertices but no faces ('f' lines)")
    } else if short == faces {
        format!(
            "no usable triangles: {} fewer than 3 vertices, and a face needs at least 3 to be a surface",
            if faces == 1 {
                "its only face ('f' line) has".to_string()
            } else {
                format!("all {faces} faces ('f' lines) have")
            }
        )
    } else {
        format!("no usable triangles: none of its {faces} faces ('f' lines) could be read as a polygon")
    }
}

/// Finds the first bad vertex line or face index in an OBJ the parser
/// rejected, in the file's own numbering.
fn diagnose_obj(text: &str) -> Option<String> {
    let is_v = |l: &str| l.split_whitespace().next() == Some("v");
    let total = text.lines().filter(|l| is_v(l)).count() as i64;
    let (mut vertices, mut faces) = (0i64, 0usize);
    for (ln, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => {
                vertices += 1;
                let ok = words.take(3).filter(|w| w.parse::<f32>().is_ok()).count() == 3;
                if !ok {
                    return Some(format!(
                        "vertex {vertices} (line {}): expected three numbers, found '{}'",
                        ln + 1,
                        line.trim()
                    ));
                }
            }
            Some("f") => {
                faces += 1;
                for w in words {
                    let index = w.split('/').next().unwrap_or("");
                    let Ok(i) = index.parse::<i64>() else {
                        return Some(format!(
                            "face {faces} (line {}): cannot read vertex index '{w}'",
                            ln + 1
                        ));
                    };
                    let absolute = if i < 0 { vertices + 1 + i } else { i };
                    if absolute < 1 || absolute > total {
                        return Some(format!(
                            "face {faces} (line {}) refers to vertex {i}, but the file has {total} vertices",
                            ln + 1
                        ));
                    }
                }
            }
            _ => {}
        }
    }
    None
}

/// Finds the first vertex line with a NaN or infinite coordinate.
fn locate_nonfinite_obj(text: &str) -> Option<String> {
    let mut vertices = 0usize;
    for (ln, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        vertices += 1;
        if words
            .take(3)
            .any(|w| w.parse::<f32>().is_ok_and(|x| !x.is_finite()))
        {
            return Some(format!(
                "vertex {vertices} (line {}) has a non-finite coordinate: '{}'",
                ln + 1,
                line.trim()
            ));
        }
    }
    None
}

/// Names accepted for the per-vertex scalar, in order of preference.
const WEIGHT_NAMES: [&str; 4] = ["quality", "weight", "value", "confidence"];

/// A PLY vertex as far as we use it.
struct PlyVertex {
    p: [f64; 3],
    rgb: [f32; 3],
    weight: f32,
    weight_rank: usize,
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        PlyVertex {
            p: [0.0; 3],
            rgb: [0.0; 3],
            weight: 0.0,
            weight_rank: usize::MAX,
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let k = match name {
            "x" | "red" => 0,
            "y" | "green" => 1,
            "z" | "blue" => 2,
            _ => usize::MAX,
        };
        let Some(value) = property.to_f32_lossy() else {
            return PropertyAccessResult::Ignored;
        };
        match name {
            "x" | "y" | "z" => {
                self.p[k] = match property {
                    Property::Double(d) => d,
                    _ => value as f64,
                }
            }
            "red" | "green" | "blue" => {
                let scale = match property {
                    Property::Float(_) | Property::Double(_) => 1.0,
                    Property::UShort(_) => 65535.0,
                    _ => 255.0,
                };
                self.rgb[k] = (value / scale).clamp(0.0, 1.0);
            }
            _ => match WEIGHT_NAMES.iter().position(|w| *w == name) {
                Some(rank) if rank < self.weight_rank => {
                    self.weight = value;
                    self.weight_rank = rank;
                }
                Some(_) => {}
                None => return PropertyAccessResult::Ignored,
            },
        }
        PropertyAccessResult::Set
    }
}

/// A PLY face: its vertex list, or a note that it could not be read.
struct PlyFace {
    indices: Vec<u32>,
    bad: bool,
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        PlyFace {
            indices: Vec::new(),
            bad: false,
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if name != "vertex_indices" && name != "vertex_index" {
            return PropertyAccessResult::Ignored;
        }
        match property.to_u32_list() {
            Some(list) => self.indices = list,
            None => self.bad = true,
        }
        PropertyAccessResult::Set
    }
}

/// An element we skip.
struct PlyIgnored;

impl PropertyAccess for PlyIgnored {
    fn new() -> Self {
        PlyIgnored
    }
}

fn has_scalar(def: &ElementDef, name: &str) -> bool {
    matches!(
        def.properties.get(name).map(|p| &p.data_type),
        Some(PropertyType::Scalar(_))
    )
}

fn read_ply(path: &Path) -> Result<Mesh> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    if len == 0 {
        return Err(Error::input(path, "empty file: no usable triangles"));
    }
    match catch_unwind(AssertUnwindSafe(|| read_ply_from(path, file))) {
        Ok(result) => result,
        Err(p) => Err(Error::input(
            path,
            format!("cannot parse PLY: the parser failed ({})", panic_message(&*p)),
        )),
    }
}

fn read_ply_from(path: &Path, file: File) -> Result<Mesh> {
    let mut reader = Reader::new(BufReader::new(file));
    let header = Parser::<PlyIgnored>::new()
        .read_header(&mut reader)
        .map_err(|e| Error::input(path, format!("not a valid PLY file: {e}")))?;
    let Some(vdef) = header.elements.get("vertex") else {
        return Err(Error::input(path, "PLY file has no 'vertex' element"));
    };
    for axis in ["x", "y", "z"] {
        if !has_scalar(vdef, axis) {
            return Err(Error::input(
                path,
                format!("PLY 'vertex' element has no scalar property '{axis}'"),
            ));
        }
    }
    let has_colors = ["red", "green", "blue"].iter().all(|c| has_scalar(vdef, c));
    let has_weights = WEIGHT_NAMES.iter().any(|w| has_scalar(vdef, w));
    if let Some(fdef) = header.elements.get("face") {
        if !fdef.properties.contains_key("vertex_indices") && !fdef.properties.contains_key("vertex_index") {
            return Err(Error::input(
                path,
                "PLY 'face' element has no 'vertex_indices' list",
            ));
        }
    }
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for (name, def) in &header.elements {
        let context = |e: ply_rs_bw::parser::ParseError| {
            Error::input(path, format!("cannot read PLY element '{name}': {e}"))
        };
        match name.as_str() {
            "vertex" => {
                vertices = Parser::<PlyVertex>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?
            }
            "face" => {
                faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?
            }
            _ => {
                Parser::<PlyIgnored>::new()
                    .read_payload_for_element(&mut reader, def, &header)
                    .map_err(context)?;
            }
        }
    }
    check_ply_end(path, &mut reader, &header)?;
    let n = vertices.len();
    let mut mesh = Mesh {
        positions: Vec::with_capacity(n),
        ..Default::default()
    };
    for (i, v) in vertices.iter().enumerate() {
        let p = v.p.map(|c| c as f32);
        if !p.iter().all(|c| c.is_finite()) {
            return Err(Error::input(
                path,
                format!(
                    "vertex {i} (counting from 0) has a non-finite or out-of-range coordinate ({} {} {})",
                    v.p[0], v.p[1], v.p[2]
                ),
            ));
        }
        mesh.positions.push(p);
    }
    if has_colors {
        mesh.vertex_colors = Some(vertices.iter().map(|v| v.rgb).collect());
    }
    if has_weights {
        mesh.vertex_weights = Some(vertices.iter().map(|v| v.weight).collect());
    }
    if !faces.is_empty() && faces.iter().all(|f| !f.bad && f.indices.len() < 3) {
        return Err(Error::input(
            path,
            format!(
                "no usable triangles: {} fewer than 3 vertices, and a face needs at least 3 to be a surface",
                if faces.len() == 1 {
                    "its only face has".to_string()
                } else {
                    format!("all {} faces have", faces.len())
                }
            ),
        ));
    }
    for (f, face) in faces.iter().enumerate() {
        if face.bad {
            return Err(Error::input(
                path,
                format!("face {f} has a negative or non-integer vertex index"),
            ));
        }
        if let Some(&v) = face.indices.iter().find(|&&v| v as usize >= n) {
            return Err(Error::input(
                path,
                format!(
                    "face {f} refers to vertex {v}, but the file has only {n} vertices (counting from 0)"
                ),
            ));
        }
        match face.indices.as_slice() {
            [] => {}
            // Kept as degenerate triangles so repair counts them.
            [a] => mesh.triangles.push([*a, *a, *a]),
            [a, b] => mesh.triangles.push([*a, *b, *b]),
            [a, rest @ ..] => {
                for w in rest.windows(2) {
                    mesh.triangles.push([*a, w[0], w[1]]);
                }
            }
        }
    }
    Ok(mesh)
}

/// Refuses data after the last element the header declares (an ASCII file:
/// anything but white space; a binary one: any byte), which means the header
/// under-counts that element and the rest would be silently dropped.
fn check_ply_end(
    path: &Path,
    reader: &mut Reader<BufReader<File>>,
    header: &ply_rs_bw::ply::Header,
) -> Result<()> {
    use std::io::Read;
    let ascii = matches!(header.encoding, ply_rs_bw::ply::Encoding::Ascii);
    let mut rest = [0u8; 4096];
    loop {
        let got = reader.get_mut().read(&mut rest).map_err(|e| Error::io(path, e))?;
        if got == 0 {
            return Ok(());
        }
        if rest[..got].iter().any(|b| !ascii || !b.is_ascii_whitespace()) {
            let what = match header.elements.iter().last() {
                Some((name, def)) => match name.as_str() {
                    "face" if def.count == 1 => "the header declares 1 face".to_string(),
                    "face" => format!("the header declares {} faces", def.count),
                    "vertex" if def.count == 1 => "the header declares 1 vertex".to_string(),
                    "vertex" => format!("the header declares {} vertices", def.count),
                    _ => format!("the header declares {} '{name}' elements", def.count),
                },
                None => "the header declares no elements".to_string(),
            };
            return Err(Error::input(
                path,
                format!(
                    "{what} but more data follows them: the header under-counts an element \
                     (fix its 'element' line)"
                ),
            ));
        }
    }
}

fn check_indices(path: &Path, mesh: &Mesh) -> Result<()> {
    let n = mesh.positions.len();
    for (f, t) in mesh.triangles.iter().enumerate() {
        if let Some(&v) = t.iter().find(|&&v| v as usize >= n) {
            return Err(Error::input(
                path,
                format!("cannot write: triangle {f} refers to vertex {v}, but the mesh has {n} vertices"),
            ));
        }
    }
    Ok(())
}

/// Writes an OBJ atomically: positions (with `r g b` if the mesh has vertex
/// colours), optional per-corner UVs (three per triangle, written as
/// deduplicated `vt` lines and `f a/ta b/tb c/tc` faces), and an optional
/// `(material file, material name)` pair for `mtllib`/`usemtl`.
pub fn write_obj(
    path: &Path,
    mesh: &Mesh,
    corner_uvs: Option<&[[f32; 2]]>,
    material: Option<(&str, &str)>,
) -> Result<()> {
    check_indices(path, mesh)?;
    if let Some(uvs) = corner_uvs {
        if uvs.len() != 3 * mesh.triangles.len() {
            return Err(Error::input(
                path,
                format!(
                    "cannot write: {} corner UVs given for {} triangles (expected {})",
                    uvs.len(),
                    mesh.triangles.len(),
                    3 * mesh.triangles.len()
                ),
            ));
        }
    }
    let colors = mesh
        .vertex_colors
        .as_ref()
        .filter(|c| c.len() == mesh.positions.len());
    // Deduplicated UVs, numbered in order of first use.
    let (uv_list, uv_index) = match corner_uvs {
        Some(uvs) => {
            let mut map = std::collections::HashMap::new();
            let mut list = Vec::new();
            let index: Vec<usize> = uvs
                .iter()
                .map(|uv| {
                    *map.entry([uv[0].to_bits(), uv[1].to_bits()]).or_insert_with(|| {
                        list.push(*uv);
                        list.len()
                    })
                })
                .collect();
            (list, index)
        }
        None => (Vec::new(), Vec::new()),
    };
    let io = |e| Error::io(path, e);
    write_atomic(path, |out| {
        writeln!(
            out,
            "# btfquilt: {} vertices, {} triangles",
            mesh.positions.len(),
            mesh.triangles.len()
        )
        .map_err(io)?;
        if let Some((file, _)) = material {
            writeln!(out, "mtllib {file}").map_err(io)?;
        }
        for (v, p) in mesh.positions.iter().enumerate() {
            match colors {
                Some(c) => {
                    let c = c[v];
                    writeln!(out, "v {} {} {} {} {} {}", p[0], p[1], p[2], c[0], c[1], c[2]).map_err(io)?
                }
                None => writeln!(out, "v {} {} {}", p[0], p[1], p[2]).map_err(io)?,
            }
        }
        for uv in &uv_list {
            writeln!(out, "vt {} {}", uv[0], uv[1]).map_err(io)?;
        }
        if let Some((_, name)) = material {
            writeln!(out, "usemtl {name}").map_err(io)?;
        }
        for (f, t) in mesh.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|v| v as usize + 1);
            if uv_index.is_empty() {
                writeln!(out, "f {a} {b} {c}").map_err(io)?;
            } else {
                let [ta, tb, tc] = [uv_index[3 * f], uv_index[3 * f + 1], uv_index[3 * f + 2]];
                writeln!(out, "f {a}/{ta} {b}/{tb} {c}/{tc}").map_err(io)?;
            }
        }
        Ok(())
    })
}

/// Writes an ASCII PLY atomically, with vertex colours (uchar `red`, `green`,
/// `blue`) and weights (float `quality`) if the mesh has them.
pub fn write_ply(path: &Path, mesh: &Mesh) -> Result<()> {
    check_indices(path, mesh)?;
    let n = mesh.positions.len();
    let colors = mesh.vertex_colors.as_ref().filter(|c| c.len() == n);
    let weights = mesh.vertex_weights.as_ref().filter(|w| w.len() == n);
    let io = |e| Error::io(path, e);
    write_atomic(path, |out: &mut BufWriter<&mut File>| {
        writeln!(out, "ply\nformat ascii 1.0\ncomment written by btfquilt").map_err(io)?;
        writeln!(out, "element vertex {n}").map_err(io)?;
        writeln!(out, "property float x\nproperty float y\nproperty float z").map_err(io)?;
        if colors.is_some() {
            writeln!(
                out,
                "property uchar red\nproperty uchar green\nproperty uchar blue"
            )
            .map_err(io)?;
        }
        if weights.is_some() {
            writeln!(out, "property float quality").map_err(io)?;
        }
        writeln!(out, "element face {}", mesh.triangles.len()).map_err(io)?;
        writeln!(out, "property list uchar int vertex_indices\nend_header").map_err(io)?;
        for (v, p) in mesh.positions.iter().enumerate() {
            write!(out, "{} {} {}", p[0], p[1], p[2]).map_err(io)?;
            if let Some(c) = colors {
                let [r, g, b] = c[v].map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8);
                write!(out, " {r} {g} {b}").map_err(io)?;
            }
            if let Some(w) = weights {
                write!(out, " {}", w[v]).map_err(io)?;
            }
            writeln!(out).map_err(io)?;
        }
        for t in &mesh.triangles {
            writeln!(out, "3 {} {} {}", t[0], t[1], t[2]).map_err(io)?;
        }
        Ok(())
    })
}
