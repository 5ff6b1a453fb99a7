//! Wavefront OBJ loading with its MTL materials (through `tobj`), after a scan of the file
//! that names what it holds and envlight does not draw.

use super::*;

/// The largest OBJ material library that is read.
pub const MAX_MTL_BYTES: u64 = 64 << 20;

/// Reads an MTL file, checking what `tobj` would panic on: a colour (`Ka`, `Kd`, `Ks`, `Ke`)
/// with fewer than three numbers. The error carries tobj's kind and the problem in words.
pub(super) fn read_mtl(path: &Path) -> Result<Vec<u8>, (tobj::LoadError, String)> {
    let bytes = crate::read_file::read_regular_file(path, MAX_MTL_BYTES, "a material library")
        .map_err(|e| (tobj::LoadError::OpenFileFailed, e.to_string()))?;
    for (number, line) in String::from_utf8_lossy(&bytes).lines().enumerate() {
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            if words.take(3).count() < 3 {
                return Err((
                    tobj::LoadError::MaterialParseError,
                    format!("line {}: {key} needs three numbers (r g b)", number + 1),
                ));
            }
        }
    }
    Ok(bytes)
}

/// What [`scan_obj`] found that is not drawn, for the warnings.
#[derive(Debug, Default, PartialEq)]
pub(super) struct ObjScan {
    /// `l` and `p` elements (tobj would turn them into zero-area triangles).
    pub(super) lines_and_points: usize,
    /// Faces of fewer than three corners (tobj drops them).
    pub(super) short_faces: usize,
}

/// Checks an OBJ file's text before `tobj` parses it, with the line number of each problem
/// (tobj's own errors name neither line nor problem: "position parse error", "read error"):
/// every line UTF-8; `v x y z [w | r g b]` with numbers (w not 0, vertex colours on every
/// vertex or on none), `vt u v`, `vn x y z`; face corners `v`, `v/vt`, `v//vn` or `v/vt/vn`
/// with integer indices (in `l` lines too, which tobj parses as it does faces), each no larger
/// in magnitude than the number of positions, texture coordinates or normals in the file (a
/// negative one: than those defined above its line, which it counts back from), and not 0
/// (`tobj` multiplies the texture-coordinate and normal indices unchecked: an index near 2⁶³
/// overflows, a panic with overflow checks on, and wraps past its bounds check without); no
/// byte-order mark. Counts what will not be drawn ([`ObjScan`]).
pub(super) fn scan_obj(text: &[u8]) -> Result<ObjScan, String> {
    // Finite in f32: "1e39" and "nan" parse, as infinity and NaN.
    let number = |word: &str| word.parse::<f32>().is_ok_and(f32::is_finite);
    let mut scan = ObjScan::default();
    let mut counts = [0usize; 3];
    // The first vertex line with a colour and the first without.
    let (mut coloured, mut plain) = (None, None);
    let lines = || text.split(|&c| c == b'\n').zip(1usize..);
    if text.starts_with("\u{feff}".as_bytes()) {
        return Err(
            "the file begins with a UTF-8 byte-order mark, which OBJ readers do not \
                    expect (its first line would be lost); remove it"
                .into(),
        );
    }
    for (line, n) in lines() {
        let line = std::str::from_utf8(line)
            .map_err(|_| format!("line {n} is not UTF-8 text (an OBJ file is text)"))?;
        let mut words = line.split_whitespace();
        let (kind, rest): (usize, Vec<&str>) = match words.next() {
            Some("v") => (0, words.collect()),
            Some("vt") => (1, words.collect()),
            Some("vn") => (2, words.collect()),
            Some("l" | "p") => {
                scan.lines_and_points += 1;
                continue;
            }
            _ => continue,
        };
        let needed = [3, 2, 3][kind];
        if rest.len() < needed || !rest[..needed].iter().all(|w| number(w)) {
            let form = ["v x y z", "vt u v", "vn x y z"][kind];
            return Err(format!(
                "line {n}: expected {needed} finite numbers ({form}), got {:?}",
                line.trim()
            ));
        }
        if kind == 0 {
            match rest[3..] {
                [] => plain = plain.or(Some(n)),
                [w] if number(w) && w.parse::<f32>().is_ok_and(|w| w != 0.0) => {
                    plain = plain.or(Some(n))
                }
                [w] => {
                    return Err(format!(
                        "line {n}: the homogeneous w {w:?} must be a number other than 0"
                    ))
                }
                [r, g, b] if [r, g, b].iter().all(|w| number(w)) => coloured = coloured.or(Some(n)),
                _ => {
                    return Err(format!(
                        "line {n}: a vertex is v x y z, v x y z w or v x y z r g b, got {:?}",
                        line.trim()
                    ))
                }
            }
            if let (Some(c), Some(p)) = (coloured, plain) {
                return Err(format!(
                    "line {c} gives a vertex colour and line {p} does not: vertex colours must \
                     be on every vertex or on none"
                ));
            }
        }
        counts[kind] += 1;
    }
    const KINDS: [&str; 3] = ["positions", "texture coordinates", "normals"];
    // Defined so far: a negative index counts back from the elements above its line.
    let mut defined = [0usize; 3];
    for (line, n) in lines() {
        // UTF-8: checked above.
        let line = std::str::from_utf8(line).unwrap_or_default();
        let mut words = line.split_whitespace();
        let keyword = words.next();
        match keyword {
            Some("v") => defined[0] += 1,
            Some("vt") => defined[1] += 1,
            Some("vn") => defined[2] += 1,
            _ => {}
        }
        // tobj parses `l` lines as it does faces (and then leaves them out).
        if !matches!(keyword, Some("f" | "l")) {
            continue;
        }
        let corners: Vec<&str> = words.collect();
        if corners.is_empty() {
            return Err(format!(
                "line {n}: {} without vertices",
                if keyword == Some("f") {
                    "a face"
                } else {
                    "a line"
                }
            ));
        }
        if keyword == Some("f") && corners.len() < 3 {
            scan.short_faces += 1;
        }
        for corner in corners {
            let parts: Vec<&str> = corner.split('/').collect();
            if parts.len() > 3 || parts[0].is_empty() {
                return Err(format!(
                    "line {n}: face corner {corner:?} is not v, v/vt, v//vn or v/vt/vn"
                ));
            }
            for (kind, index) in parts.iter().enumerate().filter(|(_, i)| !i.is_empty()) {
                let Ok(index) = index.parse::<i128>() else {
                    return Err(format!(
                        "line {n}: face corner {corner:?}: {index:?} is not an integer index"
                    ));
                };
                if index == 0 {
                    return Err(format!("line {n}: face index 0 (OBJ indices start at 1)"));
                }
                if index.unsigned_abs() > counts[kind] as u128 {
                    return Err(format!(
                        "line {n}: face index {index} out of range of the file's {} {}",
                        counts[kind], KINDS[kind]
                    ));
                }
                if index < 0 && index.unsigned_abs() > defined[kind] as u128 {
                    return Err(format!(
                        "line {n}: face index {index} counts back past the {} {} defined \
                         above it",
                        defined[kind], KINDS[kind]
                    ));
                }
            }
        }
    }
    Ok(scan)
}

/// The OBJ text with comments that follow the data on a geometry line (`f 1 2 3 # back`,
/// `v 0 0 0 # origin`) cut off. Exporters write them and most readers accept them; tobj reads
/// the `#` as one more number or corner and fails. Only geometry lines are cut (`v`, `vt`,
/// `vn`, `vp`, `f`, `l`, `p`, `s`): a name after `o`, `g`, `usemtl` or `mtllib` may hold a `#`.
/// Every line keeps its place, so line numbers in errors stay those of the file.
pub(super) fn strip_trailing_comments(text: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    const GEOMETRY: [&[u8]; 8] = [b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p", b"s"];
    let cut = |line: &[u8]| -> Option<usize> {
        let keyword = line
            .trim_ascii_start()
            .split(u8::is_ascii_whitespace)
            .next()?;
        if !GEOMETRY.contains(&keyword) {
            return None;
        }
        line.iter().position(|&c| c == b'#')
    };
    if !text.split(|&c| c == b'\n').any(|line| cut(line).is_some()) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = Vec::with_capacity(text.len());
    for (i, line) in text.split(|&c| c == b'\n').enumerate() {
        if i > 0 {
            out.push(b'\n');
        }
        out.extend_from_slice(&line[..cut(line).unwrap_or(line.len())]);
    }
    std::borrow::Cow::Owned(out)
}

pub(super) fn load_obj(path: &Path) -> Result<Builder, SceneError> {
    let err = |message: String| SceneError::Obj {
        path: path.to_path_buf(),
        message,
    };
    // Read once: the text is scanned for lines and points here and parsed by tobj from memory.
    let text = read_scene_file(path)?;
    let text = strip_trailing_comments(&text);
    // Lines and points are not drawn: tobj would turn them into zero-area triangles, so they
    // are left out, and said so.
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_lines: true,
        ignore_points: true,
    };
    let scan = scan_obj(&text).map_err(err)?;
    if scan.lines_and_points > 0 {
        tracing::warn!(
            "{}: skipping {} line and point elements (only faces are drawn)",
            path.display(),
            scan.lines_and_points
        );
    }
    if scan.short_faces > 0 {
        tracing::warn!(
            "{}: skipping {} faces of fewer than 3 corners",
            path.display(),
            scan.short_faces
        );
    }
    // Material libraries are found next to the OBJ file, as `tobj::load_obj` does.
    let base = path.parent().unwrap_or(Path::new("."));
    // tobj's own errors say only "open file failed": the library's path and the problem are
    // kept here for the warning.
    let mtl_problem = std::cell::RefCell::new(None);
    let (models, materials) = tobj::load_obj_buf(&mut &text[..], &options, |mtl| {
        let mtl_path = base.join(mtl);
        let loaded = read_mtl(&mtl_path)
            .and_then(|bytes| tobj::load_mtl_buf(&mut &bytes[..]).map_err(|e| (e, e.to_string())));
        loaded.map_err(|(e, problem)| {
            *mtl_problem.borrow_mut() = Some(format!("{}: {problem}", mtl_path.display()));
            e
        })
    })
    .map_err(|e| err(e.to_string()))?;
    let mut warned = false;
    let materials = materials.unwrap_or_else(|e| {
        let problem = mtl_problem.take().unwrap_or_else(|| e.to_string());
        tracing::warn!(
            "{}: materials not loaded ({problem}); using grey",
            path.display()
        );
        warned = true;
        Vec::new()
    });
    // `usemtl` of a name no library defines: drawn grey, and said so.
    let unknown: std::collections::BTreeSet<String> = text
        .split(|&c| c == b'\n')
        .filter_map(|l| l.trim_ascii_start().strip_prefix(b"usemtl"))
        .map(|name| String::from_utf8_lossy(name).trim().to_string())
        .filter(|name| !name.is_empty() && !materials.iter().any(|m| &m.name == name))
        .collect();
    if !unknown.is_empty() && !warned {
        tracing::warn!(
            "{}: usemtl of materials its libraries do not define ({}); drawn grey",
            path.display(),
            unknown.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    let mut b = Builder::default();
    let mut ignored = std::collections::BTreeSet::new();
    let mut ids: Vec<Option<u32>> = vec![None; materials.len()];
    let mut default_id = None;
    for model in &models {
        let m = &model.mesh;
        let positions: Vec<Vec3> = m
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let indices = m.indices.clone();
        if indices.iter().any(|&i| i as usize >= positions.len()) {
            return Err(err(format!("object {:?}: index out of range", model.name)));
        }
        let mut normals: Vec<Vec3> = if m.normals.len() == m.positions.len() {
            m.normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]))
                .collect()
        } else {
            smooth_normals(&positions, &indices)
        };
        if positions.iter().chain(&normals).any(|p| !p.is_finite()) {
            return Err(err("non-finite vertex position or normal".into()));
        }
        repair_zero_normals(path, &positions, &mut normals, &indices);
        // OBJ's v runs up the image, glTF's (and the renderer's) down.
        let uvs: Vec<[f32; 2]> = if m.texcoords.len() == 2 * positions.len() {
            m.texcoords
                .chunks_exact(2)
                .map(|t| [t[0], 1.0 - t[1]])
                .collect()
        } else {
            Vec::new()
        };
        if uvs.iter().flatten().any(|c| !c.is_finite()) {
            return Err(err(format!(
                "object {:?}: a texture coordinate is not finite",
                model.name
            )));
        }
        let id = match m.material_id.filter(|&i| i < materials.len()) {
            Some(i) => match ids[i] {
                Some(id) => id,
                None => {
                    let mat = &materials[i];
                    let d = mat.diffuse.unwrap_or([0.8, 0.8, 0.8]);
                    if !d.iter().all(|v| (0.0..=1.0).contains(v)) {
                        return Err(err(format!(
                            "material {:?}: Kd {d:?} must lie in [0, 1]",
                            mat.name
                        )));
                    }
                    // The PBR statements (Pr, Pm, Pc, Pcr), where given; else the Blinn-Phong
                    // exponent → roughness (α² ≈ 2 / (Ns + 2)).
                    let pbr = |key: &str| {
                        obj_pbr_factor(mat, key)
                            .map_err(|m| err(format!("material {:?}: {m}", mat.name)))
                    };
                    let roughness = match pbr("Pr")? {
                        Some(r) => r,
                        None => mat
                            .shininess
                            .map_or(0.5, |ns| (2.0 / (ns.max(0.0) + 2.0)).sqrt().sqrt()),
                    };
                    let metallic = pbr("Pm")?.unwrap_or(0.0);
                    let clearcoat = pbr("Pc")?.unwrap_or(0.0);
                    let clearcoat_roughness = pbr("Pcr")?.unwrap_or(0.0);
                    for (kind, texture) in [
                        ("map_Ka", &mat.ambient_texture),
                        ("map_Ks", &mat.specular_texture),
                        ("bump/norm", &mat.normal_texture),
                        ("map_Ns", &mat.shininess_texture),
                    ] {
                        if texture.is_some() {
                            ignored.insert(kind.to_string());
                        }
                    }
                    // Other maps (map_Pr, map_Pm, …), named rather than dropped silently.
                    for key in mat.unknown_param.keys() {
                        if key.starts_with("map_") && key != "map_Ke" {
                            ignored.insert(key.clone());
                        }
                    }
                    // d (or Tr = 1 − d) below 1: the surface is blended with that alpha.
                    let dissolve = obj_dissolve(mat)
                        .map_err(|m| err(format!("material {:?}: {m}", mat.name)))?;
                    let named =
                        |kind: &str, m: String| err(format!("material {:?}: {kind} {m}", mat.name));
                    let diffuse_map = mat
                        .diffuse_texture
                        .as_deref()
                        .map(|map| obj_texture("map_Kd", map, base, &mut b))
                        .transpose()
                        .map_err(|m| named("map_Kd", m))?;
                    // map_d: a cut-out mask, joined to the base colour's alpha.
                    let base_color = match mat.dissolve_texture.as_deref() {
                        Some(map) => {
                            let mask = obj_texture("map_d", map, base, &mut b)
                                .map_err(|m| named("map_d", m))?;
                            Some(with_mask(&mut b, diffuse_map, mask))
                        }
                        None => diffuse_map,
                    };
                    let emissive_map = mat.unknown_param.get("map_Ke");
                    let emissive = emissive_map
                        .map(|map| obj_texture("map_Ke", map, base, &mut b))
                        .transpose()
                        .map_err(|m| named("map_Ke", m))?;
                    // Ke scales map_Ke; a map_Ke without Ke glows at its texels' colour.
                    let emission = match mat.emissive {
                        Some(ke) if ke.iter().all(|v| v.is_finite() && *v >= 0.0) => ke,
                        Some(ke) => {
                            return Err(err(format!(
                                "material {:?}: Ke {ke:?} must be finite and ≥ 0",
                                mat.name
                            )))
                        }
                        None if emissive.is_some() => [1.0; 3],
                        None => [0.0; 3],
                    };
                    let id = b.material(Material {
                        base_color: d,
                        roughness: roughness.clamp(0.0, 1.0),
                        metallic,
                        specular: 0.5,
                        clearcoat,
                        clearcoat_roughness,
                        sheen_color: [0.0; 3],
                        sheen_roughness: 0.0,
                        emission,
                        alpha: dissolve,
                        alpha_mode: if mat.dissolve_texture.is_some() {
                            AlphaMode::Mask(OBJ_ALPHA_CUTOFF)
                        } else if dissolve < 1.0 {
                            AlphaMode::Blend
                        } else {
                            AlphaMode::Opaque
                        },
                        textures: MaterialTextures {
                            base_color: base_color.map(TextureRef::repeating),
                            emissive: emissive.map(TextureRef::repeating),
                            ..Default::default()
                        },
                        ..Material::default()
                    });
                    ids[i] = Some(id);
                    id
                }
            },
            None => *default_id.get_or_insert_with(|| b.material(Material::default())),
        };
        if uvs.is_empty() && b.materials[id as usize].textures.base_color.is_some() {
            tracing::warn!(
                "{}: object {:?} has a textured material but no texture coordinates (vt); \
                 drawn with the texture's top-left texel",
                path.display(),
                model.name
            );
        }
        b.mesh(&positions, &normals, &uvs, &indices, id);
    }
    if !ignored.is_empty() {
        tracing::warn!(
            "{}: material maps not drawn (envlight renders map_Kd, map_Ke and map_d, as a \
             cut-out): {}",
            path.display(),
            ignored.into_iter().collect::<Vec<_>>().join(", ")
        );
    }
    Ok(b)
}

/// The file an MTL map statement (`map_Kd …`, the words after the keyword) names: all of it,
/// or, when options come first (`-s 1 1 1 file.png`), its last word.
fn map_file_name(map: &str) -> &str {
    let map = map.trim();
    if map.starts_with('-') {
        map.split_whitespace().last().unwrap_or(map)
    } else {
        map
    }
}

/// An MTL material's PBR factor `key` (the PBR extension of MTL: `Pr` roughness, `Pm`
/// metallic, `Pc` clear coat, `Pcr` its roughness), where given: a number in [0, 1], else an
/// error naming the statement.
fn obj_pbr_factor(mat: &tobj::Material, key: &str) -> Result<Option<f32>, String> {
    let Some(text) = mat.unknown_param.get(key) else {
        return Ok(None);
    };
    match text.trim().parse::<f32>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(Some(v)),
        _ => Err(format!("{key} {text:?} is not a number in [0, 1]")),
    }
}

/// An MTL material's opacity: its `d` (dissolve), or 1 − its `Tr` (transparency) where it has
/// no `d`, or 1. A value outside [0, 1] or not a number is an error naming the statement.
fn obj_dissolve(mat: &tobj::Material) -> Result<f32, String> {
    let (statement, opacity) = match (mat.dissolve, mat.unknown_param.get("Tr")) {
        (Some(d), _) => ("d", d),
        (None, Some(tr)) => match tr.trim().parse::<f32>() {
            Ok(t) => ("Tr", 1.0 - t),
            Err(_) => return Err(format!("Tr {tr:?} is not a number")),
        },
        (None, None) => return Ok(1.0),
    };
    if !(0.0..=1.0).contains(&opacity) {
        return Err(format!(
            "{statement} gives an opacity of {opacity}, outside [0, 1]"
        ));
    }
    if statement == "Tr" && opacity == 0.0 {
        // Some writers put the opacity in Tr (three.js's MTL loader has a switch for them).
        tracing::warn!(
            "material {:?}: Tr 1 makes it invisible (Tr is 1 − opacity); if its writer meant \
             opaque, write d 1",
            mat.name
        );
    }
    Ok(opacity)
}

/// The alpha below which an OBJ material with a `map_d` is cut out (as glTF's MASK default).
pub const OBJ_ALPHA_CUTOFF: f32 = 0.5;

/// A base-colour image for an OBJ material with a `map_d` mask (image `mask` of the scene's
/// textures): the `map_Kd` image `diffuse` (white without one) with its alpha replaced by the
/// mask's — its A channel where any texel is not opaque, else its R (a grey mask), read at the
/// same texture coordinates (nearest texel where the sizes differ). The joined image is added
/// to the scene; its index is returned.
fn with_mask(b: &mut Builder, diffuse: Option<u32>, mask: u32) -> u32 {
    let mask = &b.textures[mask as usize];
    let colour = diffuse.map(|i| &b.textures[i as usize]);
    let (width, height) = colour.map_or((mask.width, mask.height), |c| (c.width, c.height));
    let masked_alpha = mask.rgba.chunks_exact(4).any(|p| p[3] < 255);
    let mut rgba = Vec::with_capacity(width as usize * height as usize * 4);
    for y in 0..height {
        for x in 0..width {
            let rgb = colour.map_or([255; 3], |c| {
                let i = (y as usize * c.width as usize + x as usize) * 4;
                c.rgba
                    .get(i..i + 3)
                    .map_or([255; 3], |p| [p[0], p[1], p[2]])
            });
            // The mask's texel whose area holds this texel's centre.
            let mx = (u64::from(x) * u64::from(mask.width) / u64::from(width)) as usize;
            let my = (u64::from(y) * u64::from(mask.height) / u64::from(height)) as usize;
            let m = (my * mask.width as usize + mx) * 4;
            let alpha = mask
                .rgba
                .get(m..m + 4)
                .map_or(255, |p| if masked_alpha { p[3] } else { p[0] });
            rgba.extend_from_slice(&[rgb[0], rgb[1], rgb[2], alpha]);
        }
    }
    let name = match colour {
        Some(c) => format!("{} masked by {}", c.name, mask.name),
        None => format!("mask {}", mask.name),
    };
    b.textures.push(TextureImage {
        name,
        width,
        height,
        rgba,
    });
    (b.textures.len() - 1) as u32
}

/// Loads an MTL texture (`map_Kd`) named relative to the OBJ file's directory. Options before
/// the file name (`-s 1 1 1 file.png`) are not applied, with a warning.
fn obj_texture(kind: &str, map: &str, base: &Path, b: &mut Builder) -> Result<u32, String> {
    let file_name = map_file_name(map);
    if file_name != map.trim() {
        tracing::warn!("{kind} {map:?}: its options are not applied; reading {file_name:?}");
    }
    let file = base.join(file_name);
    if let Some(i) = b
        .textures
        .iter()
        .position(|t| t.name == file.display().to_string())
    {
        return Ok(i as u32);
    }
    let bytes = crate::read_file::read_regular_file(&file, MAX_SCENE_FILE_BYTES, "a texture")
        .map_err(|e| format!("{}: {e}", file.display()))?;
    b.textures
        .push(decode_texture(&bytes, file.display().to_string())?);
    Ok((b.textures.len() - 1) as u32)
}

/// The material libraries an OBJ file (`bytes`, in directory `base`) refers to and the maps
/// of theirs that are drawn, for [`scene_files`]; best effort.
pub(super) fn referenced_files(bytes: &[u8], base: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    for line in String::from_utf8_lossy(bytes).lines() {
        if let Some(names) = line.trim_start().strip_prefix("mtllib") {
            for library in names.split_whitespace().map(|name| base.join(name)) {
                // Its maps that are drawn.
                let maps = crate::read_file::read_regular_file(
                    &library,
                    MAX_MTL_BYTES,
                    "a material library",
                )
                .map(|text| {
                    String::from_utf8_lossy(&text)
                        .lines()
                        .filter_map(|l| {
                            let l = l.trim_start();
                            ["map_Kd", "map_Ke", "map_d"]
                                .iter()
                                .find_map(|kind| l.strip_prefix(kind))
                                .filter(|rest| rest.starts_with([' ', '\t']))
                        })
                        .map(|m| base.join(map_file_name(m)))
                        .collect::<Vec<_>>()
                });
                files.push(library);
                files.extend(maps.unwrap_or_default());
            }
        }
    }
    files
}
