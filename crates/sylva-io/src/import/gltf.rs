//! glTF 2.0 (`.gltf` with external or data-URI buffers, `.glb`). The `gltf` crate parses and
//! validates the JSON; buffers, images and accessors are read here so that every range is
//! checked and every error names its element (`buffers[0]`, `accessors[3] (POSITION of
//! meshes[0].primitives[1])`, `images[2]`).
//!
//! The default scene (else the first, else every root node) is flattened with its node
//! transforms; normals go through the inverse transpose, and mirroring transforms flip the
//! winding. Triangles, strips and fans are read; points and lines carry no surface and are
//! skipped. Per material: `baseColorFactor` × `baseColorTexture` (with
//! `KHR_texture_transform`), `alphaMode` (MASK and BLEND both become a mask at
//! `alphaCutoff`, baked so texture alpha ≥ 0.5 means opaque), `doubleSided`, and
//! `KHR_materials_diffuse_transmission` (a translucent leaf).

use super::{
    decode_image, read_model_file, read_referenced, remap_alpha, tint, to_texture, ImportError,
};
use super::{RawMaterial, RawModel};
use base64::Engine;
use glam::{Mat3, Mat4, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::material::AlphaMode;
use gltf::mesh::{Mode, Semantic};
use gltf::texture::WrappingMode;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use sylva_core::colour::linear_to_srgb8;
use sylva_geom::{Texture, Wrap};

pub(super) fn load(path: &Path) -> Result<RawModel, ImportError> {
    let bytes = read_model_file(path)?;
    let glb = bytes.starts_with(b"glTF");
    if glb {
        check_glb_header(&bytes, path)?;
    }
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| parse_error(e, path, glb))?;
    drop(bytes);
    // The gltf crate's validation indexes some arrays before checking the index: check
    // those first, then let it validate the rest.
    check_before_validation(document.as_json(), path)?;
    let document =
        gltf::Document::from_json(document.into_json()).map_err(|e| parse_error(e, path, glb))?;
    let ctx = Ctx {
        path,
        dir: path.parent().unwrap_or(Path::new("")).to_path_buf(),
        buffers: Vec::new(),
        doc: &document,
    };
    let ctx = ctx.with_buffers(blob)?;
    let mut st = State {
        images: vec![None; document.images().len()],
        slots: HashMap::new(),
        raw: RawModel::default(),
    };

    let roots: Vec<gltf::Node> = match document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        Some(scene) => scene.nodes().collect(),
        None => {
            let mut child = vec![false; document.nodes().len()];
            for n in document.nodes() {
                for c in n.children() {
                    child[c.index()] = true;
                }
            }
            document.nodes().filter(|n| !child[n.index()]).collect()
        }
    };
    // Depth first with an explicit stack: deep hierarchies cannot overflow the call stack.
    let mut visited = vec![false; document.nodes().len()];
    let mut stack: Vec<(gltf::Node, Mat4)> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Mat4::IDENTITY))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        let el = format!("nodes[{}]", node.index());
        if std::mem::replace(&mut visited[node.index()], true) {
            return Err(ImportError::at(
                path,
                el,
                "is reached twice in the node hierarchy (a cycle, or a node with two parents)",
            ));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        if !local.is_finite() {
            return Err(ImportError::at(path, el, "transform is not finite"));
        }
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                ctx.primitive(&mut st, &prim, mesh.index(), node.index(), world)?;
            }
        }
        let children: Vec<_> = node.children().collect();
        stack.extend(children.into_iter().rev().map(|c| (c, world)));
    }
    Ok(st.raw)
}

/// What must hold before the gltf crate validates the document: a glTF 2 asset, and
/// attributes that name existing accessors (its validation indexes them unchecked).
fn check_before_validation(root: &gltf::json::Root, path: &Path) -> Result<(), ImportError> {
    let version = &root.asset.version;
    if version.split('.').next() != Some("2") {
        return Err(ImportError::at(
            path,
            "asset.version",
            format!("'{version}': only glTF 2.x is read"),
        ));
    }
    let accessors = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= accessors {
                    let name = semantic.to_string();
                    return Err(ImportError::at(
                        path,
                        format!("meshes[{m}].primitives[{p}].attributes.{name}"),
                        format!(
                            "accessor {} does not exist (the file has {accessors})",
                            index.value()
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The GLB header checks the gltf crate leaves to arithmetic that could underflow.
fn check_glb_header(bytes: &[u8], path: &Path) -> Result<(), ImportError> {
    let err = |m: String| ImportError::at(path, "GLB header", m);
    if bytes.len() < 20 {
        return Err(err(format!(
            "file is {} bytes, shorter than a GLB header and its JSON chunk header",
            bytes.len()
        )));
    }
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let (version, length) = (u32_at(4), u32_at(8) as usize);
    if version != 2 {
        return Err(err(format!("version {version}; only glTF 2 is read")));
    }
    if length < 20 || length > bytes.len() {
        return Err(err(format!(
            "declares {length} bytes but the file has {}",
            bytes.len()
        )));
    }
    Ok(())
}

fn parse_error(e: gltf::Error, path: &Path, glb: bool) -> ImportError {
    match e {
        gltf::Error::Deserialize(e) => {
            let chunk = if glb { "JSON chunk: " } else { "" };
            let full = e.to_string();
            // serde_json appends " at line L column C"; the element says it instead.
            let msg = full
                .rsplit_once(" at line ")
                .map(|(m, _)| m.to_string())
                .unwrap_or(full);
            let what = match e.classify() {
                serde_json::error::Category::Syntax | serde_json::error::Category::Eof => {
                    "JSON syntax error"
                }
                _ => "not a valid glTF document",
            };
            ImportError::at(
                path,
                format!("{chunk}line {}, column {}", e.line(), e.column()),
                format!("{what}: {msg}"),
            )
        }
        gltf::Error::Validation(errors) => {
            let more = match errors.len() {
                0 | 1 => String::new(),
                n => format!(" (and {} more problems)", n - 1),
            };
            match errors.into_iter().next() {
                Some((p, err)) => ImportError::at(path, p.to_string(), format!("{err}{more}")),
                None => ImportError::whole(path, "invalid glTF"),
            }
        }
        gltf::Error::Binary(e) => ImportError::at(path, "GLB", e.to_string()),
        e => ImportError::whole(path, e.to_string()),
    }
}

struct Ctx<'a> {
    path: &'a Path,
    dir: PathBuf,
    doc: &'a gltf::Document,
    /// Each buffer's bytes, at least its declared length.
    buffers: Vec<Vec<u8>>,
}

/// What a primitive needs of its material: its slot in the model and how to read its uvs.
#[derive(Debug, Clone, Copy)]
struct MatSlot {
    slot: u32,
    tex_coord: u32,
    /// KHR_texture_transform as u' = a·u + b·v + c, v' = d·u + e·v + f.
    uv: [f32; 6],
    textured: bool,
}

struct State {
    images: Vec<Option<Arc<image::RgbaImage>>>,
    slots: HashMap<Option<usize>, MatSlot>,
    raw: RawModel,
}

impl<'a> Ctx<'a> {
    fn err(&self, element: impl Into<String>, message: impl Into<String>) -> ImportError {
        ImportError::at(self.path, element, message)
    }

    /// Loads every buffer and checks buffer views against them.
    fn with_buffers(mut self, mut blob: Option<Vec<u8>>) -> Result<Self, ImportError> {
        for b in self.doc.buffers() {
            let el = format!("buffers[{}]", b.index());
            let (data, origin) = match b.source() {
                gltf::buffer::Source::Bin => {
                    let data = blob.take().ok_or_else(|| {
                        self.err(
                            &el,
                            "refers to the GLB binary chunk, but there is none (or another buffer took it)",
                        )
                    })?;
                    (data, "the GLB binary chunk".to_string())
                }
                gltf::buffer::Source::Uri(uri) => {
                    let data = self.load_uri(uri, &el)?;
                    (data, format!("'{}'", short_uri(uri)))
                }
            };
            if data.len() < b.length() {
                return Err(self.err(
                    el,
                    format!(
                        "byteLength is {} but {origin} holds only {} bytes (buffer too short)",
                        b.length(),
                        data.len()
                    ),
                ));
            }
            self.buffers.push(data);
        }
        for v in self.doc.views() {
            let b = v.buffer();
            let end = v.offset().checked_add(v.length());
            if end.is_none_or(|e| e > b.length()) {
                return Err(self.err(
                    format!("bufferViews[{}]", v.index()),
                    format!(
                        "bytes {}..{} lie outside buffers[{}] ({} bytes)",
                        v.offset(),
                        v.offset() as u128 + v.length() as u128,
                        b.index(),
                        b.length()
                    ),
                ));
            }
        }
        Ok(self)
    }

    /// A data URI's bytes, or a file's relative to the glTF file.
    fn load_uri(&self, uri: &str, el: &str) -> Result<Vec<u8>, ImportError> {
        if let Some(data) = uri.strip_prefix("data:") {
            let (header, payload) = data
                .split_once(',')
                .ok_or_else(|| self.err(el, "data URI without ','"))?;
            return if header.ends_with(";base64") {
                let engine = base64::engine::GeneralPurpose::new(
                    &base64::alphabet::STANDARD,
                    base64::engine::GeneralPurposeConfig::new()
                        .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
                );
                engine
                    .decode(payload.trim())
                    .map_err(|e| self.err(el, format!("data URI: bad base64: {e}")))
            } else {
                Ok(percent_decode(payload))
            };
        }
        if let Some((scheme, _)) = uri.split_once("://") {
            return Err(self.err(
                el,
                format!("'{scheme}://' URIs are not read; only relative file paths and data URIs"),
            ));
        }
        let rel = String::from_utf8_lossy(&percent_decode(uri)).into_owned();
        // Only files inside the model's folder: a model must not read /etc/passwd.
        let p = sylva_core::resolve_inside(&self.dir, &rel, self.path)
            .map_err(|e| self.err(el, e.problem()))?;
        read_referenced(&p, self.path, el, sylva_core::limits::MODEL_FILE_BYTES)
    }

    /// The bytes of a buffer view (ranges checked in [`Ctx::with_buffers`]).
    fn view_bytes(&self, v: &gltf::buffer::View) -> &[u8] {
        &self.buffers[v.buffer().index()][v.offset()..v.offset() + v.length()]
    }

    /// Checks that `n` elements of `size` bytes, `stride` apart from `start`, fit in `view`.
    fn fits(
        &self,
        el: &str,
        view: &gltf::buffer::View,
        start: usize,
        stride: usize,
        n: usize,
        size: usize,
    ) -> Result<(), ImportError> {
        if n == 0 {
            return Ok(());
        }
        let end = stride
            .checked_mul(n - 1)
            .and_then(|x| x.checked_add(start))
            .and_then(|x| x.checked_add(size));
        match end {
            Some(e) if e <= view.length() => Ok(()),
            _ => Err(self.err(
                el,
                format!(
                    "{n} elements of {size} bytes from byte {start} (stride {stride}) run past the end of bufferViews[{}], which is {} bytes long",
                    view.index(),
                    view.length()
                ),
            )),
        }
    }

    /// Checks an accessor's ranges before anything is allocated for it.
    fn check_accessor(&self, acc: &gltf::Accessor, el: &str) -> Result<(), ImportError> {
        let esize = acc.data_type().size() * acc.dimensions().multiplicity();
        if let Some(view) = acc.view() {
            let stride = view.stride().unwrap_or(esize).max(esize);
            self.fits(el, &view, acc.offset(), stride, acc.count(), esize)?;
        }
        Ok(())
    }

    /// Visits every (element, component, value) of an accessor, sparse substitutions last;
    /// integer components are normalised when the accessor says so.
    fn visit(
        &self,
        acc: &gltf::Accessor,
        what: &str,
        f: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(), ImportError> {
        let el = format!("accessors[{}] ({what})", acc.index());
        let ct = acc.data_type();
        let csize = ct.size();
        let comps = acc.dimensions().multiplicity();
        let esize = csize * comps;
        let count = acc.count();
        let norm = acc.normalized();
        let decode = |b: &[u8]| -> f64 {
            match ct {
                DataType::I8 => {
                    let x = b[0] as i8 as f64;
                    if norm {
                        (x / 127.0).max(-1.0)
                    } else {
                        x
                    }
                }
                DataType::U8 => {
                    let x = b[0] as f64;
                    if norm {
                        x / 255.0
                    } else {
                        x
                    }
                }
                DataType::I16 => {
                    let x = i16::from_le_bytes([b[0], b[1]]) as f64;
                    if norm {
                        (x / 32767.0).max(-1.0)
                    } else {
                        x
                    }
                }
                DataType::U16 => {
                    let x = u16::from_le_bytes([b[0], b[1]]) as f64;
                    if norm {
                        x / 65535.0
                    } else {
                        x
                    }
                }
                DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            }
        };
        match acc.view() {
            Some(view) => {
                let stride = view.stride().unwrap_or(esize);
                if stride < esize {
                    return Err(self.err(
                        &el,
                        format!(
                            "bufferViews[{}] has byteStride {stride}, less than the element size {esize}",
                            view.index()
                        ),
                    ));
                }
                self.fits(&el, &view, acc.offset(), stride, count, esize)?;
                let data = self.view_bytes(&view);
                for i in 0..count {
                    let base = acc.offset() + i * stride;
                    for c in 0..comps {
                        f(i, c, decode(&data[base + c * csize..]));
                    }
                }
            }
            None => {
                // No view: all zeros (sparse substitutions follow).
                for i in 0..count {
                    for c in 0..comps {
                        f(i, c, 0.0);
                    }
                }
            }
        }
        if let Some(sparse) = acc.sparse() {
            let n = sparse.count();
            let idx = sparse.indices();
            let isize = idx.index_type().size();
            let iview = idx.view();
            self.fits(
                &format!("{el}.sparse.indices"),
                &iview,
                idx.offset(),
                isize,
                n,
                isize,
            )?;
            let vals = sparse.values();
            let vview = vals.view();
            self.fits(
                &format!("{el}.sparse.values"),
                &vview,
                vals.offset(),
                esize,
                n,
                esize,
            )?;
            let ib = self.view_bytes(&iview);
            let vb = self.view_bytes(&vview);
            for k in 0..n {
                let o = idx.offset() + k * isize;
                let target = match isize {
                    1 => ib[o] as usize,
                    2 => u16::from_le_bytes([ib[o], ib[o + 1]]) as usize,
                    _ => u32::from_le_bytes([ib[o], ib[o + 1], ib[o + 2], ib[o + 3]]) as usize,
                };
                if target >= count {
                    return Err(self.err(
                        format!("{el}.sparse.indices"),
                        format!("index {target} is past the accessor's {count} elements"),
                    ));
                }
                for c in 0..comps {
                    f(
                        target,
                        c,
                        decode(&vb[vals.offset() + k * esize + c * csize..]),
                    );
                }
            }
        }
        Ok(())
    }

    /// An accessor of `N`-vectors as f32, every value finite.
    fn floats<const N: usize>(
        &self,
        acc: &gltf::Accessor,
        what: &str,
    ) -> Result<Vec<[f32; N]>, ImportError> {
        let el = format!("accessors[{}] ({what})", acc.index());
        let comps = acc.dimensions().multiplicity();
        if comps != N
            || !matches!(
                acc.dimensions(),
                Dimensions::Scalar | Dimensions::Vec2 | Dimensions::Vec3 | Dimensions::Vec4
            )
        {
            return Err(self.err(
                el,
                format!("has type {:?}, expected {N} components", acc.dimensions()),
            ));
        }
        self.check_accessor(acc, &el)?;
        sylva_core::check_memory(&el, acc.count() as u64 * N as u64 * 4)
            .map_err(|e| self.err(&el, e.to_string()))?;
        let mut out = vec![[0f32; N]; acc.count()];
        self.visit(acc, what, &mut |i, c, v| out[i][c] = v as f32)?;
        if let Some(i) = out.iter().position(|v| v.iter().any(|x| !x.is_finite())) {
            return Err(self.err(el, format!("element {i} ({:?}) is not finite", out[i])));
        }
        Ok(out)
    }

    fn indices(&self, acc: &gltf::Accessor, what: &str) -> Result<Vec<u32>, ImportError> {
        let el = format!("accessors[{}] ({what})", acc.index());
        if acc.dimensions() != Dimensions::Scalar
            || !matches!(
                acc.data_type(),
                DataType::U8 | DataType::U16 | DataType::U32
            )
        {
            return Err(self.err(
                el,
                format!(
                    "indices must be unsigned integer scalars, got {:?} {:?}",
                    acc.data_type(),
                    acc.dimensions()
                ),
            ));
        }
        self.check_accessor(acc, &el)?;
        sylva_core::check_memory(&el, acc.count() as u64 * 4)
            .map_err(|e| self.err(&el, e.to_string()))?;
        let mut out = vec![0u32; acc.count()];
        self.visit(acc, what, &mut |i, _, v| out[i] = v as u32)?;
        Ok(out)
    }

    fn primitive(
        &self,
        st: &mut State,
        prim: &gltf::Primitive,
        mesh: usize,
        node: usize,
        world: Mat4,
    ) -> Result<(), ImportError> {
        let el = format!("meshes[{mesh}].primitives[{}]", prim.index());
        if !matches!(
            prim.mode(),
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            return Ok(());
        }
        // The specification says to skip primitives without positions.
        let Some(pos_acc) = prim.get(&Semantic::Positions) else {
            return Ok(());
        };
        // glTF 2 positions are floats; integer ones need KHR_mesh_quantization, not read here.
        if pos_acc.data_type() != DataType::F32 {
            return Err(self.err(
                format!("accessors[{}] (POSITION of {el})", pos_acc.index()),
                format!(
                    "positions must be FLOAT (5126), got {:?} (quantized positions, KHR_mesh_quantization, are not read)",
                    pos_acc.data_type()
                ),
            ));
        }
        let positions = self.floats::<3>(&pos_acc, &format!("POSITION of {el}"))?;
        let n = positions.len();
        let normals = match prim.get(&Semantic::Normals) {
            Some(a) => {
                let v = self.floats::<3>(&a, &format!("NORMAL of {el}"))?;
                if v.len() != n {
                    return Err(self.err(
                        &el,
                        format!("NORMAL has {} elements but POSITION has {n}", v.len()),
                    ));
                }
                Some(v)
            }
            None => None,
        };
        let mat = self.material(st, &prim.material())?;
        let uvs = match prim.get(&Semantic::TexCoords(mat.tex_coord)) {
            Some(a) => {
                let v = self.floats::<2>(&a, &format!("TEXCOORD_{} of {el}", mat.tex_coord))?;
                if v.len() != n {
                    return Err(self.err(
                        &el,
                        format!(
                            "TEXCOORD_{} has {} elements but POSITION has {n}",
                            mat.tex_coord,
                            v.len()
                        ),
                    ));
                }
                let [a, b, c, d, e, f] = mat.uv;
                v.into_iter()
                    .map(|[u, v]| [a * u + b * v + c, d * u + e * v + f])
                    .collect()
            }
            None if mat.textured => {
                return Err(self.err(
                    &el,
                    format!(
                        "its material has a base colour texture on TEXCOORD_{}, which the primitive lacks",
                        mat.tex_coord
                    ),
                ))
            }
            None => vec![[0.0; 2]; n],
        };
        let idx: Vec<u32> = match prim.indices() {
            Some(a) => {
                let idx = self.indices(&a, &format!("indices of {el}"))?;
                if let Some(k) = idx.iter().position(|&i| i as usize >= n) {
                    return Err(self.err(
                        format!("accessors[{}] (indices of {el})", a.index()),
                        format!(
                            "index {} at position {k} is out of range: {n} vertices",
                            idx[k]
                        ),
                    ));
                }
                idx
            }
            None => (0..n as u32).collect(),
        };
        let tris: Vec<[u32; 3]> = match prim.mode() {
            Mode::Triangles => {
                if !idx.len().is_multiple_of(3) {
                    return Err(self.err(
                        &el,
                        format!("{} indices are not a whole number of triangles", idx.len()),
                    ));
                }
                idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()
            }
            // Strip triangle i is (v_i, v_{i+1+i%2}, v_{i+2-i%2}): every other one turned
            // so all keep the winding of the first.
            Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
                .map(|i| [idx[i], idx[i + 1 + i % 2], idx[i + 2 - i % 2]])
                .collect(),
            _ => (0..idx.len().saturating_sub(2))
                .map(|i| [idx[i + 1], idx[i + 2], idx[0]])
                .collect(),
        };

        let m3 = Mat3::from_mat4(world);
        let det = m3.determinant();
        if det == 0.0 || !det.is_finite() {
            // A singular transform (scale 0 hides a node) leaves no area to see.
            return Ok(());
        }
        let normal_matrix = m3.inverse().transpose();
        let base = st.raw.positions.len() as u32;
        for (k, p) in positions.iter().enumerate() {
            let q = world.transform_point3(Vec3::from_array(*p));
            if !q.is_finite() {
                return Err(self.err(
                    &el,
                    format!("vertex {k} under nodes[{node}]'s transform is not finite"),
                ));
            }
            st.raw.positions.push(q);
            st.raw.normals.push(match &normals {
                // A zero normal means "compute it"; transformed ones are normalised later.
                Some(v) => normal_matrix * Vec3::from_array(v[k]),
                None => Vec3::ZERO,
            });
        }
        st.raw.uvs.extend(uvs);
        // A mirroring transform turns front faces into back faces: keep the winding right.
        let flip = det < 0.0;
        for t in tris {
            let t = t.map(|i| base + i);
            st.raw
                .triangles
                .push(if flip { [t[0], t[2], t[1]] } else { t });
            st.raw.material_of.push(mat.slot);
        }
        Ok(())
    }

    /// The model's slot for a glTF material, building it on first use.
    fn material(&self, st: &mut State, m: &gltf::Material) -> Result<MatSlot, ImportError> {
        if let Some(s) = st.slots.get(&m.index()) {
            return Ok(*s);
        }
        let el = match m.index() {
            Some(i) => format!("materials[{i}]"),
            None => "default material".to_string(),
        };
        let name = match (m.name(), m.index()) {
            (Some(n), _) if !n.is_empty() => n.to_string(),
            (_, Some(i)) => format!("material {i}"),
            (_, None) => "default".to_string(),
        };
        let pbr = m.pbr_metallic_roughness();
        let factor = pbr.base_color_factor();
        if !factor.iter().all(|x| x.is_finite() && *x >= 0.0) {
            return Err(self.err(
                &el,
                format!("baseColorFactor {factor:?} must be finite and ≥ 0"),
            ));
        }
        let mode = m.alpha_mode();
        let cutoff = m.alpha_cutoff().unwrap_or(0.5);
        if !(cutoff.is_finite() && cutoff >= 0.0) {
            return Err(self.err(&el, format!("alphaCutoff {cutoff} must be ≥ 0")));
        }
        let mut raw = RawMaterial::plain(name, [factor[0], factor[1], factor[2]]);
        raw.double_sided = m.double_sided();
        raw.alpha_mask = mode != AlphaMode::Opaque;
        let transmission = diffuse_transmission(m).map_err(|msg| self.err(&el, msg))?;
        raw.translucent = transmission.is_some();
        raw.diffuse_transmission = transmission.and_then(|t| t.factor);

        let mut slot = MatSlot {
            slot: 0,
            tex_coord: 0,
            uv: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            textured: false,
        };
        // Maps coverage to bytes: ignored when opaque, else cut at the cutoff.
        let bake_alpha = |a: f32| match mode {
            AlphaMode::Opaque => 255,
            _ => remap_alpha(a, cutoff),
        };
        if let Some(info) = pbr.base_color_texture() {
            let tex = info.texture();
            let img = self.image(st, &tex.source(), &el)?;
            let sampler = tex.sampler();
            let wrap = if sampler.wrap_s() == WrappingMode::ClampToEdge
                && sampler.wrap_t() == WrappingMode::ClampToEdge
            {
                Wrap::Clamp
            } else {
                // MIRRORED_REPEAT is read as REPEAT: sylva textures have no mirror mode.
                Wrap::Repeat
            };
            let mut t = to_texture(&img, wrap);
            tint(&mut t.pixels, [factor[0], factor[1], factor[2]]);
            for p in &mut t.pixels {
                p[3] = bake_alpha(factor[3] * p[3] as f32 / 255.0);
            }
            raw.texture = Some(t);
            slot.textured = true;
            slot.tex_coord = info.tex_coord();
            if let Some(tt) = info.extension_value("KHR_texture_transform") {
                let (uv, set) = texture_transform(tt).map_err(|msg| self.err(&el, msg))?;
                slot.uv = uv;
                if let Some(s) = set {
                    slot.tex_coord = s;
                }
            }
        } else if mode != AlphaMode::Opaque && factor[3] < cutoff {
            // Cut everywhere by the factor alone: a 1×1 texture carries the transparency.
            let c = [factor[0], factor[1], factor[2]].map(linear_to_srgb8);
            raw.texture = Some(Texture::new(
                1,
                1,
                vec![[c[0], c[1], c[2], bake_alpha(factor[3])]],
                Wrap::Clamp,
            ));
        }
        st.raw.materials.push(raw);
        slot.slot = st.raw.materials.len() as u32 - 1;
        st.slots.insert(m.index(), slot);
        Ok(slot)
    }

    /// A decoded image, once per image however many materials use it.
    fn image(
        &self,
        st: &mut State,
        img: &gltf::Image,
        used_by: &str,
    ) -> Result<Arc<image::RgbaImage>, ImportError> {
        if let Some(i) = &st.images[img.index()] {
            return Ok(i.clone());
        }
        let el = format!("images[{}] (used by {used_by})", img.index());
        let decoded = match img.source() {
            gltf::image::Source::View { view, .. } => {
                decode_image(self.view_bytes(&view), self.path, &el)?
            }
            gltf::image::Source::Uri { uri, .. } => {
                let bytes = self.load_uri(uri, &el)?;
                decode_image(&bytes, self.path, &el)?
            }
        };
        let decoded = Arc::new(decoded);
        st.images[img.index()] = Some(decoded.clone());
        Ok(decoded)
    }
}

/// What `KHR_materials_diffuse_transmission` says about a material that transmits light.
struct DiffuseTransmission {
    /// `diffuseTransmissionFactor` and `diffuseTransmissionColorFactor`, when the factor is
    /// above 0.
    factor: Option<(f32, [f32; 3])>,
}

/// `KHR_materials_diffuse_transmission`: `Some` when the material transmits any light.
fn diffuse_transmission(m: &gltf::Material) -> Result<Option<DiffuseTransmission>, String> {
    let Some(ext) = m.extension_value("KHR_materials_diffuse_transmission") else {
        return Ok(None);
    };
    let factor = match ext.get("diffuseTransmissionFactor") {
        None => 0.0,
        Some(v) => match v.as_f64() {
            Some(f) if (0.0..=1.0).contains(&f) => f,
            _ => {
                return Err(format!(
                    "KHR_materials_diffuse_transmission.diffuseTransmissionFactor {v} must be a number in [0, 1]"
                ))
            }
        },
    };
    let colour = match ext.get("diffuseTransmissionColorFactor") {
        None => [1.0; 3],
        Some(v) => match v.as_array().map(|a| a.iter().map(|x| x.as_f64()).collect::<Vec<_>>()) {
            Some(c) if c.len() == 3 && c.iter().all(|x| x.is_some_and(|x| x.is_finite() && x >= 0.0)) => {
                [0, 1, 2].map(|k| c[k].expect("checked") as f32)
            }
            _ => {
                return Err(format!(
                    "KHR_materials_diffuse_transmission.diffuseTransmissionColorFactor {v} must be three numbers ≥ 0"
                ))
            }
        },
    };
    if factor > 0.0 || ext.get("diffuseTransmissionTexture").is_some() {
        Ok(Some(DiffuseTransmission {
            factor: (factor > 0.0).then_some((factor as f32, colour)),
        }))
    } else {
        Ok(None)
    }
}

/// `KHR_texture_transform` as an affine uv map, and its `texCoord` override.
fn texture_transform(v: &serde_json::Value) -> Result<([f32; 6], Option<u32>), String> {
    let num = |x: &serde_json::Value| x.as_f64().map(|f| f as f32);
    let pair = |key: &str, default: [f32; 2]| -> Result<[f32; 2], String> {
        match v.get(key) {
            None => Ok(default),
            Some(a) => match a.as_array().map(|a| a.iter().map(num).collect::<Vec<_>>()) {
                Some(x) if x.len() == 2 && x.iter().all(|f| f.is_some_and(f32::is_finite)) => {
                    Ok([x[0].expect("checked"), x[1].expect("checked")])
                }
                _ => Err(format!(
                    "KHR_texture_transform.{key} must be two numbers, got {a}"
                )),
            },
        }
    };
    let [ox, oy] = pair("offset", [0.0, 0.0])?;
    let [sx, sy] = pair("scale", [1.0, 1.0])?;
    let r = match v.get("rotation") {
        None => 0.0,
        Some(x) => num(x)
            .filter(|f| f.is_finite())
            .ok_or_else(|| format!("KHR_texture_transform.rotation must be a number, got {x}"))?,
    };
    let set = match v.get("texCoord") {
        None => None,
        Some(x) => Some(
            x.as_u64()
                .and_then(|s| u32::try_from(s).ok())
                .ok_or_else(|| {
                    format!("KHR_texture_transform.texCoord must be an index, got {x}")
                })?,
        ),
    };
    // The extension's T · R · S with R = [[cos, sin], [−sin, cos]].
    let (s, c) = r.sin_cos();
    Ok(([c * sx, s * sy, ox, -s * sx, c * sy, oy], set))
}

/// `%XX` escapes decoded; anything else (a lone `%`, `%zz`) as it is.
fn percent_decode(s: &str) -> Vec<u8> {
    percent_encoding::percent_decode_str(s).collect()
}

/// A URI short enough for an error message (data URIs can be megabytes).
fn short_uri(uri: &str) -> String {
    if uri.starts_with("data:") {
        let head: String = uri.chars().take(32).collect();
        format!("{head}…")
    } else {
        uri.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("my%20tree.bin"), b"my tree.bin");
        assert_eq!(percent_decode("100%"), b"100%");
        assert_eq!(percent_decode("a%2"), b"a%2");
        assert_eq!(percent_decode("%zz"), b"%zz");
    }

    #[test]
    fn texture_transform_matches_the_extension() {
        let v: serde_json::Value = serde_json::json!({
            "offset": [0.5, 0.25], "rotation": std::f64::consts::FRAC_PI_2, "scale": [2.0, 3.0]
        });
        let ([a, b, c, d, e, f], set) = texture_transform(&v).unwrap();
        assert_eq!(set, None);
        // uv (1, 0): scaled (2, 0), rotated by R = [[0, 1], [-1, 0]] → (0, -2), offset.
        let (u, w) = (a * 1.0 + b * 0.0 + c, d * 1.0 + e * 0.0 + f);
        assert!(
            (u - 0.5).abs() < 1e-6 && (w - (-2.0 + 0.25)).abs() < 1e-6,
            "{u} {w}"
        );
        // uv (0, 1): scaled (0, 3) → (3, 0).
        let (u, w) = (b + c, e + f);
        assert!((u - 3.5).abs() < 1e-6 && (w - 0.25).abs() < 1e-6, "{u} {w}");
    }
}
