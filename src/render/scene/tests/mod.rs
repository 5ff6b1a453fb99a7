//! Tests of scene loading, by source; the scene files they write share the helpers here.

mod animated_files;
mod built_in;
mod compressed_files;
mod gltf_files;
mod hostile_files;
mod obj_files;

use super::*;

/// A 2 × 1 PNG: a red and a blue texel.
fn two_texel_png() -> Vec<u8> {
    let mut png = Vec::new();
    image::RgbaImage::from_raw(2, 1, two_texel_png_rgba())
        .unwrap()
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    png
}

/// A one-triangle glTF with TEXCOORD_0 and a base-colour and a metallic-roughness texture
/// of the image at `image_uri`, its sampler clamping u and mirroring v.
fn textured_gltf(dir: &Path, name: &str, image_uri: &str) -> PathBuf {
    let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let uvs: [f32; 6] = [0.0, 0.0, 1.0, 0.0, 0.0, 2.0];
    let bytes: Vec<u8> = positions
        .iter()
        .chain(&uvs)
        .flat_map(|f| f.to_le_bytes())
        .collect();
    let b64 = base64_encode(&bytes);
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"TEXCOORD_0":1}},"material":0}}]}}],
        "materials":[{{"pbrMetallicRoughness":{{"baseColorTexture":{{"index":0}},"metallicRoughnessTexture":{{"index":0}}}},
                      "normalTexture":{{"index":0}}}}],
        "textures":[{{"source":0,"sampler":0}}],
        "samplers":[{{"wrapS":33071,"wrapT":33648}}],
        "images":[{{"uri":"{image_uri}"}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":24}}],
        "buffers":[{{"byteLength":60,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
    );
    let path = dir.join(name);
    std::fs::write(&path, json).unwrap();
    path
}

/// The text of a [`textured_gltf`] whose image is the [`two_texel_png`] `tex.png`, both
/// written to `dir`, for tests that edit the file.
fn textured_gltf_text(dir: &Path) -> String {
    std::fs::write(dir.join("tex.png"), two_texel_png()).unwrap();
    std::fs::read_to_string(textured_gltf(dir, "t.gltf", "tex.png")).unwrap()
}

/// [`two_texel_png`]'s pixels: red, then blue.
fn two_texel_png_rgba() -> Vec<u8> {
    vec![255, 0, 0, 255, 0, 0, 255, 255]
}

/// A one-triangle glTF (optionally with NORMALs and indices in the buffer), with the
/// given nodes, accessor counts and material; written to `dir/name`.
fn write_gltf(dir: &Path, name: &str, nodes: &str, counts: [u32; 3], color: &str) -> PathBuf {
    let positions: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let normals: [f32; 9] = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
    let mut bytes: Vec<u8> = positions
        .iter()
        .chain(&normals)
        .flat_map(|f| f.to_le_bytes())
        .collect();
    bytes.extend([0u16, 1, 2].iter().flat_map(|i| i.to_le_bytes()));
    let b64 = base64_encode(&bytes);
    let [p, n, i] = counts;
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":{nodes},
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0,"NORMAL":1}},"indices":2,"material":0}}]}}],
        "materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":{color}}}}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{p},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5126,"count":{n},"type":"VEC3"}},
                     {{"bufferView":2,"componentType":5123,"count":{i},"type":"SCALAR"}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":36}},
                       {{"buffer":0,"byteOffset":72,"byteLength":6}}],
        "buffers":[{{"byteLength":78,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
    );
    let path = dir.join(name);
    std::fs::write(&path, json).unwrap();
    path
}

fn base64_decode(text: &str) -> Vec<u8> {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let digits: Vec<u32> = (text.bytes())
        .filter(|&c| c != b'=')
        .map(|c| A.iter().position(|&a| a == c).unwrap() as u32)
        .collect();
    let mut out = Vec::new();
    for chunk in digits.chunks(4) {
        let n = chunk
            .iter()
            .enumerate()
            .fold(0, |n, (k, d)| n | d << (18 - 6 * k));
        out.extend(&n.to_be_bytes()[1..chunk.len()]);
    }
    out
}

/// Loading `path` fails with an error naming the file and containing `needle`.
fn assert_load_fails_naming(path: &Path, needle: &str) {
    let name = path.file_name().unwrap().to_string_lossy().into_owned();
    let e = Scene::load(path, false).err().map(|e| e.to_string());
    let e = e.unwrap_or_else(|| panic!("{name} loaded"));
    assert!(e.contains(&name) && e.contains(needle), "{e}");
}

/// The one-triangle glTF of [`write_gltf`] with `from` replaced by `to` in its text.
fn edited_gltf(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
    let path = write_gltf(dir, name, r#"[{"mesh":0}]"#, [3, 3, 3], "[0.5,0.5,0.5,1]");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains(from), "{from}");
    std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
    path
}

/// The POSITION accessor of [`write_gltf`]'s file.
const POSITIONS: &str =
    r#"{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}"#;

/// A sparse POSITION accessor of `count` elements without a buffer view, its three sparse
/// indices (0, 1, 2) and values taken from [`write_gltf`]'s buffer.
fn sparse_positions(count: usize) -> String {
    format!(
        r#"{{"componentType":5126,"count":{count},"type":"VEC3","min":[0,0,0],"max":[1,1,0],
        "sparse":{{"count":3,"indices":{{"bufferView":2,"componentType":5123}},"values":{{"bufferView":0}}}}}}"#
    )
}

fn base64_encode(data: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in data.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for i in 0..4 {
            if i <= c.len() {
                out.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// Whether `path` loads; a panic of the scene readers, which `Scene::load` turns into an
/// error, fails the test (without this check the mutation tests could not fail).
fn loads_without_panic(path: &Path) -> bool {
    match Scene::load(path, false) {
        Ok(_) => true,
        Err(e) => {
            let e = e.to_string();
            assert!(!e.contains("the reader panicked"), "{e}");
            false
        }
    }
}

/// The spans of the numbers in a JSON text (not those inside names such as `TEXCOORD_0`
/// or in base64 data).
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let bytes = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = bytes[i].is_ascii_digit()
            && !bytes[i - 1].is_ascii_alphanumeric()
            && bytes[i - 1] != b'+'
            && bytes[i - 1] != b'/';
        if starts {
            let end = (i..bytes.len())
                .find(|&j| !(bytes[j].is_ascii_digit() || b".eE-".contains(&bytes[j])))
                .unwrap_or(bytes.len());
            spans.push((i, end));
            i = end;
        } else {
            i += 1;
        }
    }
    spans
}

/// Values that overflow, wrap or misplace what a glTF number counts or indexes.
const HOSTILE_NUMBERS: [&str; 12] = [
    "0",
    "-1",
    "1",
    "255",
    "65535",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "9007199254740993",
    "1e308",
    "-1e308",
    "0.5",
];
