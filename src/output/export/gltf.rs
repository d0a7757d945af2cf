//! Binary glTF 2.0: the JSON document (serde) and the .glb container with
//! the texture embedded.

use super::*;

const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

/// serde_json's compact layout with numbers as Rust prints them (`1`, not
/// `1.0`; `-0`; never an exponent), as the glTF JSON has always been
/// written.
struct GltfFormatter;

impl serde_json::ser::Formatter for GltfFormatter {
    fn write_f64<W: ?Sized + Write>(&mut self, w: &mut W, v: f64) -> std::io::Result<()> {
        write!(w, "{v}")
    }
}

// The glTF document of `glb_bytes`: the fields in key order.

#[derive(Serialize)]
struct Gltf {
    asset: Asset,
    scene: u32,
    scenes: [Scene; 1],
    nodes: [Node; 1],
    meshes: [GltfMesh; 1],
    materials: [Material; 1],
    textures: [Texture; 1],
    images: [Image; 1],
    samplers: [Sampler; 1],
    accessors: [Accessor; 4],
    #[serde(rename = "bufferViews")]
    buffer_views: Vec<BufferView>,
    buffers: [Buffer; 1],
}

#[derive(Serialize)]
struct Asset {
    pub(super) version: &'static str,
    generator: &'static str,
}

#[derive(Serialize)]
struct Scene {
    nodes: [u32; 1],
}

#[derive(Serialize)]
struct Node {
    pub(super) mesh: u32,
    pub(super) name: &'static str,
}

#[derive(Serialize)]
struct GltfMesh {
    pub(super) name: &'static str,
    primitives: [Primitive; 1],
}

#[derive(Serialize)]
struct Primitive {
    attributes: Attributes,
    indices: u32,
    material: u32,
    mode: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
struct Attributes {
    pub(super) position: u32,
    pub(super) normal: u32,
    texcoord_0: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Material {
    pub(super) name: &'static str,
    pbr_metallic_roughness: Pbr,
    double_sided: bool,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Pbr {
    base_color_texture: TextureRef,
    base_color_factor: [f64; 4],
    metallic_factor: f64,
    roughness_factor: f64,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct TextureRef {
    pub(super) index: u32,
    tex_coord: u32,
}

#[derive(Serialize)]
struct Texture {
    sampler: u32,
    pub(super) source: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Image {
    pub(super) name: &'static str,
    buffer_view: usize,
    mime_type: &'static str,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Sampler {
    mag_filter: u32,
    min_filter: u32,
    wrap_s: u32,
    wrap_t: u32,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Accessor {
    buffer_view: usize,
    byte_offset: usize,
    component_type: u32,
    pub(super) count: usize,
    #[serde(rename = "type")]
    kind: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) min: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) max: Option<[f64; 3]>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct BufferView {
    buffer: u32,
    byte_offset: usize,
    byte_length: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(super) target: Option<u32>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct Buffer {
    byte_length: usize,
}

/// A binary glTF 2.0 file: one node with one mesh (POSITION with min/max,
/// NORMAL, TEXCOORD_0, u32 indices, triangles), one material
/// (pbrMetallicRoughness with `png` as the sRGB base colour texture, metallic
/// 0, roughness 1, single sided), a sampler with trilinear filtering and
/// clamping, the PNG embedded through a bufferView. The JSON is serialized
/// from typed structs in a fixed key order, so the bytes depend only on the
/// inputs.
pub fn glb_bytes(mesh: &SplitMesh, png: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let n = mesh.positions.len();
    if n == 0 || mesh.triangles.is_empty() {
        return Err("an empty mesh".into());
    }
    if mesh.normals.len() != n || mesh.uvs.len() != n {
        return Err("positions, normals and uvs differ in count".into());
    }
    if mesh.triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err("an index is out of range".into());
    }
    if !png.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Err("the texture is not a PNG".into());
    }
    // the binary buffer: every view starts 4-byte aligned
    let mut bin: Vec<u8> = Vec::new();
    let mut views: Vec<(usize, usize, Option<u32>)> = Vec::new();
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>| {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push((bin.len(), bytes.len(), target));
        bin.extend_from_slice(bytes);
        views.len() - 1
    };
    let flat = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
    let pos = view(&mut bin, &flat(mesh.positions.as_flattened()), Some(ARRAY_BUFFER));
    let nor = view(&mut bin, &flat(mesh.normals.as_flattened()), Some(ARRAY_BUFFER));
    let tex = view(&mut bin, &flat(mesh.uvs.as_flattened()), Some(ARRAY_BUFFER));
    let idx_bytes: Vec<u8> = mesh
        .triangles
        .as_flattened()
        .iter()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let idx = view(&mut bin, &idx_bytes, Some(ELEMENT_ARRAY_BUFFER));
    let img = view(&mut bin, png, None);
    let buffer_len = bin.len();

    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    // f32 → its exact f64 decimal, so a reader comparing as f32 or f64 agrees
    let wide = |v: [f32; 3]| v.map(|x| x as f64);
    let accessor = |view: usize, component_type: u32, count: usize, kind: &'static str| Accessor {
        buffer_view: view,
        byte_offset: 0,
        component_type,
        count,
        kind,
        min: None,
        max: None,
    };
    let doc = Gltf {
        asset: Asset {
            version: "2.0",
            generator: concat!("btfquilt ", env!("CARGO_PKG_VERSION")),
        },
        scene: 0,
        scenes: [Scene { nodes: [0] }],
        nodes: [Node {
            mesh: 0,
            name: "mesh",
        }],
        meshes: [GltfMesh {
            name: "mesh",
            primitives: [Primitive {
                attributes: Attributes {
                    position: 0,
                    normal: 1,
                    texcoord_0: 2,
                },
                indices: 3,
                material: 0,
                mode: 4, // triangles
            }],
        }],
        materials: [Material {
            name: "atlas",
            pbr_metallic_roughness: Pbr {
                base_color_texture: TextureRef {
                    index: 0,
                    tex_coord: 0,
                },
                base_color_factor: [1.0; 4],
                metallic_factor: 0.0,
                roughness_factor: 1.0,
            },
            double_sided: false,
        }],
        textures: [Texture {
            sampler: 0,
            source: 0,
        }],
        images: [Image {
            name: "atlas",
            buffer_view: img,
            mime_type: "image/png",
        }],
        // LINEAR magnification, LINEAR_MIPMAP_LINEAR minification, CLAMP_TO_EDGE
        samplers: [Sampler {
            mag_filter: 9729,
            min_filter: 9987,
            wrap_s: 33071,
            wrap_t: 33071,
        }],
        accessors: [
            Accessor {
                min: Some(wide(min)),
                max: Some(wide(max)),
                ..accessor(pos, FLOAT, n, "VEC3")
            },
            accessor(nor, FLOAT, n, "VEC3"),
            accessor(tex, FLOAT, n, "VEC2"),
            accessor(idx, UNSIGNED_INT, 3 * mesh.triangles.len(), "SCALAR"),
        ],
        buffer_views: views
            .iter()
            .map(|&(byte_offset, byte_length, target)| BufferView {
                buffer: 0,
                byte_offset,
                byte_length,
                target,
            })
            .collect(),
        buffers: [Buffer {
            byte_length: buffer_len,
        }],
    };
    let mut json = Vec::new();
    doc.serialize(&mut serde_json::Serializer::with_formatter(
        &mut json,
        GltfFormatter,
    ))
    .map_err(|e| format!("writing the glTF JSON: {e}"))?;

    // the GLB container: header, JSON chunk (space padded), BIN chunk (zero padded)
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let total32 = u32::try_from(total).map_err(|_| format!("{total} bytes: too large for a GLB file"))?;
    let mut out = Vec::with_capacity(total);
    for v in [GLB_MAGIC, 2, total32, json.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&json);
    for v in [bin.len() as u32, CHUNK_BIN] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&bin);
    debug_assert_eq!(out.len(), total);
    Ok(out)
}
