use super::*;

/// A 1×1 PNG (just the signature matters to `glb_bytes`).
const PNG: &[u8] = b"\x89PNG\r\n\x1a\nnot really an image";

fn json_chunk(glb: &[u8]) -> &str {
    let len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    std::str::from_utf8(&glb[20..20 + len]).unwrap()
}

/// The glTF JSON's exact text: key order, no whitespace, numbers as Rust
/// prints them (`1`, `-0`, no exponents), as files have always been
/// written.
#[test]
fn glb_json_text_is_pinned() {
    let mesh = SplitMesh {
        positions: vec![[-0.0, 0.1, -1e-7], [1.5, 2e20, -3.25], [0.0, 1e-30, 7.0]],
        normals: vec![[0.0, 0.0, 1.0]; 3],
        uvs: vec![[0.0, 0.0], [1.0, 0.5], [0.25, 1.0]],
        triangles: vec![[0, 1, 2]],
        source: vec![0, 1, 2],
    };
    let glb = glb_bytes(&mesh, PNG).unwrap();
    let expected = concat!(
        r#"{"asset":{"version":"2.0","generator":"btfquilt "#,
        env!("CARGO_PKG_VERSION"),
        r#""},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0,"name":"mesh"}],"#,
        r#""meshes":[{"name":"mesh","primitives":[{"attributes":{"POSITION":0,"NORMAL":1,"TEXCOORD_0":2},"#,
        r#""indices":3,"material":0,"mode":4}]}],"#,
        r#""materials":[{"name":"atlas","pbrMetallicRoughness":{"baseColorTexture":{"index":0,"texCoord":0},"#,
        r#""baseColorFactor":[1,1,1,1],"metallicFactor":0,"roughnessFactor":1},"doubleSided":false}],"#,
        r#""textures":[{"sampler":0,"source":0}],"images":[{"name":"atlas","bufferView":4,"mimeType":"image/png"}],"#,
        r#""samplers":[{"magFilter":9729,"minFilter":9987,"wrapS":33071,"wrapT":33071}],"#,
        r#""accessors":[{"bufferView":0,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC3","#,
        r#""min":[-0,0.0000000000000000000000000000010000000031710769,-3.25],"max":[1.5,200000004008175470000,7]},"#,
        r#"{"bufferView":1,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC3"},"#,
        r#"{"bufferView":2,"byteOffset":0,"componentType":5126,"count":3,"type":"VEC2"},"#,
        r#"{"bufferView":3,"byteOffset":0,"componentType":5125,"count":3,"type":"SCALAR"}],"#,
        r#""bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36,"target":34962},"#,
        r#"{"buffer":0,"byteOffset":36,"byteLength":36,"target":34962},"#,
        r#"{"buffer":0,"byteOffset":72,"byteLength":24,"target":34962},"#,
        r#"{"buffer":0,"byteOffset":96,"byteLength":12,"target":34963},"#,
        r#"{"buffer":0,"byteOffset":108,"byteLength":27}],"buffers":[{"byteLength":135}]}"#
    );
    let json = json_chunk(&glb);
    assert_eq!(json.trim_end_matches(' '), expected);
    // and it is JSON with the four accessors and five buffer views
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    assert_eq!(v["accessors"].as_array().map(Vec::len), Some(4));
    assert_eq!(v["bufferViews"].as_array().map(Vec::len), Some(5));
    assert_eq!(v["accessors"][0]["max"][1].as_f64(), Some(2e20f32 as f64));
}
