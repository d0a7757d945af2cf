//! `export`: binary glTF of a geometry image and of a decorated mesh, the
//! surface BTF of a decorated mesh, and what bad inputs leave behind.

use std::path::{Path, PathBuf};

use btfquilt::artifact::gim::Gim;
use btfquilt::artifact::svd::SvdArtifact;
use btfquilt::container::MemoryBudget;
use btfquilt::quilt::{Quilt, NO_PATCH};
use serde_json::Value as Json;

use crate::common::{btfquilt, channel, fails_clearly, listing, ok, read_exr, s};

fn spot() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj")
}

/// A decorated Spot (96² atlas) tiled with a small generated BTF
/// (32², 4φ×3θ views and lights, 8 terms): `(gim, svd, quilt)`.
fn btf_quilt(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let btf = dir.join("b.btf");
    let svd = dir.join("b.svd");
    let gim = dir.join("spot.gim");
    let quilt = dir.join("spot.quilt");
    ok(&[
        "generate-btf",
        "--family",
        "bricks",
        "--size",
        "32",
        "--views",
        "4x3",
        "--lights",
        "4x3",
        "-q",
        "-o",
        s(&btf),
    ]);
    ok(&["factorize", s(&btf), "--terms", "8", "-q", "-o", s(&svd)]);
    ok(&["atlas", s(&spot()), "--resolution", "96", "-q", "-o", s(&gim)]);
    crate::common::tile(&gim, &svd, &quilt);
    (gim, svd, quilt)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

fn int(j: &Json, key: &str) -> usize {
    j.get(key)
        .and_then(Json::as_f64)
        .unwrap_or_else(|| panic!("'{key}' missing or not a number in {j:?}")) as usize
}

/// What a GLB holds, read by hand.
struct Glb {
    json: Json,
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<u32>,
    image: Vec<u8>,
}

/// Parses a GLB checking the container layout and every accessor and
/// bufferView against the glTF 2.0 rules this exporter must follow.
fn parse_glb(bytes: &[u8]) -> Glb {
    // header: magic, version, total length
    assert!(bytes.len() >= 28, "too short: {}", bytes.len());
    assert_eq!(&bytes[0..4], b"glTF");
    assert_eq!(u32_at(bytes, 4), 2);
    assert_eq!(u32_at(bytes, 8) as usize, bytes.len());
    // chunk 0: JSON, padded with spaces to 4 bytes
    let json_len = u32_at(bytes, 12) as usize;
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0);
    let json_bytes = &bytes[20..20 + json_len];
    let text = std::str::from_utf8(json_bytes).unwrap();
    let trimmed = text.trim_end_matches(' ');
    assert!(trimmed.ends_with('}') && json_len - trimmed.len() < 4);
    let json: Json = serde_json::from_str(text).unwrap();
    // chunk 1: BIN, padded with zeros, ends the file
    let bin_at = 20 + json_len;
    let bin_len = u32_at(bytes, bin_at) as usize;
    assert_eq!(&bytes[bin_at + 4..bin_at + 8], b"BIN\0");
    assert_eq!(bin_len % 4, 0);
    assert_eq!(bin_at + 8 + bin_len, bytes.len());
    let bin = &bytes[bin_at + 8..];

    let asset = json.get("asset").unwrap();
    assert_eq!(asset.get("version"), Some(&Json::String("2.0".into())));
    assert!(matches!(asset.get("generator"), Some(Json::String(g)) if g.starts_with("btfquilt")));
    let buffers = json.get("buffers").unwrap().as_array().unwrap();
    assert_eq!(buffers.len(), 1);
    let buffer_len = int(&buffers[0], "byteLength");
    assert!(
        buffer_len <= bin_len && bin_len - buffer_len < 4,
        "{buffer_len} vs {bin_len}"
    );
    assert!(bin[buffer_len..].iter().all(|&b| b == 0));
    let views = json.get("bufferViews").unwrap().as_array().unwrap();
    for v in views {
        assert_eq!(int(v, "buffer"), 0);
        let (o, l) = (int(v, "byteOffset"), int(v, "byteLength"));
        assert_eq!(o % 4, 0, "bufferView not 4-byte aligned: {v:?}");
        assert!(o + l <= buffer_len, "bufferView outside the buffer: {v:?}");
        assert!(v.get("byteStride").is_none());
    }
    let view_bytes = |i: usize| {
        let v = &views[i];
        let o = int(v, "byteOffset");
        &bin[o..o + int(v, "byteLength")]
    };
    let accessors = json.get("accessors").unwrap().as_array().unwrap();
    let read = |i: usize, ty: &str, comp: usize, target: usize| -> &[u8] {
        let a = &accessors[i];
        assert_eq!(a.get("type"), Some(&Json::String(ty.into())), "{a:?}");
        let n = match ty {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            _ => unreachable!(),
        };
        assert_eq!(int(a, "componentType"), comp);
        let count = int(a, "count");
        assert!(count > 0);
        let offset = a.get("byteOffset").and_then(Json::as_f64).unwrap_or(0.0) as usize;
        let view = int(a, "bufferView");
        assert_eq!(int(&views[view], "target"), target, "{:?}", views[view]);
        let data = view_bytes(view);
        let size = count * n * 4;
        assert!(offset + size <= data.len(), "accessor {i} overruns its view");
        &data[offset..offset + size]
    };
    let prims = json.get("meshes").unwrap().as_array().unwrap()[0]
        .get("primitives")
        .unwrap()
        .as_array()
        .unwrap();
    assert_eq!(prims.len(), 1);
    let prim = &prims[0];
    assert_eq!(prim.get("mode").and_then(Json::as_f64).unwrap_or(4.0), 4.0);
    let attrs = prim.get("attributes").unwrap();
    let positions: Vec<[f32; 3]> = f32s(read(int(attrs, "POSITION"), "VEC3", 5126, 34962))
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let normals: Vec<[f32; 3]> = f32s(read(int(attrs, "NORMAL"), "VEC3", 5126, 34962))
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let uvs: Vec<[f32; 2]> = f32s(read(int(attrs, "TEXCOORD_0"), "VEC2", 5126, 34962))
        .chunks_exact(2)
        .map(|c| [c[0], c[1]])
        .collect();
    let indices: Vec<u32> = read(int(prim, "indices"), "SCALAR", 5125, 34963)
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(normals.len(), positions.len());
    assert_eq!(uvs.len(), positions.len());
    assert_eq!(indices.len() % 3, 0);
    assert!(
        indices.iter().all(|&i| (i as usize) < positions.len()),
        "index out of range"
    );

    // POSITION min/max: present and equal to the real bounds
    let pa = &accessors[int(attrs, "POSITION")];
    for (key, pick) in [("min", f32::min as fn(f32, f32) -> f32), ("max", f32::max)] {
        let declared: Vec<f64> = pa
            .get(key)
            .and_then(Json::as_array)
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(declared.len(), 3, "POSITION {key}");
        for k in 0..3 {
            let real = positions.iter().map(|p| p[k]).reduce(pick).unwrap();
            assert_eq!(declared[k] as f32, real, "POSITION {key}[{k}]");
            assert_eq!(declared[k], real as f64, "POSITION {key}[{k}] is not exact");
        }
    }
    // normals are unit
    for n in &normals {
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((l - 1.0).abs() < 1e-5, "normal {n:?} has length {l}");
    }
    // material, texture, sampler, image
    let mat = &json.get("materials").unwrap().as_array().unwrap()[int(prim, "material")];
    let pbr = mat.get("pbrMetallicRoughness").unwrap();
    assert_eq!(pbr.get("metallicFactor").and_then(Json::as_f64), Some(0.0));
    assert_eq!(pbr.get("roughnessFactor").and_then(Json::as_f64), Some(1.0));
    assert_eq!(mat.get("doubleSided"), Some(&Json::Bool(false)));
    let tex = &json.get("textures").unwrap().as_array().unwrap()
        [int(pbr.get("baseColorTexture").unwrap(), "index")];
    let sampler = &json.get("samplers").unwrap().as_array().unwrap()[int(tex, "sampler")];
    assert_eq!(int(sampler, "minFilter"), 9987, "LINEAR_MIPMAP_LINEAR");
    assert_eq!(int(sampler, "magFilter"), 9729, "LINEAR");
    let img = &json.get("images").unwrap().as_array().unwrap()[int(tex, "source")];
    assert_eq!(img.get("mimeType"), Some(&Json::String("image/png".into())));
    assert!(views[int(img, "bufferView")].get("target").is_none());
    let image = view_bytes(int(img, "bufferView")).to_vec();
    Glb {
        json,
        positions,
        normals,
        uvs,
        indices,
        image,
    }
}

/// The GLB as the `gltf` crate reads it (schema validation included):
/// positions, normals, uvs, indices.
type Attributes = (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<u32>);
fn read_with_gltf_crate(bytes: &[u8]) -> Attributes {
    let g = gltf::Gltf::from_slice(bytes).expect("the gltf crate accepts and validates the file");
    let blob = g.blob.clone().expect("a BIN chunk");
    let mesh = g.meshes().next().unwrap();
    let prim = mesh.primitives().next().unwrap();
    assert_eq!(prim.mode(), gltf::mesh::Mode::Triangles);
    let reader = prim.reader(|b| match b.source() {
        gltf::buffer::Source::Bin => Some(&blob[..]),
        _ => None,
    });
    let image = g.images().next().unwrap();
    assert!(matches!(
        image.source(),
        gltf::image::Source::View {
            mime_type: "image/png",
            ..
        }
    ));
    (
        reader.read_positions().unwrap().collect(),
        reader.read_normals().unwrap().collect(),
        reader.read_tex_coords(0).unwrap().into_f32().collect(),
        reader.read_indices().unwrap().into_u32().collect(),
    )
}

/// Corner by corner, the GLB shows the gim's mesh with its corner uvs.
fn assert_same_mesh(glb: &Glb, gim: &Gim) {
    let mesh = gim.mesh().unwrap();
    let corner_uv = gim.corner_uv().unwrap();
    assert_eq!(glb.indices.len(), 3 * mesh.triangles.len());
    for (f, tri) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let i = glb.indices[3 * f + k] as usize;
            assert_eq!(
                glb.positions[i], mesh.positions[tri[k] as usize],
                "face {f} corner {k}"
            );
            assert_eq!(glb.uvs[i], corner_uv[3 * f + k], "face {f} corner {k} uv");
        }
    }
    // vertices were split only where uvs differ: (position, uv) pairs are unique
    let mut pairs: Vec<[u32; 5]> = (0..glb.positions.len())
        .map(|i| {
            let p = glb.positions[i].map(f32::to_bits);
            let t = glb.uvs[i].map(f32::to_bits);
            [p[0], p[1], p[2], t[0], t[1]]
        })
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    assert_eq!(pairs.len(), glb.positions.len(), "duplicate vertices");
    // every vertex is used
    let mut used = vec![false; glb.positions.len()];
    glb.indices.iter().for_each(|&i| used[i as usize] = true);
    assert!(used.iter().all(|&u| u));
    // the normals face the way the triangles wind
    let agree = glb
        .indices
        .chunks_exact(3)
        .filter(|t| {
            let [a, b, c] = [0, 1, 2].map(|k| glb.positions[t[k] as usize]);
            let (e1, e2) = (
                [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
            );
            let n = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let s: f32 = t
                .iter()
                .map(|&i| {
                    let v = glb.normals[i as usize];
                    v[0] * n[0] + v[1] * n[1] + v[2] * n[2]
                })
                .sum();
            s > 0.0
        })
        .count();
    assert!(
        agree * 100 >= glb.indices.len() / 3 * 99,
        "normals disagree with the winding"
    );
}

#[test]
fn gltf_of_a_decorated_mesh_is_a_valid_glb_with_the_baked_atlas() {
    let dir = tempfile::tempdir().unwrap();
    let (gim_path, _, quilt) = btf_quilt(dir.path());
    let out = dir.path().join("gltf");
    let t = std::time::Instant::now();
    let said = ok(&["export", s(&quilt), "--format", "gltf", "-o", s(&out)]);
    eprintln!("export --format gltf: {:.2} s", t.elapsed().as_secs_f64());
    assert!(said.contains("mesh.glb"), "{said}");
    // only the GLB: no scratch texture, no staging folder
    assert_eq!(listing(&out), ["mesh.glb"]);
    let bytes = std::fs::read(out.join("mesh.glb")).unwrap();
    let glb = parse_glb(&bytes);
    let gim = Gim::open(&gim_path, MemoryBudget::default()).unwrap();
    assert_same_mesh(&glb, &gim);
    assert!(
        glb.positions.len() > gim.mesh().unwrap().positions.len(),
        "no vertex split at seams"
    );
    // the same attributes through the gltf crate
    let (p, n, uv, idx) = read_with_gltf_crate(&bytes);
    assert_eq!(
        (p, n, uv, idx),
        (
            glb.positions.clone(),
            glb.normals.clone(),
            glb.uvs.clone(),
            glb.indices.clone()
        )
    );
    // the embedded image is the baked atlas, byte for byte
    let png = dir.path().join("atlas.png");
    btfquilt::output::bake::bake(&quilt, None, &png, MemoryBudget::default()).unwrap();
    assert_eq!(glb.image, std::fs::read(&png).unwrap());
    let decoded = image::load_from_memory(&glb.image).unwrap();
    assert_eq!((decoded.width(), decoded.height()), (96, 96));
    assert_eq!(glb.json.get("scene").and_then(Json::as_f64), Some(0.0));
    // deterministic
    let again = dir.path().join("again");
    ok(&["export", s(&quilt), "--format", "gltf", "-o", s(&again)]);
    assert_eq!(std::fs::read(again.join("mesh.glb")).unwrap(), bytes);
}

#[test]
fn gltf_of_a_geometry_image_embeds_the_chart_map() {
    let dir = tempfile::tempdir().unwrap();
    let gim_path = dir.path().join("spot.gim");
    crate::common::atlas(&spot(), 64, &gim_path);
    let out = dir.path().join("out");
    ok(&["export", s(&gim_path), "--format", "gltf", "-o", s(&out)]);
    assert_eq!(listing(&out), ["mesh.glb"]);
    let bytes = std::fs::read(out.join("mesh.glb")).unwrap();
    let glb = parse_glb(&bytes);
    let gim = Gim::open(&gim_path, MemoryBudget::default()).unwrap();
    assert_same_mesh(&glb, &gim);
    read_with_gltf_crate(&bytes);
    let charts = dir.path().join("charts.png");
    btfquilt::output::show::show(&gim, btfquilt::output::show::ShowWhat::Charts, &charts).unwrap();
    assert_eq!(glb.image, std::fs::read(&charts).unwrap());
    // uvs in the atlas, v down like the gim (no flip, unlike OBJ)
    assert!(glb.uvs.iter().flatten().all(|&c| (0.0..=1.0).contains(&c)));
}

/// Bilinear lookup of `n`-channel `[y][x][i]` maps with pixel centres at
/// integers, clamped (the convention FORMAT.md documents).
fn bilinear(maps: &[f32], w: usize, h: usize, n: usize, x: f32, y: f32) -> Vec<f32> {
    let x = x.clamp(0.0, (w - 1) as f32);
    let y = y.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let at = |x: usize, y: usize, i: usize| maps[(y * w + x) * n + i];
    (0..n)
        .map(|i| {
            let top = at(x0, y0, i) + (at(x1, y0, i) - at(x0, y0, i)) * fx;
            let bottom = at(x0, y1, i) + (at(x1, y1, i) - at(x0, y1, i)) * fx;
            top + (bottom - top) * fy
        })
        .collect()
}

fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let head = lines
        .next()
        .unwrap()
        .split(',')
        .map(String::from)
        .collect::<Vec<_>>();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect::<Vec<_>>())
        .collect::<Vec<_>>();
    for r in &rows {
        assert_eq!(r.len(), head.len(), "ragged row in {}", path.display());
    }
    (head, rows)
}

#[test]
fn surface_btf_reconstructs_what_the_factorization_gives() {
    let dir = tempfile::tempdir().unwrap();
    let (_, svd_path, quilt_path) = btf_quilt(dir.path());
    let out = dir.path().join("out");
    // with the mesh into the same folder in one go
    let t = std::time::Instant::now();
    ok(&[
        "export",
        s(&quilt_path),
        "--btf",
        s(&out),
        "--format",
        "gltf",
        "-o",
        s(&out),
    ]);
    eprintln!("export --btf --format gltf: {:.2} s", t.elapsed().as_secs_f64());
    assert_eq!(
        listing(&out),
        [
            "FORMAT.md",
            "appearance.csv",
            "directions.csv",
            "geometry_maps.exr",
            "mesh.glb",
            "singular_values.csv",
            "synthesis.exr"
        ]
    );
    let budget = MemoryBudget::default();
    let quilt = Quilt::open(&quilt_path, budget).unwrap();
    let svd = SvdArtifact::open(&svd_path, budget).unwrap();
    let (r, w, h, n) = (quilt.resolution, svd.width, svd.height, svd.terms);
    let (nv, nl) = (svd.views.len(), svd.lights.len());
    assert_eq!((w, h, n, nv, nl), (32, 32, 8, 12, 12));

    // synthesis.exr: coordinates and frames, NaN where empty
    let (sw, sh, syn) = read_exr(&out.join("synthesis.exr"));
    assert_eq!((sw, sh), (r, r));
    let (coords, patches, jac) = (
        quilt.coords().unwrap(),
        quilt.patches().unwrap(),
        quilt.jacobians().unwrap(),
    );
    let (u, v, angle) = (channel(&syn, "u"), channel(&syn, "v"), channel(&syn, "angle"));
    let jnames = ["dudX", "dvdX", "dudY", "dvdY"];
    let mut covered = Vec::new();
    for t in 0..r * r {
        if patches[t] == NO_PATCH {
            assert!(
                u[t].is_nan() && v[t].is_nan() && angle[t].is_nan(),
                "empty texel {t} not NaN"
            );
            continue;
        }
        covered.push(t);
        assert_eq!([u[t], v[t]], coords[t], "texel {t}");
        for (k, name) in jnames.iter().enumerate() {
            assert_eq!(channel(&syn, name)[t], jac[t][k], "{name} at {t}");
        }
        let expect = (jac[t][1] as f64).atan2(jac[t][0] as f64).to_degrees();
        let d = (angle[t] as f64 - expect).rem_euclid(360.0);
        assert!(d.min(360.0 - d) < 1e-3, "angle {} vs {expect} at {t}", angle[t]);
        assert!((-180.0..=180.0).contains(&angle[t]));
    }
    assert!(covered.len() > r * r / 4, "only {} texels covered", covered.len());

    // geometry_maps.exr: the maps exactly, channels g00..g07
    let (gw, gh, gch) = read_exr(&out.join("geometry_maps.exr"));
    assert_eq!((gw, gh), (w, h));
    let mut names: Vec<&str> = gch.iter().map(|(n, _)| n.as_str()).collect();
    names.sort();
    assert_eq!(names, ["g00", "g01", "g02", "g03", "g04", "g05", "g06", "g07"]);
    let svd_maps = svd.geometry_maps().unwrap();
    let mut maps = vec![0f32; w * h * n];
    for i in 0..n {
        for (x, &val) in channel(&gch, &format!("g{i:02}")).iter().enumerate() {
            maps[x * n + i] = val;
        }
    }
    assert!(maps == svd_maps, "geometry maps differ from the .svd's");

    // appearance.csv: views × lights rows, exact values
    let (head, rows) = read_csv(&out.join("appearance.csv"));
    assert_eq!(head.len(), 5 + 3 * n);
    assert_eq!(
        head[..6],
        [
            "pair",
            "view_theta",
            "view_phi",
            "light_theta",
            "light_phi",
            "r00"
        ]
    );
    assert_eq!(head[5 + n], "g00");
    assert_eq!(head[5 + 2 * n + n - 1], "b07");
    assert_eq!(rows.len(), nv * nl);
    let svd_p = svd.appearance().unwrap();
    let mut p = Vec::with_capacity(svd_p.len());
    for (pair, row) in rows.iter().enumerate() {
        let f: Vec<f32> = row.iter().map(|x| x.parse().unwrap()).collect();
        assert_eq!(f[0] as usize, pair);
        let (vd, ld) = (svd.views[pair / nl], svd.lights[pair % nl]);
        assert_eq!(f[1..5], [vd.theta, vd.phi, ld.theta, ld.phi]);
        p.extend_from_slice(&f[5..]);
    }
    assert_eq!(p.len(), svd_p.len());
    if let Some(i) = (0..p.len()).find(|&i| p[i].to_bits() != svd_p[i].to_bits()) {
        panic!(
            "appearance does not round-trip exactly: value {i} reads {} for {}",
            p[i], svd_p[i]
        );
    }

    // reconstruct a few texels for a few pairs, both ways
    let step = (covered.len() / 25).max(1);
    for pair in [0, nl + 3, nv * nl / 2, nv * nl - 1] {
        let truth = svd.reconstruct_pair(pair).unwrap();
        let scale = truth.data.iter().fold(0f32, |a, &b| a.max(b.abs())).max(1e-6);
        for &t in covered.iter().step_by(step) {
            let g = bilinear(&maps, w, h, n, u[t], v[t]);
            let g_svd = bilinear(&svd_maps, w, h, n, coords[t][0], coords[t][1]);
            let image = bilinear(&truth.data, w, h, 3, coords[t][0], coords[t][1]);
            for c in 0..3 {
                let coef = &p[(pair * 3 + c) * n..(pair * 3 + c + 1) * n];
                let coef_svd = &svd_p[(pair * 3 + c) * n..(pair * 3 + c + 1) * n];
                let ours: f32 = g.iter().zip(coef).map(|(a, b)| a * b).sum();
                let theirs: f32 = g_svd.iter().zip(coef_svd).map(|(a, b)| a * b).sum();
                assert!(
                    (ours - theirs).abs() <= 1e-6 * scale,
                    "pair {pair} texel {t}: {ours} vs {theirs}"
                );
                // and the library's own reconstruction, interpolated (linearity)
                assert!(
                    (ours - image[c]).abs() <= 1e-4 * scale,
                    "pair {pair} texel {t} c {c}: {ours} vs {}",
                    image[c]
                );
            }
        }
    }

    // directions.csv: the two lists with unit vectors; singular values
    let (head, rows) = read_csv(&out.join("directions.csv"));
    assert_eq!(head, ["set", "index", "theta", "phi", "x", "y", "z"]);
    assert_eq!(rows.len(), nv + nl);
    for (k, row) in rows.iter().enumerate() {
        let (set, list, i) = if k < nv {
            ("view", &svd.views, k)
        } else {
            ("light", &svd.lights, k - nv)
        };
        assert_eq!((row[0].as_str(), row[1].parse::<usize>().unwrap()), (set, i));
        let f: Vec<f32> = row[2..].iter().map(|x| x.parse().unwrap()).collect();
        assert_eq!([f[0], f[1]], [list[i].theta, list[i].phi]);
        assert!((f[2] * f[2] + f[3] * f[3] + f[4] * f[4] - 1.0).abs() < 1e-5);
        assert!((f[4] - list[i].theta.to_radians().cos()).abs() < 1e-6);
    }
    let (_, rows) = read_csv(&out.join("singular_values.csv"));
    let sigma: Vec<f32> = rows.iter().map(|r| r[1].parse().unwrap()).collect();
    assert_eq!(sigma, svd.singular_values().unwrap());
    let md = std::fs::read_to_string(out.join("FORMAT.md")).unwrap();
    for needle in [
        "NaN",
        "32×32",
        "n = 8",
        "12 views × 12 lights",
        "bilinear",
        "atan2(dvdX, dudX)",
    ] {
        assert!(md.contains(needle), "'{needle}' missing from FORMAT.md");
    }
}

#[test]
fn bad_inputs_fail_clearly_and_leave_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // not an artifact
    let junk = d.join("junk.gim");
    std::fs::write(&junk, "not a container").unwrap();
    let out = d.join("out");
    fails_clearly(
        &btfquilt(&["export", s(&junk), "--format", "gltf", "-o", s(&out)]),
        &["junk.gim", "not a btfquilt container"],
    );
    assert!(!out.exists());
    let missing = d.join("missing.quilt");
    fails_clearly(
        &btfquilt(&["export", s(&missing), "--format", "gltf", "-o", s(&out)]),
        &["missing.quilt"],
    );
    assert!(!out.exists());

    let gim = d.join("spot.gim");
    ok(&["atlas", s(&spot()), "--resolution", "48", "-q", "-o", s(&gim)]);
    fails_clearly(
        &btfquilt(&["export", s(&gim), "--format", "fbx", "-o", s(&out)]),
        &["'fbx'", "--format", "obj, gltf"],
    );
    fails_clearly(&btfquilt(&["export", s(&gim), "--format", "gltf"]), &["-o"]);
    fails_clearly(&btfquilt(&["export", s(&gim)]), &["nothing to export"]);
    // a geometry image has no surface BTF
    fails_clearly(
        &btfquilt(&[
            "export",
            s(&gim),
            "--btf",
            s(&out),
            "--format",
            "gltf",
            "-o",
            s(&out),
        ]),
        &["spot.gim", "--btf"],
    );
    assert!(!out.exists());
    // another kind of artifact
    let btf = d.join("small.btf");
    ok(&[
        "generate-btf",
        "--size",
        "16",
        "--views",
        "4x2",
        "--lights",
        "4x2",
        "-q",
        "-o",
        s(&btf),
    ]);
    fails_clearly(
        &btfquilt(&["export", s(&btf), "--format", "gltf", "-o", s(&out)]),
        &["small.btf", "'btf'"],
    );
    assert!(!out.exists());

    // a decorated mesh whose sample is gone: a folder that existed keeps
    // exactly what it had, one that did not is not left behind
    let (_, svd, quilt) = btf_quilt(d);
    let moved = d.join("moved.svd");
    std::fs::rename(&svd, &moved).unwrap();
    let kept = d.join("kept");
    std::fs::create_dir(&kept).unwrap();
    std::fs::write(kept.join("synthesis.exr"), "old").unwrap();
    for args in [
        vec!["export", s(&quilt), "--btf", s(&kept)],
        vec![
            "export",
            s(&quilt),
            "--btf",
            s(&kept),
            "--format",
            "gltf",
            "-o",
            s(&out),
        ],
        vec!["export", s(&quilt), "--format", "obj", "-o", s(&out)],
    ] {
        fails_clearly(&btfquilt(&args), &["spot.quilt", "b.svd"]);
        assert_eq!(listing(&kept), ["synthesis.exr"], "{args:?}");
        assert_eq!(std::fs::read(kept.join("synthesis.exr")).unwrap(), b"old");
        assert!(!out.exists(), "{args:?} left {:?}", listing(&out));
    }
    // --sample points at it again: then it works and replaces the old file
    ok(&["export", s(&quilt), "--btf", s(&kept), "--sample", s(&moved)]);
    assert_eq!(listing(&kept).len(), 6);
    assert_ne!(std::fs::read(kept.join("synthesis.exr")).unwrap(), b"old");
}

fn square_mesh() -> btfquilt::mesh::Mesh {
    btfquilt::mesh::Mesh {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    }
}

#[test]
fn vertices_split_only_at_uv_seams_and_names_are_padded() {
    use btfquilt::output::export::{split_by_uv, term_names, MeshFormat};
    assert_eq!(term_names("g", 3), ["g00", "g01", "g02"]);
    assert_eq!(term_names("r", 101)[100], "r100");
    assert_eq!(term_names("r", 101)[7], "r007");
    assert_eq!("gltf".parse::<MeshFormat>().unwrap(), MeshFormat::Gltf);
    assert!("fbx"
        .parse::<MeshFormat>()
        .unwrap_err()
        .to_string()
        .contains("'fbx'"));
    let mesh = square_mesh();
    // vertices 0 and 2 shared with the same uv
    let uv = [
        [0.0, 1.0],
        [1.0, 1.0],
        [1.0, 0.0],
        [0.0, 1.0],
        [1.0, 0.0],
        [0.0, 0.0],
    ];
    let s = split_by_uv(&mesh, &uv).unwrap();
    assert_eq!(s.positions.len(), 4);
    assert_eq!(s.triangles, [[0, 1, 2], [0, 2, 3]]);
    // vertex 2 on a seam: two copies, numbered in order of first use
    let mut seam = uv;
    seam[4] = [0.5, 0.0];
    let s = split_by_uv(&mesh, &seam).unwrap();
    assert_eq!(s.positions.len(), 5);
    assert_eq!(s.source, [0, 1, 2, 2, 3]);
    assert_eq!(s.triangles, [[0, 1, 2], [0, 3, 4]]);
    assert!(s.normals.iter().all(|n| *n == [0.0, 0.0, 1.0]));
    // -0.0 and 0.0 are the same uv
    let mut signed = uv;
    signed[3] = [-0.0, 1.0];
    assert_eq!(split_by_uv(&mesh, &signed).unwrap().positions.len(), 4);
    assert!(split_by_uv(&mesh, &uv[..5]).is_err());
}

#[test]
fn glb_of_a_tiny_mesh_is_laid_out_and_validates() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("t.png");
    let img = btfquilt::io::imageio::RgbImage {
        width: 3,
        height: 2,
        data: (0..18).map(|i| i as f32 / 18.0).collect(),
    };
    btfquilt::io::imageio::write_png(&png, &img, btfquilt::io::imageio::PngDepth::Eight).unwrap();
    let png = std::fs::read(&png).unwrap();
    let mesh = square_mesh();
    let uv = [
        [0.0, 1.0],
        [1.0, 1.0],
        [1.0, 0.0],
        [0.0, 1.0],
        [1.0, 0.0],
        [0.0, 0.0],
    ];
    let split = btfquilt::output::export::split_by_uv(&mesh, &uv).unwrap();
    let bytes = btfquilt::output::export::glb_bytes(&split, &png).unwrap();
    let glb = parse_glb(&bytes);
    assert_eq!(glb.image, png);
    assert_eq!(glb.indices, [0, 1, 2, 0, 2, 3]);
    assert_eq!(glb.uvs, [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]]);
    let (p, _, uvs, idx) = read_with_gltf_crate(&bytes);
    assert_eq!((p, uvs, idx), (glb.positions, glb.uvs, glb.indices));
    assert!(btfquilt::output::export::glb_bytes(&split, b"GIF89a").is_err());
}
