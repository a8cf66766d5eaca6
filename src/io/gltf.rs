//! glTF 2.0 (`.gltf` JSON and `.glb` binary) yarn curves as line primitives.
//!
//! # Reading
//!
//! [`decode`] reads every `LINES` (mode 1), `LINE_LOOP` (2) and `LINE_STRIP`
//! (3) primitive of every mesh reachable from the scene graph — the default
//! scene, else every scene, else every root node — and applies the node world
//! transforms (matrix or TRS, composed down the hierarchy) to the positions.
//! Points and triangle primitives are skipped with a note. Buffers come from
//! the GLB `BIN` chunk, base64 `data:` URIs, or external URIs through
//! [`Resources`]; only the buffers line primitives use are loaded.
//!
//! Topology:
//! * `LINE_STRIP` -> one open curve;
//! * `LINE_LOOP` -> one closed curve;
//! * `LINES` -> consecutive segments that share a vertex (segment k ends
//!   where segment k+1 starts) are chained into one polyline; a chain that
//!   comes back to its first vertex is a closed curve.
//!
//! A strip or chain (or a loop, redundantly) that ends on the vertex it
//! started from is a closed curve and the repeated vertex is dropped. Two
//! vertex references are the *same vertex* when they have the same index, or
//! — in a primitive without indices, where a shared vertex can only be
//! written by repeating it — the same position and `_RADIUS` values, bit for
//! bit. So the Khronos asset generator's `Mesh_PrimitiveMode` files 01-03 and
//! 08-10, which all draw one quad outline, each read as one closed curve of
//! four points.
//!
//! Radius: the optional `_RADIUS` vertex attribute (float `SCALAR`) gives a
//! per-vertex radius, scaled by the node's transform scale (cube root of the
//! absolute determinant of the world matrix's 3x3 part). Each curve's radius
//! is the mean of its vertex radii; when every curve has a constant radius
//! the per-vertex radii are dropped. glTF declares metres and +Y up.
//!
//! Every error carries a JSON-pointer-like [`Location::Path`]
//! (`/meshes/0/primitives/1/attributes/POSITION`, `/accessors/3`) or, for the
//! GLB framing, a [`Location::Byte`].
//!
//! # Writing
//!
//! [`encode`] writes one node with one mesh holding one `LINE_STRIP`
//! primitive per yarn, as docs/design.md describes, with attributes `POSITION` (float
//! `VEC3`, with the `min`/`max` the spec requires) and `_RADIUS` (float
//! `SCALAR`: the vertex radius, else the curve radius) and `u32` indices. A
//! closed yarn repeats its first index at the end of its strip: every glTF
//! client draws the closing segment, and the reader rule above turns it back
//! into a closed curve, so closed flags round-trip exactly (an open yarn
//! never repeats an index, even if its end points coincide). All data lives in
//! one buffer (a base64 `data:` URI in `.gltf`, the `BIN` chunk in `.glb`)
//! with three buffer views: positions (stride 12), radii (stride 4), indices.

use std::borrow::Cow;
use std::collections::HashMap;
use std::rc::Rc;

use base64::engine::general_purpose::{GeneralPurpose, GeneralPurposeConfig};
use base64::engine::DecodePaddingMode;
use base64::Engine;
use gltf::json::accessor::{ComponentType, GenericComponentType, Type};
use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;
use serde_json::json;

use super::bytes::ByteReader;
use super::{Decoded, FormatError, ReadOptions, Resources};
use crate::geom::{Units, UpAxis, Vec3, Yarns};

/// Most nodes a glTF may hold (yarns or a character): far beyond any rig or
/// scene, and every walk over them is linear, so the work stays bounded.
pub const MAX_NODES: usize = 1_000_000;

const GLB_MAGIC: &[u8; 4] = b"glTF";
const GLB_HEADER_LEN: usize = 12;
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
/// GL enums of buffer view targets.
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
/// Extensions that change how mesh geometry is stored: a reader that ignores
/// them would read the wrong numbers, so files requiring them are refused.
const GEOMETRY_EXTENSIONS: &[&str] = &[
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_mesh_quantization",
];

/// base64 as in data URIs; some writers drop the `=` padding.
const BASE64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_padding_mode(DecodePaddingMode::Indifferent),
);

fn at(path: impl Into<String>, message: impl Into<String>) -> FormatError {
    FormatError::at_path(path, message)
}

// ---------------------------------------------------------------------------
// Reading
// ---------------------------------------------------------------------------

/// Decodes a `.gltf` (JSON) or `.glb` (binary, detected by its `glTF` magic)
/// file into its line primitives' curves, in the file's frame (metres, +Y up,
/// both declared). External buffers are loaded through `res`.
pub fn decode(
    data: &[u8],
    opts: &ReadOptions,
    res: &dyn Resources,
) -> Result<Decoded, FormatError> {
    if data.is_empty() {
        return Err(FormatError::whole_file(
            "empty file: neither glTF JSON nor GLB",
        ));
    }
    let (json_bytes, json_offset, bin) = if data.starts_with(GLB_MAGIC) {
        let glb = parse_glb(data)?;
        (glb.json, Some(glb.json_offset), glb.bin)
    } else {
        (data, None, None)
    };
    let root = parse_json(json_bytes, json_offset)?;
    check_root(&root)?;
    Reader::new(&root, bin, res, opts).read_scenes()
}

/// The parts of a GLB container.
pub(crate) struct Glb<'a> {
    pub(crate) json: &'a [u8],
    pub(crate) json_offset: u64,
    pub(crate) bin: Option<&'a [u8]>,
}

/// Splits a GLB file into its JSON and BIN chunks, checking the framing.
pub(crate) fn parse_glb(data: &[u8]) -> Result<Glb<'_>, FormatError> {
    let mut r = ByteReader::new(data);
    r.take(4, "GLB magic")?;
    let version = r.u32_le("GLB version")?;
    if version != 2 {
        return Err(FormatError::at_byte(
            4,
            format!("GLB container version {version}; only version 2 (glTF 2.0) is supported"),
        ));
    }
    let length = r.u32_le("GLB total length")?;
    if u64::from(length) != data.len() as u64 {
        return Err(FormatError::at_byte(
            8,
            format!(
                "GLB header declares {length} bytes but the file has {} (truncated or padded file)",
                data.len()
            ),
        ));
    }
    debug_assert_eq!(r.pos(), GLB_HEADER_LEN);
    let (json_offset, json_type, json) = read_chunk(&mut r, "first chunk")?;
    if json_type != CHUNK_JSON {
        return Err(FormatError::at_byte(
            json_offset - 4,
            format!("the first GLB chunk must be JSON (type 0x{CHUNK_JSON:08X}), found type 0x{json_type:08X}"),
        ));
    }
    let mut bin = None;
    while !r.is_at_end() {
        let (offset, kind, body) = read_chunk(&mut r, "chunk")?;
        if kind == CHUNK_BIN {
            if bin.is_some() {
                return Err(FormatError::at_byte(
                    offset - 8,
                    "a GLB file may hold only one BIN chunk",
                ));
            }
            bin = Some(body);
        }
        // Other chunk types are reserved for extensions: skipped, as the spec says.
    }
    Ok(Glb {
        json,
        json_offset,
        bin,
    })
}

/// Reads one chunk header and body; returns (offset of the body, type, body).
fn read_chunk<'a>(r: &mut ByteReader<'a>, what: &str) -> Result<(u64, u32, &'a [u8]), FormatError> {
    let len = r.u32_le(&format!("GLB {what} length"))?;
    let kind = r.u32_le(&format!("GLB {what} type"))?;
    let body_at = r.pos() as u64;
    let len = usize::try_from(len)
        .map_err(|_| FormatError::at_byte(body_at - 8, "chunk length does not fit in memory"))?;
    let body = r.take(len, &format!("GLB {what} body (type 0x{kind:08X})"))?;
    Ok((body_at, kind, body))
}

/// Parses the glTF JSON (the whole `.gltf` file, or the GLB JSON chunk at `glb_offset`).
pub(crate) fn parse_json(
    bytes: &[u8],
    glb_offset: Option<u64>,
) -> Result<gltf::json::Root, FormatError> {
    let text = match std::str::from_utf8(bytes) {
        Ok(t) => t,
        Err(e) => {
            let bad = e.valid_up_to();
            return Err(match glb_offset {
                Some(o) => {
                    FormatError::at_byte(o + bad as u64, "the GLB JSON chunk is not UTF-8 text")
                }
                None => {
                    let line = bytes[..bad].iter().filter(|&&b| b == b'\n').count() + 1;
                    FormatError::at_line(line, "not UTF-8 text: a .gltf file is UTF-8 JSON")
                }
            });
        }
    };
    // glTF forbids a byte order mark, but some writers add one; it carries no meaning.
    let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
    let first = match gltf::json::Root::from_str(text) {
        Ok(root) => return Ok(root),
        Err(e) => e,
    };
    // gltf-json insists on `scene.nodes`, which the spec makes optional: fill it in
    // and try again (only on this error path, so valid files are parsed once).
    if let Ok(mut v) = serde_json::from_str::<serde_json::Value>(text) {
        let mut patched = false;
        if let Some(scenes) = v.get_mut("scenes").and_then(|s| s.as_array_mut()) {
            for scene in scenes.iter_mut().filter_map(|s| s.as_object_mut()) {
                if !scene.contains_key("nodes") {
                    scene.insert("nodes".into(), json!([]));
                    patched = true;
                }
            }
        }
        if patched {
            if let Ok(root) = serde_json::from_value::<gltf::json::Root>(v) {
                return Ok(root);
            }
        }
    }
    Err(first).map_err(|e| {
        let what = match e.classify() {
            serde_json::error::Category::Data => "JSON does not match the glTF schema",
            serde_json::error::Category::Eof => "JSON ends early",
            _ => "invalid JSON",
        };
        match glb_offset {
            Some(o) => FormatError::at_byte(o, format!("GLB JSON chunk: {what}: {e}")),
            None => FormatError::at_line(e.line().max(1), format!("{what}: {e}")),
        }
    })
}

/// Checks what the whole asset declares before any geometry is read.
pub(crate) fn check_root(root: &gltf::json::Root) -> Result<(), FormatError> {
    let version = root.asset.version.as_str();
    if !version.starts_with("2.") {
        return Err(at(
            "/asset/version",
            format!(
                "glTF version '{}': only glTF 2.x is supported",
                crate::geom::excerpt(version)
            ),
        ));
    }
    if root.nodes.len() > MAX_NODES {
        return Err(at(
            "/nodes",
            format!(
                "{} nodes, more than the {MAX_NODES} knitvox reads",
                root.nodes.len()
            ),
        ));
    }
    for (i, ext) in root.extensions_required.iter().enumerate() {
        if GEOMETRY_EXTENSIONS.contains(&ext.as_str()) {
            return Err(at(
                format!("/extensionsRequired/{i}"),
                format!("the file requires extension {ext}, which knitvox does not decode; re-export without it"),
            ));
        }
    }
    Ok(())
}

/// Curves of one primitive, as vertex index lists into its attribute arrays
/// (file-local coordinates; node transforms are applied when emitted).
struct PrimCurves {
    positions: Rc<Vec<f32>>,
    radii: Option<Rc<Vec<f32>>>,
    /// (vertex indices, closed)
    curves: Vec<(Vec<u32>, bool)>,
}

/// A column-major 4x4 matrix, as glTF stores them.
type Mat4 = [f64; 16];

const IDENTITY: Mat4 = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
];

fn mat_mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut c = [0.0; 16];
    for col in 0..4 {
        for row in 0..4 {
            c[col * 4 + row] = (0..4).map(|k| a[k * 4 + row] * b[col * 4 + k]).sum();
        }
    }
    c
}

fn transform_point(m: &Mat4, p: [f64; 3]) -> Vec3 {
    [
        m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12],
        m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13],
        m[2] * p[0] + m[6] * p[1] + m[10] * p[2] + m[14],
    ]
}

/// Cube root of |det| of the 3x3 part: the factor by which the transform scales lengths
/// on average (exact for uniform scales), used for radii.
fn length_scale(m: &Mat4) -> f64 {
    let det = m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2])
        + m[8] * (m[1] * m[6] - m[5] * m[2]);
    det.abs().cbrt()
}

/// The local transform of a node (matrix, or translation * rotation * scale).
fn node_matrix(node: &gltf::json::Node, path: &str) -> Result<Mat4, FormatError> {
    if let Some(m) = &node.matrix {
        let m: Mat4 = m.map(f64::from);
        if let Some(k) = m.iter().position(|x| !x.is_finite()) {
            return Err(at(
                format!("{path}/matrix/{k}"),
                format!("matrix element is not finite ({})", m[k]),
            ));
        }
        return Ok(m);
    }
    let t = node.translation.unwrap_or([0.0; 3]).map(f64::from);
    let s = node.scale.unwrap_or([1.0; 3]).map(f64::from);
    let q = node
        .rotation
        .map_or([0.0, 0.0, 0.0, 1.0], |r| r.0)
        .map(f64::from);
    for (name, vals) in [
        ("translation", &t[..]),
        ("scale", &s[..]),
        ("rotation", &q[..]),
    ] {
        if let Some(k) = vals.iter().position(|x| !x.is_finite()) {
            return Err(at(
                format!("{path}/{name}/{k}"),
                format!("{name} element is not finite ({})", vals[k]),
            ));
        }
    }
    // The spec asks for a unit quaternion; normalising forgives writers that round.
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n > 0.0 && n.is_finite()) {
        return Err(at(
            format!("{path}/rotation"),
            "rotation quaternion has zero length",
        ));
    }
    let [x, y, z, w] = q.map(|v| v / n);
    let r = [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y + z * w),
        2.0 * (x * z - y * w),
        2.0 * (x * y - z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z + x * w),
        2.0 * (x * z + y * w),
        2.0 * (y * z - x * w),
        1.0 - 2.0 * (x * x + y * y),
    ];
    Ok([
        r[0] * s[0],
        r[1] * s[0],
        r[2] * s[0],
        0.0,
        r[3] * s[1],
        r[4] * s[1],
        r[5] * s[1],
        0.0,
        r[6] * s[2],
        r[7] * s[2],
        r[8] * s[2],
        0.0,
        t[0],
        t[1],
        t[2],
        1.0,
    ])
}

/// Decoding state: the parsed JSON, loaded buffers and decoded accessors.
pub(crate) struct Reader<'a> {
    root: &'a gltf::json::Root,
    bin: Option<&'a [u8]>,
    res: &'a dyn Resources,
    opts: &'a ReadOptions,
    /// Loaded buffers, truncated to their declared byteLength.
    buffers: Vec<Option<Cow<'a, [u8]>>>,
    /// Float accessors already decoded (positions, radii), shared by primitives.
    float_cache: HashMap<usize, Rc<Vec<f32>>>,
    /// Primitives already decoded, for meshes instanced by several nodes.
    prim_cache: HashMap<(usize, usize), Option<Rc<PrimCurves>>>,
    /// Points emitted so far (guards instancing against `max_points`).
    total_points: u64,
    notes: Vec<String>,
    /// Skipped primitive modes (name, count).
    skipped: Vec<(&'static str, usize)>,
    /// LINES, LINE_LOOP, LINE_STRIP primitives read.
    modes_read: [usize; 3],
}

/// What the emitted curves look like so far.
#[derive(Default)]
struct Out {
    yarns: Yarns,
    /// Per-vertex radius, filled with NaN for curves without `_RADIUS` until the end.
    vertex_radius: Vec<f64>,
    /// Per curve: whether its radii came from `_RADIUS`.
    has_radius: Vec<bool>,
}

impl<'a> Reader<'a> {
    /// A reader over a parsed document (used by `gltf_skin` too).
    pub(crate) fn new(
        root: &'a gltf::json::Root,
        bin: Option<&'a [u8]>,
        res: &'a dyn Resources,
        opts: &'a ReadOptions,
    ) -> Reader<'a> {
        Reader {
            root,
            bin,
            res,
            opts,
            buffers: vec![None; root.buffers.len()],
            float_cache: HashMap::new(),
            prim_cache: HashMap::new(),
            total_points: 0,
            notes: Vec::new(),
            skipped: Vec::new(),
            modes_read: [0; 3],
        }
    }

    fn read_scenes(mut self) -> Result<Decoded, FormatError> {
        let root = self.root;
        let mut out = Out {
            yarns: Yarns::new(),
            ..Default::default()
        };
        // (label for errors, root node indices with the path each was referenced from)
        let mut sources: Vec<Vec<(usize, String)>> = Vec::new();
        if let Some(s) = root.scene {
            let s = s.value();
            let scene = root.scenes.get(s).ok_or_else(|| {
                at(
                    "/scene",
                    format!(
                        "default scene {s} does not exist (the file has {})",
                        root.scenes.len()
                    ),
                )
            })?;
            sources.push(
                scene
                    .nodes
                    .iter()
                    .enumerate()
                    .map(|(k, n)| (n.value(), format!("/scenes/{s}/nodes/{k}")))
                    .collect(),
            );
        } else if !root.scenes.is_empty() {
            if root.scenes.len() > 1 {
                self.notes.push(format!(
                    "no default scene: read all {} scenes",
                    root.scenes.len()
                ));
            }
            for (s, scene) in root.scenes.iter().enumerate() {
                sources.push(
                    scene
                        .nodes
                        .iter()
                        .enumerate()
                        .map(|(k, n)| (n.value(), format!("/scenes/{s}/nodes/{k}")))
                        .collect(),
                );
            }
        } else {
            // No scenes: every node that is nobody's child is a root.
            let mut is_child = vec![false; root.nodes.len()];
            for node in &root.nodes {
                for c in node.children.iter().flatten() {
                    if let Some(f) = is_child.get_mut(c.value()) {
                        *f = true;
                    }
                }
            }
            if !root.nodes.is_empty() {
                self.notes.push("no scenes: read every root node".into());
            }
            sources.push(
                (0..root.nodes.len())
                    .filter(|&n| !is_child[n])
                    .map(|n| (n, format!("/nodes/{n}")))
                    .collect(),
            );
        }
        for roots in sources {
            self.read_tree(&roots, &mut out)?;
        }
        self.finish(out)
    }

    /// Walks one scene's node trees depth-first, emitting the curves of every mesh.
    fn read_tree(&mut self, roots: &[(usize, String)], out: &mut Out) -> Result<(), FormatError> {
        let root = self.root;
        // Each node may appear once per scene (the spec makes scenes strict trees);
        // refusing repeats also stops cycles and exponential diamond graphs.
        let mut visited = vec![false; root.nodes.len()];
        let mut stack: Vec<(usize, String, Mat4)> = roots
            .iter()
            .rev()
            .map(|(n, p)| (*n, p.clone(), IDENTITY))
            .collect();
        while let Some((n, referrer, parent)) = stack.pop() {
            let node = root.nodes.get(n).ok_or_else(|| {
                at(
                    referrer.clone(),
                    format!(
                        "node {n} does not exist (the file has {})",
                        root.nodes.len()
                    ),
                )
            })?;
            if std::mem::replace(&mut visited[n], true) {
                return Err(at(
                    referrer,
                    format!("node {n} is reached twice in one scene: the node hierarchy has a cycle or a node with two parents"),
                ));
            }
            let path = format!("/nodes/{n}");
            let local = node_matrix(node, &path)?;
            let world = if parent == IDENTITY {
                local
            } else {
                mat_mul(&parent, &local)
            };
            if let Some(m) = node.mesh {
                // A skinned mesh ignores its node's transform (spec 3.7.3.3); without
                // animation the joints sit in bind pose, so the vertices are the rest shape.
                let (world_for_mesh, skinned) = if node.skin.is_some() {
                    (IDENTITY, true)
                } else {
                    (world, false)
                };
                if skinned {
                    self.notes.push(format!(
                        "node {n} is skinned: its mesh is read in bind pose"
                    ));
                }
                self.emit_mesh(m.value(), &path, &world_for_mesh, out)?;
            }
            for (k, c) in node
                .children
                .as_deref()
                .unwrap_or(&[])
                .iter()
                .enumerate()
                .rev()
            {
                stack.push((c.value(), format!("{path}/children/{k}"), world));
            }
        }
        Ok(())
    }

    fn emit_mesh(
        &mut self,
        m: usize,
        node: &str,
        world: &Mat4,
        out: &mut Out,
    ) -> Result<(), FormatError> {
        let root = self.root;
        let referrer = format!("{node}/mesh");
        let mesh = root.meshes.get(m).ok_or_else(|| {
            at(
                referrer.clone(),
                format!(
                    "mesh {m} does not exist (the file has {})",
                    root.meshes.len()
                ),
            )
        })?;
        for p in 0..mesh.primitives.len() {
            let prim = match self.prim_cache.get(&(m, p)) {
                Some(c) => c.clone(),
                None => {
                    let c = self.read_primitive(m, p)?.map(Rc::new);
                    self.prim_cache.insert((m, p), c.clone());
                    c
                }
            };
            if let Some(prim) = prim {
                self.emit_prim(
                    &prim,
                    &format!("/meshes/{m}/primitives/{p}"),
                    node,
                    world,
                    out,
                )?;
            }
        }
        Ok(())
    }

    /// Transforms one primitive's curves by `world` and appends them.
    fn emit_prim(
        &mut self,
        prim: &PrimCurves,
        path: &str,
        node: &str,
        world: &Mat4,
        out: &mut Out,
    ) -> Result<(), FormatError> {
        let identity = *world == IDENTITY;
        let scale = length_scale(world);
        if prim.radii.is_some() && !(scale > 0.0 && scale.is_finite()) {
            return Err(at(
                node,
                format!("the node's world transform is singular (scale {scale}): the radii of {path} would vanish"),
            ));
        }
        for (idx, closed) in &prim.curves {
            self.total_points = self.total_points.saturating_add(idx.len() as u64);
            if self.total_points > self.opts.max_points {
                return Err(at(
                    path,
                    format!(
                        "the scene holds more than {} points (the read limit; instanced meshes count once per node)",
                        self.opts.max_points
                    ),
                ));
            }
            let mut pts = Vec::with_capacity(idx.len());
            for &v in idx {
                let k = v as usize * 3;
                let p = match prim.positions.get(k..k + 3) {
                    Some(s) => [f64::from(s[0]), f64::from(s[1]), f64::from(s[2])],
                    None => return Err(at(path, format!("vertex {v} out of range"))), // checked on read
                };
                let q = if identity {
                    p
                } else {
                    transform_point(world, p)
                };
                if !q.iter().all(|x| x.is_finite()) {
                    return Err(at(
                        path,
                        format!("vertex {v} is not finite after the node transform ({q:?})"),
                    ));
                }
                pts.push(q);
            }
            let mean = match &prim.radii {
                Some(r) => {
                    let start = out.vertex_radius.len();
                    for &v in idx {
                        let rv = r.get(v as usize).copied().unwrap_or(f32::NAN);
                        out.vertex_radius.push(f64::from(rv) * scale);
                    }
                    let rs = &out.vertex_radius[start..];
                    out.has_radius.push(true);
                    rs.iter().sum::<f64>() / rs.len().max(1) as f64
                }
                None => {
                    out.vertex_radius
                        .extend(std::iter::repeat_n(f64::NAN, idx.len()));
                    out.has_radius.push(false);
                    self.opts.radius
                }
            };
            out.yarns.push_curve(&pts, *closed, mean);
        }
        Ok(())
    }

    fn finish(mut self, out: Out) -> Result<Decoded, FormatError> {
        let Out {
            mut yarns,
            mut vertex_radius,
            has_radius,
        } = out;
        let with = has_radius.iter().filter(|h| **h).count();
        let radius_in_file = with > 0;
        if radius_in_file {
            if with < has_radius.len() {
                self.notes.push(format!(
                    "{} of {} curves have no _RADIUS attribute: they get the default radius {} m",
                    has_radius.len() - with,
                    has_radius.len(),
                    self.opts.radius
                ));
                vertex_radius
                    .iter_mut()
                    .filter(|r| r.is_nan())
                    .for_each(|r| *r = self.opts.radius);
            }
            // Constant radius along every curve: the per-curve radius says it all.
            let uniform = (0..yarns.num_curves()).all(|c| {
                let r = &vertex_radius[yarns.curve_range(c)];
                r.iter().all(|x| x.to_bits() == r[0].to_bits())
            });
            if uniform {
                for c in 0..yarns.num_curves() {
                    yarns.radius[c] = vertex_radius[yarns.offsets[c]];
                }
            } else {
                yarns.vertex_radius = Some(vertex_radius);
            }
        }
        let [lines, loops, strips] = self.modes_read;
        self.notes.insert(
            0,
            format!(
                "glTF {}{}: {} curves from {lines} LINES, {loops} LINE_LOOP, {strips} LINE_STRIP primitives",
                crate::geom::excerpt(&self.root.asset.version),
                self.root.asset.generator.as_deref().map(|g| format!(" by '{}'", crate::geom::excerpt(g))).unwrap_or_default(),
                yarns.num_curves()
            ),
        );
        if !self.skipped.is_empty() {
            let list: Vec<String> = self
                .skipped
                .iter()
                .map(|(m, n)| format!("{n} {m}"))
                .collect();
            self.notes.push(format!(
                "skipped primitives that are not lines: {}",
                list.join(", ")
            ));
        }
        for ext in &self.root.extensions_required {
            self.notes.push(format!(
                "the file requires extension {ext}; ignored (it does not change line geometry)"
            ));
        }
        Ok(Decoded {
            yarns,
            frames: None,
            units: Some(Units::METRES),
            up_axis: Some(UpAxis::Y),
            radius_in_file,
            notes: self.notes,
        })
    }

    /// Reads one primitive's vertices and splits it into curves; `None` for non-line modes.
    fn read_primitive(&mut self, m: usize, p: usize) -> Result<Option<PrimCurves>, FormatError> {
        let root = self.root;
        let path = format!("/meshes/{m}/primitives/{p}");
        let Some(prim) = root.meshes.get(m).and_then(|mesh| mesh.primitives.get(p)) else {
            return Ok(None);
        };
        let mode = match prim.mode {
            Checked::Valid(mode) => mode,
            Checked::Invalid => {
                return Err(at(
                    format!("{path}/mode"),
                    "unknown primitive mode (valid: 0 to 6)",
                ))
            }
        };
        let slot = match mode {
            Mode::Lines => 0,
            Mode::LineLoop => 1,
            Mode::LineStrip => 2,
            other => {
                let name = match other {
                    Mode::Points => "POINTS",
                    _ => "triangle",
                };
                match self.skipped.iter_mut().find(|(n, _)| *n == name) {
                    Some(e) => e.1 += 1,
                    None => self.skipped.push((name, 1)),
                }
                return Ok(None);
            }
        };
        if prim.targets.as_ref().is_some_and(|t| !t.is_empty()) {
            self.notes
                .push(format!("{path}: morph targets ignored (base shape read)"));
        }
        let pos_acc = prim
            .attributes
            .get(&Checked::Valid(Semantic::Positions))
            .ok_or_else(|| {
                at(
                    format!("{path}/attributes"),
                    "line primitive has no POSITION attribute",
                )
            })?
            .value();
        let positions =
            self.read_floats(pos_acc, Type::Vec3, &format!("{path}/attributes/POSITION"))?;
        let nv = positions.len() / 3;
        let radii = match prim
            .attributes
            .get(&Checked::Valid(Semantic::Extras("RADIUS".into())))
        {
            Some(a) => {
                let rpath = format!("{path}/attributes/_RADIUS");
                let r = self.read_floats(a.value(), Type::Scalar, &rpath)?;
                if r.len() != nv {
                    return Err(at(
                        rpath,
                        format!(
                            "_RADIUS has {} values but POSITION has {nv} vertices",
                            r.len()
                        ),
                    ));
                }
                if let Some(k) = r
                    .iter()
                    .position(|x| x.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater))
                {
                    return Err(at(
                        format!("/accessors/{}", a.value()),
                        format!("_RADIUS value {} at element {k} is not positive", r[k]),
                    ));
                }
                Some(r)
            }
            None => None,
        };
        let indices: Option<Vec<u32>> = match prim.indices {
            Some(a) => {
                let ipath = format!("{path}/indices");
                let idx = self.read_indices(a.value(), &ipath)?;
                if let Some(k) = idx.iter().position(|&i| i as usize >= nv) {
                    return Err(at(
                        format!("/accessors/{}", a.value()),
                        format!(
                            "index {} at element {k} is out of range: POSITION has {nv} vertices",
                            idx[k]
                        ),
                    ));
                }
                Some(idx)
            }
            None => None,
        };
        let n = indices.as_ref().map_or(nv, Vec::len);
        let vertex = |k: usize| -> u32 { indices.as_ref().map_or(k as u32, |i| i[k]) };
        let indexed = indices.is_some();
        let same = |a: u32, b: u32| -> bool {
            a == b
                || (!indexed && {
                    let (a, b) = (a as usize, b as usize);
                    positions[a * 3..a * 3 + 3]
                        .iter()
                        .zip(&positions[b * 3..b * 3 + 3])
                        .all(|(x, y)| x.to_bits() == y.to_bits())
                        && radii
                            .as_ref()
                            .is_none_or(|r| r[a].to_bits() == r[b].to_bits())
                })
        };
        let mut curves = Vec::new();
        match mode {
            Mode::Lines => {
                if n % 2 != 0 {
                    return Err(at(
                        path,
                        format!("LINES primitive has an odd number of vertices ({n})"),
                    ));
                }
                let mut cur: Vec<u32> = Vec::new();
                for s in 0..n / 2 {
                    let (a, b) = (vertex(2 * s), vertex(2 * s + 1));
                    match cur.last() {
                        Some(&last) if same(a, last) => {
                            if same(b, cur[0]) {
                                curves.push((std::mem::take(&mut cur), true));
                            } else {
                                cur.push(b);
                            }
                        }
                        _ => {
                            if !cur.is_empty() {
                                curves.push((std::mem::take(&mut cur), false));
                            }
                            cur = vec![a, b];
                        }
                    }
                }
                if !cur.is_empty() {
                    curves.push((cur, false));
                }
            }
            Mode::LineLoop | Mode::LineStrip => {
                let what = if mode == Mode::LineLoop {
                    "LINE_LOOP"
                } else {
                    "LINE_STRIP"
                };
                if n < 2 {
                    return Err(at(
                        path,
                        format!("{what} primitive has {n} vertex; a curve needs at least 2"),
                    ));
                }
                let mut c: Vec<u32> = (0..n).map(vertex).collect();
                let mut closed = mode == Mode::LineLoop;
                // Ends on its first vertex: closed, drop the repeat (a closed curve keeps >= 2 points).
                if n >= 3 && same(c[n - 1], c[0]) {
                    c.pop();
                    closed = true;
                }
                curves.push((c, closed));
            }
            _ => {}
        }
        self.modes_read[slot] += 1;
        Ok(Some(PrimCurves {
            positions,
            radii,
            curves,
        }))
    }

    /// Makes sure buffer `b` is loaded; returns its bytes.
    fn buffer(&mut self, b: usize, referrer: &str) -> Result<&[u8], FormatError> {
        let root = self.root;
        let buf = root.buffers.get(b).ok_or_else(|| {
            at(
                referrer,
                format!(
                    "buffer {b} does not exist (the file has {})",
                    root.buffers.len()
                ),
            )
        })?;
        if self.buffers[b].is_none() {
            let path = format!("/buffers/{b}");
            let data: Cow<'a, [u8]> = match &buf.uri {
                None => {
                    match self.bin {
                        Some(bin) if b == 0 => Cow::Borrowed(bin),
                        Some(_) => return Err(at(
                            path,
                            "only buffer 0 may refer to the GLB BIN chunk; this buffer has no uri",
                        )),
                        None => {
                            return Err(at(
                                path,
                                "buffer has no uri and the file has no GLB BIN chunk",
                            ))
                        }
                    }
                }
                Some(uri) if uri.starts_with("data:") => Cow::Owned(
                    decode_data_uri(uri).map_err(|e| at(format!("{path}/uri"), e.to_string()))?,
                ),
                Some(uri) => {
                    let declared = buf.byte_length.0;
                    if declared > self.opts.max_memory {
                        return Err(at(
                                format!("{path}/byteLength"),
                                format!(
                                    "external buffer declares {declared} bytes, more than the memory budget of {} bytes (--max-memory)",
                                    self.opts.max_memory
                                ),
                            ));
                    }
                    Cow::Owned(self.res.load(uri, declared).map_err(|e| {
                        at(
                            format!("{path}/uri"),
                            format!(
                                "cannot load external buffer '{}': {e}",
                                crate::geom::excerpt(uri)
                            ),
                        )
                    })?)
                }
            };
            let declared = buf.byte_length.0;
            if (data.len() as u64) < declared {
                return Err(at(
                    format!("{path}/byteLength"),
                    format!(
                        "buffer declares {declared} bytes but its data holds only {}",
                        data.len()
                    ),
                ));
            }
            let declared = declared as usize; // <= data.len(), so it fits
            let data = match data {
                Cow::Borrowed(s) => Cow::Borrowed(&s[..declared]),
                Cow::Owned(mut v) => {
                    v.truncate(declared);
                    Cow::Owned(v)
                }
            };
            self.buffers[b] = Some(data);
        }
        Ok(self.buffers[b].as_deref().unwrap_or(&[]))
    }

    /// The bytes of buffer view `v` and its stride, bounds-checked against the buffer.
    fn view(&mut self, v: usize, referrer: &str) -> Result<(&[u8], Option<usize>), FormatError> {
        let root = self.root;
        let view = root.buffer_views.get(v).ok_or_else(|| {
            at(
                referrer,
                format!(
                    "bufferView {v} does not exist (the file has {})",
                    root.buffer_views.len()
                ),
            )
        })?;
        let path = format!("/bufferViews/{v}");
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let len = view.byte_length.0;
        let data = self.buffer(view.buffer.value(), &format!("{path}/buffer"))?;
        let end = offset.checked_add(len).filter(|&e| e <= data.len() as u64).ok_or_else(|| {
            at(
                path.clone(),
                format!(
                    "bufferView (byteOffset {offset} + byteLength {len}) runs past the end of buffer {} ({} bytes)",
                    view.buffer.value(),
                    data.len()
                ),
            )
        })?;
        Ok((
            &data[offset as usize..end as usize],
            view.byte_stride.map(|s| s.0),
        ))
    }

    /// Decodes a float accessor (positions, radii) into a flat array, checking everything.
    pub(crate) fn read_floats(
        &mut self,
        a: usize,
        want: Type,
        referrer: &str,
    ) -> Result<Rc<Vec<f32>>, FormatError> {
        if let Some(v) = self.float_cache.get(&a) {
            // The cache key is the accessor; the type check must still hold for this use.
            if self
                .root
                .accessors
                .get(a)
                .is_some_and(|acc| acc.type_ == Checked::Valid(want))
            {
                return Ok(v.clone());
            }
        }
        let vals = self.read_accessor(a, want, &[ComponentType::F32], false, referrer)?;
        let out: Vec<f32> = vals.into_iter().map(f32::from_bits).collect();
        if let Some(k) = out.iter().position(|x| !x.is_finite()) {
            let ncomp = want.multiplicity();
            return Err(at(
                format!("/accessors/{a}"),
                format!(
                    "element {} component {} is not finite ({})",
                    k / ncomp,
                    k % ncomp,
                    out[k]
                ),
            ));
        }
        let out = Rc::new(out);
        self.float_cache.insert(a, out.clone());
        Ok(out)
    }

    pub(crate) fn read_indices(
        &mut self,
        a: usize,
        referrer: &str,
    ) -> Result<Vec<u32>, FormatError> {
        self.read_accessor(
            a,
            Type::Scalar,
            &[ComponentType::U8, ComponentType::U16, ComponentType::U32],
            false,
            referrer,
        )
    }

    /// Reads accessor `a` as raw little-endian components widened to u32 (float bits for
    /// F32), applying sparse substitution. All sizes are checked before anything is allocated.
    /// `normalized_ok`: whether a normalized integer accessor is acceptable (skin weights).
    pub(crate) fn read_accessor(
        &mut self,
        a: usize,
        want: Type,
        comps: &[ComponentType],
        normalized_ok: bool,
        referrer: &str,
    ) -> Result<Vec<u32>, FormatError> {
        let root = self.root;
        let acc = root.accessors.get(a).ok_or_else(|| {
            at(
                referrer,
                format!(
                    "accessor {a} does not exist (the file has {})",
                    root.accessors.len()
                ),
            )
        })?;
        let path = format!("/accessors/{a}");
        let ty = match acc.type_ {
            Checked::Valid(t) => t,
            Checked::Invalid => return Err(at(format!("{path}/type"), "unknown accessor type")),
        };
        let ct = match acc.component_type {
            Checked::Valid(GenericComponentType(c)) => c,
            Checked::Invalid => {
                return Err(at(
                    format!("{path}/componentType"),
                    "unknown component type",
                ))
            }
        };
        let use_ = referrer.rsplit('/').next().unwrap_or(referrer);
        if ty != want || !comps.contains(&ct) {
            let allowed: Vec<String> = comps.iter().map(|c| type_name(want, *c)).collect();
            return Err(at(
                path,
                format!(
                    "{use_} (at {referrer}) must be {}, this accessor is {}{}",
                    allowed.join(" or "),
                    type_name(ty, ct),
                    if acc.normalized { " normalized" } else { "" }
                ),
            ));
        }
        if acc.normalized && !normalized_ok {
            return Err(at(
                format!("{path}/normalized"),
                format!("{use_} must not be a normalized accessor"),
            ));
        }
        let count = acc.count.0;
        if count == 0 {
            return Err(at(format!("{path}/count"), "accessor count is 0"));
        }
        if count > self.opts.max_points {
            return Err(at(
                format!("{path}/count"),
                format!(
                    "accessor count {count} exceeds the read limit of {} points",
                    self.opts.max_points
                ),
            ));
        }
        let ncomp = ty.multiplicity();
        let csize = ct.size();
        let elem = ncomp * csize;
        let Some(bv) = acc.buffer_view else {
            return Err(at(
                path,
                format!(
                    "accessor has no bufferView (all zeros{}); not supported for {use_}",
                    if acc.sparse.is_some() {
                        " plus sparse values"
                    } else {
                        ""
                    }
                ),
            ));
        };
        let offset = acc.byte_offset.map_or(0, |o| o.0);
        let (bytes, stride) = self.view(bv.value(), &format!("{path}/bufferView"))?;
        let stride = stride.unwrap_or(elem);
        if stride < elem {
            return Err(at(
                format!("/bufferViews/{}/byteStride", bv.value()),
                format!(
                    "byteStride {stride} is smaller than the {elem}-byte elements of accessor {a}"
                ),
            ));
        }
        let need = (count - 1)
            .checked_mul(stride as u64)
            .and_then(|x| x.checked_add(offset))
            .and_then(|x| x.checked_add(elem as u64));
        match need {
            Some(need) if need <= bytes.len() as u64 => {}
            _ => {
                return Err(at(
                    path,
                    format!(
                        "count {count} of {elem}-byte elements at stride {stride} from byteOffset {offset} needs {} bytes but bufferView {} has {}",
                        need.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string()),
                        bv.value(),
                        bytes.len()
                    ),
                ))
            }
        }
        let (count, offset) = (count as usize, offset as usize); // both bounded by bytes.len()
        let mut out = Vec::with_capacity(count * ncomp);
        for e in 0..count {
            let base = offset + e * stride;
            for c in 0..ncomp {
                out.push(read_component(bytes, base + c * csize, ct));
            }
        }
        if let Some(sp) = &acc.sparse {
            self.apply_sparse(a, sp, count, ncomp, ct, &mut out)?;
        }
        Ok(out)
    }

    fn apply_sparse(
        &mut self,
        a: usize,
        sp: &gltf::json::accessor::sparse::Sparse,
        count: usize,
        ncomp: usize,
        ct: ComponentType,
        out: &mut [u32],
    ) -> Result<(), FormatError> {
        let path = format!("/accessors/{a}/sparse");
        let n = sp.count.0;
        if n == 0 || n > count as u64 {
            return Err(at(
                format!("{path}/count"),
                format!("sparse count {n} must be between 1 and the accessor count {count}"),
            ));
        }
        let n = n as usize;
        let ict = match sp.indices.component_type {
            Checked::Valid(gltf::json::accessor::IndexComponentType(c)) => c,
            Checked::Invalid => {
                return Err(at(
                    format!("{path}/indices/componentType"),
                    "unknown sparse index component type",
                ))
            }
        };
        let isize = ict.size();
        let (ibytes, _) = self.view(
            sp.indices.buffer_view.value(),
            &format!("{path}/indices/bufferView"),
        )?;
        let ioff = sp.indices.byte_offset.0;
        if ioff
            .checked_add((n * isize) as u64)
            .is_none_or(|e| e > ibytes.len() as u64)
        {
            return Err(at(
                format!("{path}/indices"),
                format!("{n} sparse indices of {isize} bytes from byteOffset {ioff} run past the bufferView ({} bytes)", ibytes.len()),
            ));
        }
        let idx: Vec<usize> = (0..n)
            .map(|k| read_component(ibytes, ioff as usize + k * isize, ict) as usize)
            .collect();
        if let Some(k) = idx.iter().position(|&i| i >= count) {
            return Err(at(
                format!("{path}/indices"),
                format!(
                    "sparse index {} at element {k} is out of range (count {count})",
                    idx[k]
                ),
            ));
        }
        let csize = ct.size();
        let elem = ncomp * csize;
        let (vbytes, _) = self.view(
            sp.values.buffer_view.value(),
            &format!("{path}/values/bufferView"),
        )?;
        let voff = sp.values.byte_offset.0;
        if voff
            .checked_add((n * elem) as u64)
            .is_none_or(|e| e > vbytes.len() as u64)
        {
            return Err(at(
                format!("{path}/values"),
                format!("{n} sparse values of {elem} bytes from byteOffset {voff} run past the bufferView ({} bytes)", vbytes.len()),
            ));
        }
        for (k, &i) in idx.iter().enumerate() {
            for c in 0..ncomp {
                out[i * ncomp + c] =
                    read_component(vbytes, voff as usize + k * elem + c * csize, ct);
            }
        }
        Ok(())
    }
}

/// One little-endian component widened to u32 (floats as their bit pattern).
/// The caller has bounds-checked `at..at + size`.
fn read_component(bytes: &[u8], at: usize, ct: ComponentType) -> u32 {
    let b = |k: usize| bytes.get(at + k).copied().unwrap_or(0);
    match ct.size() {
        1 => u32::from(b(0)),
        2 => u32::from(u16::from_le_bytes([b(0), b(1)])),
        _ => u32::from_le_bytes([b(0), b(1), b(2), b(3)]),
    }
}

fn type_name(t: Type, c: ComponentType) -> String {
    let t = match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    };
    let c = match c {
        ComponentType::I8 => "byte",
        ComponentType::U8 => "unsigned byte",
        ComponentType::I16 => "short",
        ComponentType::U16 => "unsigned short",
        ComponentType::U32 => "unsigned int",
        ComponentType::F32 => "float",
    };
    format!("{c} {t}")
}

/// Why a `data:` URI could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DataUriError {
    /// No `,` separates the header from the data.
    #[error("data URI has no ',' before its data")]
    NoData,
    /// The data is not base64 (`header` is the part before the `,`).
    #[error("data URI '{header},...' is not base64; only base64 data URIs are supported")]
    NotBase64 { header: String },
    /// The base64 data does not decode.
    #[error("data URI holds invalid base64: {0}")]
    InvalidBase64(#[source] base64::DecodeError),
}

/// Decodes a `data:[<media type>];base64,<data>` URI.
fn decode_data_uri(uri: &str) -> Result<Vec<u8>, DataUriError> {
    let Some((header, payload)) = uri.split_once(',') else {
        return Err(DataUriError::NoData);
    };
    if !header.ends_with(";base64") {
        return Err(DataUriError::NotBase64 {
            header: header.to_string(),
        });
    }
    BASE64
        .decode(payload.trim_end())
        .map_err(DataUriError::InvalidBase64)
}

// ---------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------

/// Encodes yarns (already in glTF's frame: metres, +Y up) as a `.gltf`
/// (`binary == false`, buffer as a base64 data URI) or `.glb` file: one
/// `LINE_STRIP` per yarn with `POSITION` and `_RADIUS`; closed yarns repeat
/// their first index (see the module docs).
pub fn encode(yarns: &Yarns, binary: bool) -> Result<Vec<u8>, FormatError> {
    yarns.validate()?;
    let n = yarns.num_curves();
    let nv = yarns.num_points();
    let index_count = nv + yarns.num_closed();
    if u32::try_from(nv).is_err() || u32::try_from(index_count).is_err() {
        return Err(FormatError::whole_file(format!(
            "{nv} vertices are more than glTF's 32-bit indices can address"
        )));
    }
    // One buffer: positions | radii | indices, every section a multiple of 4 bytes.
    let pos_len = nv * 12;
    let rad_len = nv * 4;
    let idx_len = index_count * 4;
    let mut bin = Vec::with_capacity(pos_len + rad_len + idx_len);
    for (v, p) in yarns.points.iter().enumerate() {
        for &x in p {
            let f = x as f32;
            if !f.is_finite() {
                return Err(FormatError::whole_file(format!(
                    "vertex {v}: coordinate {x} does not fit in a 32-bit float"
                )));
            }
            bin.extend_from_slice(&f.to_le_bytes());
        }
    }
    for v in 0..nv {
        let r = yarns.radius_at(v) as f32;
        if !(r.is_finite() && r > 0.0) {
            return Err(FormatError::whole_file(format!(
                "vertex {v}: radius {} is not a positive 32-bit float",
                yarns.radius_at(v)
            )));
        }
        bin.extend_from_slice(&r.to_le_bytes());
    }
    let mut accessors = Vec::with_capacity(3 * n);
    let mut primitives = Vec::with_capacity(n);
    let mut idx_at = 0usize;
    for c in 0..n {
        let range = yarns.curve_range(c);
        let len = range.len();
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &yarns.points[range.clone()] {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f32);
                hi[k] = hi[k].max(p[k] as f32);
            }
        }
        let m = len + usize::from(yarns.closed[c]);
        for i in (0..len).chain(yarns.closed[c].then_some(0)) {
            bin.extend_from_slice(&(i as u32).to_le_bytes());
        }
        let a = accessors.len();
        accessors.push(json!({
            "bufferView": 0, "byteOffset": range.start * 12, "componentType": 5126, "count": len, "type": "VEC3",
            "min": lo.map(f64::from), "max": hi.map(f64::from),
        }));
        accessors.push(json!({
            "bufferView": 1, "byteOffset": range.start * 4, "componentType": 5126, "count": len, "type": "SCALAR",
        }));
        accessors.push(json!({
            "bufferView": 2, "byteOffset": idx_at * 4, "componentType": 5125, "count": m, "type": "SCALAR",
        }));
        idx_at += m;
        primitives.push(json!({
            "attributes": { "POSITION": a, "_RADIUS": a + 1 }, "indices": a + 2, "mode": 3,
        }));
    }
    debug_assert_eq!(bin.len(), pos_len + rad_len + idx_len);
    let generator = format!("knitvox {}", env!("CARGO_PKG_VERSION"));
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": generator },
        "scene": 0,
        "scenes": [ { "name": "yarns", "nodes": [0] } ],
        "nodes": [ { "name": "yarns" } ],
    });
    if n > 0 {
        let mut buffer = json!({ "byteLength": bin.len() });
        if !binary {
            buffer["uri"] = json!(format!(
                "data:application/octet-stream;base64,{}",
                BASE64.encode(&bin)
            ));
        }
        doc["nodes"][0]["mesh"] = json!(0);
        doc["meshes"] = json!([ { "name": "yarns", "primitives": primitives } ]);
        doc["buffers"] = json!([buffer]);
        doc["bufferViews"] = json!([
            { "buffer": 0, "byteOffset": 0, "byteLength": pos_len, "byteStride": 12, "target": ARRAY_BUFFER },
            { "buffer": 0, "byteOffset": pos_len, "byteLength": rad_len, "byteStride": 4, "target": ARRAY_BUFFER },
            { "buffer": 0, "byteOffset": pos_len + rad_len, "byteLength": idx_len, "target": ELEMENT_ARRAY_BUFFER },
        ]);
        doc["accessors"] = serde_json::Value::Array(accessors);
    }
    let json_bytes = serde_json::to_vec(&doc)
        .map_err(|e| FormatError::whole_file(format!("cannot serialise glTF JSON: {e}")))?;
    if !binary {
        return Ok(json_bytes);
    }
    glb_container(json_bytes, if n > 0 { Some(bin) } else { None })
}

/// Wraps JSON and an optional BIN payload into a GLB container, padding each
/// chunk to 4 bytes (JSON with spaces, BIN with zeros) as the spec requires.
fn glb_container(mut json: Vec<u8>, bin: Option<Vec<u8>>) -> Result<Vec<u8>, FormatError> {
    json.resize(json.len().next_multiple_of(4), b' ');
    let bin = bin.map(|mut b| {
        b.resize(b.len().next_multiple_of(4), 0);
        b
    });
    let total = GLB_HEADER_LEN + 8 + json.len() + bin.as_ref().map_or(0, |b| 8 + b.len());
    let total32 = u32::try_from(total).map_err(|_| {
        FormatError::whole_file(format!(
            "a GLB holds at most 4 GiB; these yarns need {total} bytes (write .gltf)"
        ))
    })?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(GLB_MAGIC);
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(&json);
    if let Some(b) = bin {
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(&b);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::{Location, NoResources};

    fn opts() -> ReadOptions {
        ReadOptions::default()
    }

    /// A minimal glTF with one primitive over an embedded buffer.
    fn doc(
        mode: u32,
        positions: &[[f32; 3]],
        indices: Option<&[u32]>,
        extra_node: serde_json::Value,
    ) -> Vec<u8> {
        let mut bin: Vec<u8> = positions
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let pos_len = bin.len();
        let mut prim = json!({ "attributes": { "POSITION": 0 }, "mode": mode });
        let mut accessors = vec![
            json!({ "bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3" }),
        ];
        let mut views = vec![json!({ "buffer": 0, "byteLength": pos_len })];
        if let Some(idx) = indices {
            bin.extend(idx.iter().flat_map(|i| i.to_le_bytes()));
            views.push(json!({ "buffer": 0, "byteOffset": pos_len, "byteLength": idx.len() * 4 }));
            accessors.push(json!({ "bufferView": 1, "componentType": 5125, "count": idx.len(), "type": "SCALAR" }));
            prim["indices"] = json!(1);
        }
        let mut node = json!({ "mesh": 0 });
        if let serde_json::Value::Object(m) = extra_node {
            for (k, v) in m {
                node[k] = v;
            }
        }
        serde_json::to_vec(&json!({
            "asset": { "version": "2.0" },
            "scene": 0, "scenes": [ { "nodes": [0] } ], "nodes": [node],
            "meshes": [ { "primitives": [prim] } ],
            "buffers": [ { "byteLength": bin.len(), "uri": format!("data:application/octet-stream;base64,{}", BASE64.encode(&bin)) } ],
            "bufferViews": views, "accessors": accessors,
        }))
        .unwrap()
    }

    const SQ: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];

    #[test]
    fn strip_loop_and_lines_topology() {
        let d = decode(&doc(3, &SQ, None, json!({})), &opts(), &NoResources).unwrap();
        assert_eq!(
            (
                d.yarns.num_curves(),
                d.yarns.num_points(),
                d.yarns.closed.clone()
            ),
            (1, 4, vec![false])
        );
        let d = decode(&doc(2, &SQ, None, json!({})), &opts(), &NoResources).unwrap();
        assert_eq!(
            (d.yarns.num_points(), d.yarns.closed.clone()),
            (4, vec![true])
        );
        // Strip that returns to its first index: closed, repeat dropped.
        let d = decode(
            &doc(3, &SQ, Some(&[0, 1, 2, 3, 0]), json!({})),
            &opts(),
            &NoResources,
        )
        .unwrap();
        assert_eq!(
            (d.yarns.num_points(), d.yarns.closed.clone()),
            (4, vec![true])
        );
        // LINES: chains [0 1 2] (open) and [3 0 1] (closed by the segment 1-3).
        let d = decode(
            &doc(1, &SQ, Some(&[0, 1, 1, 2, 3, 0, 0, 1, 1, 3]), json!({})),
            &opts(),
            &NoResources,
        )
        .unwrap();
        assert_eq!(d.yarns.offsets, vec![0, 3, 6]);
        assert_eq!(d.yarns.closed, vec![false, true]);
        assert_eq!(d.yarns.points[3], [0.0, 1.0, 0.0]);
        let d = decode(
            &doc(1, &SQ, Some(&[0, 1, 1, 2, 2, 0, 3, 2]), json!({})),
            &opts(),
            &NoResources,
        )
        .unwrap();
        assert_eq!(d.yarns.offsets, vec![0, 3, 5]);
        assert_eq!(d.yarns.closed, vec![true, false]);
        assert_eq!(d.units, Some(Units::METRES));
        assert_eq!(d.up_axis, Some(UpAxis::Y));
        assert!(!d.radius_in_file);
    }

    #[test]
    fn node_transforms_compose() {
        // Scale 2 then translate (10, 0, 0); rotation 90 degrees about Z maps x to y.
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let node = json!({ "translation": [10.0, 0.0, 0.0], "rotation": [0.0, 0.0, s, s], "scale": [2.0, 2.0, 2.0] });
        let d = decode(&doc(3, &SQ, None, node), &opts(), &NoResources).unwrap();
        let p = d.yarns.points[1]; // (1,0,0) -> scaled (2,0,0) -> rotated (0,2,0) -> (10,2,0)
        assert!(
            (p[0] - 10.0).abs() < 1e-6 && (p[1] - 2.0).abs() < 1e-6 && p[2].abs() < 1e-6,
            "{p:?}"
        );
        let m = json!({ "matrix": [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 5.0, 1.0] });
        let d = decode(&doc(3, &SQ, None, m), &opts(), &NoResources).unwrap();
        assert_eq!(d.yarns.points[2], [1.0, 1.0, 5.0]);
    }

    #[test]
    fn radius_scaled_by_node() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], false, 0.25);
        let bytes = encode(&y, false).unwrap();
        let mut v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        v["nodes"][0]["scale"] = json!([2.0, 2.0, 2.0]);
        let d = decode(&serde_json::to_vec(&v).unwrap(), &opts(), &NoResources).unwrap();
        assert!(d.radius_in_file);
        assert!((d.yarns.radius[0] - 0.5).abs() < 1e-7);
        assert_eq!(d.yarns.points[2], [4.0, 0.0, 0.0]);
    }

    #[test]
    fn round_trip_both_containers() {
        let mut y = Yarns::new();
        y.push_curve(
            &[[0.0, 0.1, 0.2], [1.0, 0.5, -0.25], [2.0, 0.0, 0.0]],
            true,
            0.001,
        );
        y.push_curve(&[[0.0; 3], [0.0, 0.0, 3.0]], false, 0.002);
        for binary in [false, true] {
            let bytes = encode(&y, binary).unwrap();
            assert_eq!(bytes.starts_with(GLB_MAGIC), binary);
            let d = decode(&bytes, &opts(), &NoResources).unwrap();
            assert!(d.yarns.same_topology(&y));
            assert_eq!(
                d.yarns.points,
                y.points
                    .iter()
                    .map(|p| p.map(|x| f64::from(x as f32)))
                    .collect::<Vec<_>>()
            );
            assert_eq!(
                d.yarns.radius,
                vec![f64::from(0.001f32), f64::from(0.002f32)]
            );
            assert!(d.yarns.vertex_radius.is_none());
        }
    }

    #[test]
    fn empty_yarns_encode_and_decode() {
        for binary in [false, true] {
            let bytes = encode(&Yarns::new(), binary).unwrap();
            let d = decode(&bytes, &opts(), &NoResources).unwrap();
            assert_eq!(d.yarns.num_curves(), 0);
        }
    }

    #[test]
    fn glb_framing_errors_name_bytes() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1.0; 3]], false, 0.1);
        let good = encode(&y, true).unwrap();
        let mut bad = good.clone();
        bad[8..12].copy_from_slice(&(good.len() as u32 + 100).to_le_bytes());
        let e = decode(&bad, &opts(), &NoResources).unwrap_err();
        assert_eq!(e.location, Location::Byte(8), "{e}");
        let mut bad = good.clone();
        bad[4] = 1;
        assert_eq!(
            decode(&bad, &opts(), &NoResources).unwrap_err().location,
            Location::Byte(4)
        );
        let mut bad = good.clone();
        bad[12..16].copy_from_slice(&(1u32 << 31).to_le_bytes());
        let e = decode(&bad, &opts(), &NoResources).unwrap_err();
        assert_eq!(e.location, Location::Byte(20), "{e}");
        assert!(e.message.contains("2147483648"), "{e}");
    }

    #[test]
    fn scenes_optional_parts() {
        // The spec makes scene.nodes optional (gltf-json does not); no scenes at all means root nodes.
        let base: serde_json::Value =
            serde_json::from_slice(&doc(3, &SQ, None, json!({}))).unwrap();
        let mut v = base.clone();
        v["scenes"] = json!([{}, { "nodes": [0] }]);
        v.as_object_mut().unwrap().remove("scene");
        let d = decode(&serde_json::to_vec(&v).unwrap(), &opts(), &NoResources).unwrap();
        assert_eq!(d.yarns.num_curves(), 1);
        let mut v = base.clone();
        v.as_object_mut().unwrap().remove("scene");
        v.as_object_mut().unwrap().remove("scenes");
        let d = decode(&serde_json::to_vec(&v).unwrap(), &opts(), &NoResources).unwrap();
        assert_eq!(d.yarns.num_curves(), 1);
        assert!(d.notes.iter().any(|n| n.contains("root node")));
        // A byte order mark is tolerated.
        let mut bom = "\u{FEFF}".as_bytes().to_vec();
        bom.extend(serde_json::to_vec(&base).unwrap());
        assert_eq!(
            decode(&bom, &opts(), &NoResources)
                .unwrap()
                .yarns
                .num_curves(),
            1
        );
    }

    #[test]
    fn singular_transform_with_radii_is_refused() {
        let mut y = Yarns::new();
        y.push_curve(&[[0.0; 3], [1.0, 0.0, 0.0]], false, 0.25);
        let mut v: serde_json::Value = serde_json::from_slice(&encode(&y, false).unwrap()).unwrap();
        v["nodes"][0]["scale"] = json!([1.0, 0.0, 1.0]);
        let e = decode(&serde_json::to_vec(&v).unwrap(), &opts(), &NoResources).unwrap_err();
        assert_eq!(e.location, Location::Path("/nodes/0".into()), "{e}");
    }

    #[test]
    fn data_uri_decoding() {
        assert_eq!(
            decode_data_uri("data:application/octet-stream;base64,AAEC").unwrap(),
            vec![0, 1, 2]
        );
        assert_eq!(
            decode_data_uri("data:application/gltf-buffer;base64,AAE").unwrap(),
            vec![0, 1]
        );
        assert!(decode_data_uri("data:application/octet-stream;base64,A!EC")
            .unwrap_err()
            .to_string()
            .contains("base64"));
        assert!(decode_data_uri("data:text/plain,abc")
            .unwrap_err()
            .to_string()
            .contains("not base64"));
    }

    #[test]
    fn matrices() {
        let s = length_scale(&[
            2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 1.0, 2.0, 3.0, 1.0,
        ]);
        assert!((s - 2.0).abs() < 1e-12);
        let t: Mat4 = [
            1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 2.0, 3.0, 1.0,
        ];
        assert_eq!(transform_point(&mat_mul(&t, &t), [0.0; 3]), [2.0, 4.0, 6.0]);
        assert_eq!(mat_mul(&IDENTITY, &t), t);
    }
}
