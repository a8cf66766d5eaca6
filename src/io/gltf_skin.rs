//! glTF 2.0 skinned characters (`.gltf` / `.glb`) -> [`Character`].
//!
//! Reads every node (hierarchy and rest TRS or matrix), every skin (joints and
//! `inverseBindMatrices`, identity when absent, spec 3.7.3), the `TRIANGLES`
//! primitives (indexed or not; other modes are skipped with a note) of every
//! node that carries a mesh, with `POSITION`, and for skinned nodes every
//! `JOINTS_n` (unsigned byte/short) / `WEIGHTS_n` (float, or normalized
//! unsigned byte/short) set, and every animation's translation, rotation and
//! scale channels (spec 3.11; rotations may be float or normalized integers).
//! Morph target `weights` channels are skipped with a note.
//!
//! The GLB framing, JSON, buffers and accessors go through the same
//! bounds-checked code as the yarn reader (`io::gltf`). Weights that do not
//! sum to 1 are renormalised (with a note); a joint index past the skin's
//! joint list, non-increasing key times, a wrong output count or a non-finite
//! number is an error naming its JSON path. The result is checked with
//! [`Character::validate`] before it is returned.

use std::path::Path;

use gltf::json::accessor::{ComponentType, GenericComponentType, Type};
use gltf::json::animation::{Interpolation as GInterp, Property};
use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;

use super::gltf::{check_root, parse_glb, parse_json, Reader};
use super::{DirResources, Format, FormatError, IoError, ReadOptions, Resources};
use crate::anim::{
    Animation, Channel, Character, CharacterMesh, Interpolation, LocalTransform, Mat4, Node,
    Sampler, Skin, TargetPath,
};

fn at(path: impl Into<String>, message: impl Into<String>) -> FormatError {
    FormatError::at_path(path, message)
}

/// Reads a character from a `.gltf` / `.glb` file; external buffers are
/// loaded relative to the file's directory.
pub fn read_character(path: &Path) -> Result<Character, IoError> {
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    // A `.glb` without its signature is refused from its first bytes, not
    // read whole first (as the yarn readers do).
    if Format::from_path(path) == Some(Format::Glb) {
        super::codec::refuse_without_signature(
            path,
            "character",
            super::max_memory(),
            Format::Glb,
            b"glTF",
            |head| decode_character(head, &DirResources(dir.clone())).map(|_| ()),
        )?;
    }
    let data = super::input::read_input(path, "character", super::max_memory())?;
    let format = if data.starts_with(b"glTF") {
        Format::Glb
    } else {
        Format::Gltf
    };
    decode_character(&data, &DirResources(dir)).map_err(|source| IoError::Format {
        path: path.to_path_buf(),
        format,
        source,
    })
}

/// Decodes a skinned, animated character from `.gltf` JSON or `.glb` bytes.
pub fn decode_character(data: &[u8], res: &dyn Resources) -> Result<Character, FormatError> {
    if data.is_empty() {
        return Err(FormatError::whole_file(
            "empty file: neither glTF JSON nor GLB",
        ));
    }
    let (json_bytes, json_offset, bin) = if data.starts_with(b"glTF") {
        let glb = parse_glb(data)?;
        (glb.json, Some(glb.json_offset), glb.bin)
    } else {
        (data, None, None)
    };
    let root = parse_json(json_bytes, json_offset)?;
    check_root(&root)?;
    let opts = ReadOptions::default();
    let mut r = Reader::new(&root, bin, res, &opts);
    let mut ch = Character {
        skeleton: read_nodes(&root)?,
        ..Default::default()
    };
    for (s, skin) in root.skins.iter().enumerate() {
        ch.skins.push(read_skin(&mut r, s, skin)?);
    }
    let mut skipped = 0usize;
    for (n, node) in root.nodes.iter().enumerate() {
        let Some(m) = node.mesh else { continue };
        let m = m.value();
        let mesh = root.meshes.get(m).ok_or_else(|| {
            at(
                format!("/nodes/{n}/mesh"),
                format!("mesh {m} does not exist"),
            )
        })?;
        let skin = match node.skin {
            Some(s) if s.value() >= ch.skins.len() => {
                return Err(at(
                    format!("/nodes/{n}/skin"),
                    format!("skin {} does not exist", s.value()),
                ))
            }
            Some(s) => Some((s.value(), ch.skins[s.value()].joints.len())),
            None => None,
        };
        for p in 0..mesh.primitives.len() {
            match read_primitive(&mut r, &root, n, m, p, skin, &mut ch.notes)? {
                Some(cm) => ch.meshes.push(cm),
                None => skipped += 1,
            }
        }
    }
    if skipped > 0 {
        ch.notes.push(format!(
            "skipped {skipped} primitives that are not TRIANGLES"
        ));
    }
    for (a, anim) in root.animations.iter().enumerate() {
        let an = read_animation(&mut r, &root, a, anim, &mut ch.notes)?;
        ch.animations.push(an);
    }
    ch.validate().map_err(|e| at(e.path, e.message))?;
    Ok(ch)
}

fn read_nodes(root: &gltf::json::Root) -> Result<Vec<Node>, FormatError> {
    let n = root.nodes.len();
    let mut out: Vec<Node> = Vec::with_capacity(n);
    for node in &root.nodes {
        let rest = match &node.matrix {
            Some(m) => LocalTransform::Matrix(Mat4::from_column_slice(&m.map(f64::from))),
            None => LocalTransform::Trs {
                translation: node.translation.unwrap_or([0.0; 3]).map(f64::from),
                rotation: node
                    .rotation
                    .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
                    .map(f64::from),
                scale: node.scale.unwrap_or([1.0; 3]).map(f64::from),
            },
        };
        out.push(Node {
            name: node.name.clone(),
            parent: None,
            rest,
        });
    }
    for (p, node) in root.nodes.iter().enumerate() {
        for (k, c) in node.children.iter().flatten().enumerate() {
            let path = format!("/nodes/{p}/children/{k}");
            let child = out.get_mut(c.value()).ok_or_else(|| {
                at(
                    &path,
                    format!("node {} does not exist ({n} nodes)", c.value()),
                )
            })?;
            if let Some(other) = child.parent {
                return Err(at(
                    path,
                    format!(
                        "node {} already has parent {other}: a node has at most one parent",
                        c.value()
                    ),
                ));
            }
            child.parent = Some(p);
        }
    }
    Ok(out)
}

fn read_skin(r: &mut Reader<'_>, s: usize, skin: &gltf::json::Skin) -> Result<Skin, FormatError> {
    let joints: Vec<usize> = skin.joints.iter().map(|j| j.value()).collect();
    let inverse_bind = match skin.inverse_bind_matrices {
        None => vec![Mat4::identity(); joints.len()],
        Some(a) => {
            let path = format!("/skins/{s}/inverseBindMatrices");
            let v = r.read_floats(a.value(), Type::Mat4, &path)?;
            // Spec 3.7.3.1: at least one matrix per joint.
            if v.len() / 16 < joints.len() {
                return Err(at(
                    path,
                    format!(
                        "{} inverse bind matrices for {} joints",
                        v.len() / 16,
                        joints.len()
                    ),
                ));
            }
            v.chunks_exact(16)
                .take(joints.len())
                .map(|c| Mat4::from_iterator(c.iter().map(|&x| f64::from(x))))
                .collect()
        }
    };
    Ok(Skin {
        joints,
        inverse_bind,
    })
}

/// A decoded component as a number: floats as they are, normalized integers
/// mapped to [0, 1] or [-1, 1] (spec 3.6.2.3).
fn component_value(bits: u32, ct: ComponentType) -> f64 {
    match ct {
        ComponentType::F32 => f64::from(f32::from_bits(bits)),
        ComponentType::U8 => f64::from(bits) / 255.0,
        ComponentType::U16 => f64::from(bits) / 65535.0,
        ComponentType::I8 => (f64::from(bits as u8 as i8) / 127.0).max(-1.0),
        ComponentType::I16 => (f64::from(bits as u16 as i16) / 32767.0).max(-1.0),
        ComponentType::U32 => f64::from(bits),
    }
}

/// Reads an accessor of type `want` from the allowed component types as f64,
/// integers only when normalized.
fn read_numbers(
    r: &mut Reader<'_>,
    root: &gltf::json::Root,
    a: usize,
    want: Type,
    comps: &[ComponentType],
    referrer: &str,
) -> Result<Vec<f64>, FormatError> {
    let bits = r.read_accessor(a, want, comps, true, referrer)?;
    let acc = root.accessors.get(a);
    let ct = match acc.map(|acc| acc.component_type) {
        Some(Checked::Valid(GenericComponentType(c))) => c,
        _ => ComponentType::F32, // read_accessor checked it exists and is valid
    };
    if ct != ComponentType::F32 && !acc.is_some_and(|acc| acc.normalized) {
        return Err(at(
            format!("/accessors/{a}/normalized"),
            format!("integer values for {referrer} must be a normalized accessor"),
        ));
    }
    let out: Vec<f64> = bits.into_iter().map(|b| component_value(b, ct)).collect();
    if let Some(k) = out.iter().position(|x| !x.is_finite()) {
        let nc = want.multiplicity();
        return Err(at(
            format!("/accessors/{a}"),
            format!(
                "element {} component {} is not finite ({})",
                k / nc,
                k % nc,
                out[k]
            ),
        ));
    }
    Ok(out)
}

/// One TRIANGLES primitive of mesh `m` on node `n`; `None` for other modes.
fn read_primitive(
    r: &mut Reader<'_>,
    root: &gltf::json::Root,
    n: usize,
    m: usize,
    p: usize,
    skin: Option<(usize, usize)>,
    notes: &mut Vec<String>,
) -> Result<Option<CharacterMesh>, FormatError> {
    let path = format!("/meshes/{m}/primitives/{p}");
    let Some(prim) = root.meshes.get(m).and_then(|mesh| mesh.primitives.get(p)) else {
        return Ok(None);
    };
    match prim.mode {
        Checked::Valid(Mode::Triangles) => {}
        Checked::Valid(_) => return Ok(None),
        Checked::Invalid => return Err(at(format!("{path}/mode"), "unknown primitive mode")),
    }
    let pos = prim
        .attributes
        .get(&Checked::Valid(Semantic::Positions))
        .ok_or_else(|| at(format!("{path}/attributes"), "primitive has no POSITION"))?
        .value();
    let flat = r.read_floats(pos, Type::Vec3, &format!("{path}/attributes/POSITION"))?;
    let positions: Vec<[f64; 3]> = flat
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]].map(f64::from))
        .collect();
    let nv = positions.len();
    let indices: Vec<u32> = match prim.indices {
        Some(a) => {
            let idx = r.read_indices(a.value(), &format!("{path}/indices"))?;
            if let Some(k) = idx.iter().position(|&i| i as usize >= nv) {
                return Err(at(
                    format!("/accessors/{}", a.value()),
                    format!(
                        "index {} at element {k} is out of range: POSITION has {nv} vertices",
                        idx[k]
                    ),
                ));
            }
            idx
        }
        None => (0..u32::try_from(nv).unwrap_or(u32::MAX)).collect(),
    };
    if indices.len() % 3 != 0 {
        return Err(at(
            path,
            format!(
                "TRIANGLES primitive has {} vertices, not a multiple of 3",
                indices.len()
            ),
        ));
    }
    let triangles = indices
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let mut cm = CharacterMesh {
        node: n,
        skin: None,
        positions,
        triangles,
        ..Default::default()
    };
    let Some((s, nj)) = skin else {
        return Ok(Some(cm));
    };
    cm.skin = Some(s);
    // Influence sets JOINTS_k / WEIGHTS_k, k = 0, 1, ... (spec 3.7.3.2).
    let mut sets = Vec::new();
    for k in 0u32.. {
        let (Some(j), Some(w)) = (
            prim.attributes.get(&Checked::Valid(Semantic::Joints(k))),
            prim.attributes.get(&Checked::Valid(Semantic::Weights(k))),
        ) else {
            break;
        };
        let jp = format!("{path}/attributes/JOINTS_{k}");
        let joints = r.read_accessor(
            j.value(),
            Type::Vec4,
            &[ComponentType::U8, ComponentType::U16],
            false,
            &jp,
        )?;
        let wp = format!("{path}/attributes/WEIGHTS_{k}");
        let weights = read_numbers(
            r,
            root,
            w.value(),
            Type::Vec4,
            &[ComponentType::F32, ComponentType::U8, ComponentType::U16],
            &wp,
        )?;
        for (what, len, p) in [
            ("JOINTS", joints.len(), &jp),
            ("WEIGHTS", weights.len(), &wp),
        ] {
            if len != nv * 4 {
                return Err(at(
                    p.clone(),
                    format!("{what}_{k} has {} elements but POSITION has {nv}", len / 4),
                ));
            }
        }
        if let Some(e) = weights.iter().position(|&x| x < 0.0) {
            return Err(at(
                wp,
                format!("vertex {}: weight {} is negative", e / 4, weights[e]),
            ));
        }
        // A joint with weight 0 is unused, so its index need not be valid.
        if let Some(e) = (0..joints.len()).find(|&e| joints[e] as usize >= nj && weights[e] > 0.0) {
            return Err(at(
                jp,
                format!(
                    "vertex {}: joint index {} is out of range (skin {s} has {nj} joints)",
                    e / 4,
                    joints[e]
                ),
            ));
        }
        sets.push((joints, weights));
    }
    if sets.is_empty() {
        return Err(at(
            format!("{path}/attributes"),
            format!("node {n} is skinned but the primitive has no JOINTS_0 / WEIGHTS_0"),
        ));
    }
    let k = 4 * sets.len();
    cm.influences = k;
    cm.joints = Vec::with_capacity(nv * k);
    cm.weights = Vec::with_capacity(nv * k);
    let mut renormalised = 0usize;
    for v in 0..nv {
        let start = cm.weights.len();
        for (j, w) in &sets {
            for e in 4 * v..4 * v + 4 {
                // Unused influences (weight 0) point at joint 0 so the index is always valid.
                let used = w[e] > 0.0;
                cm.joints.push(if used { j[e] } else { 0 });
                cm.weights.push(if used { w[e] } else { 0.0 });
            }
        }
        let ws = &mut cm.weights[start..];
        let sum: f64 = ws.iter().sum();
        if !(sum > 0.0) {
            return Err(at(
                format!("{path}/attributes/WEIGHTS_0"),
                format!("vertex {v}: all skin weights are 0"),
            ));
        }
        // Spec 3.7.3.2 asks for a sum of 1; quantised weights are often slightly off.
        if (sum - 1.0).abs() > 2e-7 {
            renormalised += 1;
        }
        ws.iter_mut().for_each(|w| *w /= sum);
    }
    if renormalised > 0 {
        notes.push(format!(
            "{path}: {renormalised} of {nv} vertices had skin weights not summing to 1; renormalised"
        ));
    }
    Ok(Some(cm))
}

fn read_animation(
    r: &mut Reader<'_>,
    root: &gltf::json::Root,
    a: usize,
    anim: &gltf::json::Animation,
    notes: &mut Vec<String>,
) -> Result<Animation, FormatError> {
    let path = format!("/animations/{a}");
    let mut out = Animation {
        name: anim.name.clone(),
        ..Default::default()
    };
    // File sampler index -> index in `out.samplers`.
    let mut map: Vec<Option<usize>> = vec![None; anim.samplers.len()];
    let mut weights_channels = 0usize;
    for (c, chn) in anim.channels.iter().enumerate() {
        let cp = format!("{path}/channels/{c}");
        let tpath = match chn.target.path {
            Checked::Valid(Property::Translation) => TargetPath::Translation,
            Checked::Valid(Property::Rotation) => TargetPath::Rotation,
            Checked::Valid(Property::Scale) => TargetPath::Scale,
            Checked::Valid(Property::MorphTargetWeights) => {
                weights_channels += 1;
                continue;
            }
            Checked::Invalid => return Err(at(format!("{cp}/target/path"), "unknown target path")),
        };
        let node = chn.target.node.value();
        if node >= root.nodes.len() {
            return Err(at(
                format!("{cp}/target/node"),
                format!("node {node} does not exist ({} nodes)", root.nodes.len()),
            ));
        }
        let s = chn.sampler.value();
        let smp = anim.samplers.get(s).ok_or_else(|| {
            at(
                format!("{cp}/sampler"),
                format!(
                    "sampler {s} does not exist ({} samplers)",
                    anim.samplers.len()
                ),
            )
        })?;
        let sampler = match map[s] {
            Some(i) => i,
            None => {
                let sp = format!("{path}/samplers/{s}");
                let interpolation = match smp.interpolation {
                    Checked::Valid(GInterp::Linear) => Interpolation::Linear,
                    Checked::Valid(GInterp::Step) => Interpolation::Step,
                    Checked::Valid(GInterp::CubicSpline) => Interpolation::CubicSpline,
                    Checked::Invalid => {
                        return Err(at(format!("{sp}/interpolation"), "unknown interpolation"))
                    }
                };
                let ia = smp.input.value();
                let input: Vec<f64> = r
                    .read_floats(ia, Type::Scalar, &format!("{sp}/input"))?
                    .iter()
                    .map(|&x| f64::from(x))
                    .collect();
                // Spec 3.11: key times are strictly increasing.
                if let Some(k) = input.windows(2).position(|w| w[1] <= w[0]) {
                    return Err(at(
                        format!("/accessors/{ia}"),
                        format!(
                            "sampler input (at {sp}/input) must be strictly increasing: key {} at {} s follows {} s",
                            k + 1,
                            input[k + 1],
                            input[k]
                        ),
                    ));
                }
                let (ty, comps): (Type, &[ComponentType]) = match tpath {
                    TargetPath::Rotation => (
                        Type::Vec4,
                        &[
                            ComponentType::F32,
                            ComponentType::I8,
                            ComponentType::U8,
                            ComponentType::I16,
                            ComponentType::U16,
                        ],
                    ),
                    _ => (Type::Vec3, &[ComponentType::F32]),
                };
                let output = read_numbers(
                    r,
                    root,
                    smp.output.value(),
                    ty,
                    comps,
                    &format!("{sp}/output"),
                )?;
                let per_key = tpath.components()
                    * if interpolation == Interpolation::CubicSpline {
                        3
                    } else {
                        1
                    };
                if Some(output.len()) != input.len().checked_mul(per_key) {
                    return Err(at(
                        format!("{sp}/output"),
                        format!(
                            "{} output elements for {} keys; {interpolation:?} needs {} per key",
                            output.len() / tpath.components(),
                            input.len(),
                            per_key / tpath.components()
                        ),
                    ));
                }
                if interpolation == Interpolation::CubicSpline && input.len() < 2 {
                    return Err(at(sp, "CUBICSPLINE needs at least 2 keys"));
                }
                out.samplers.push(Sampler {
                    input,
                    output,
                    interpolation,
                });
                map[s] = Some(out.samplers.len() - 1);
                out.samplers.len() - 1
            }
        };
        out.channels.push(Channel {
            node,
            path: tpath,
            sampler,
        });
    }
    if weights_channels > 0 {
        notes.push(format!(
            "{path}: {weights_channels} morph target weights channels ignored"
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::NoResources;
    use base64::Engine;
    use serde_json::json;

    #[test]
    fn normalized_components() {
        assert_eq!(component_value(255, ComponentType::U8), 1.0);
        assert_eq!(component_value(65535, ComponentType::U16), 1.0);
        assert_eq!(component_value(0x80, ComponentType::I8), -1.0);
        assert_eq!(component_value(0x7FFF, ComponentType::I16), 1.0);
        assert_eq!(component_value(1.5f32.to_bits(), ComponentType::F32), 1.5);
    }

    /// One unindexed triangle skinned to one joint with u8 weights `w`.
    fn tri(w: [u8; 4], normalized: bool) -> Vec<u8> {
        let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        bin.extend([0u8; 12]); // JOINTS_0, u8 VEC4
        for _ in 0..3 {
            bin.extend(w);
        }
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        serde_json::to_vec(&json!({
            "asset": { "version": "2.0" },
            "nodes": [ { "mesh": 0, "skin": 0 }, { "translation": [0.0, 0.0, 2.0] } ],
            "skins": [ { "joints": [1] } ],
            "meshes": [ { "primitives": [ { "attributes": { "POSITION": 0, "JOINTS_0": 1, "WEIGHTS_0": 2 } } ] } ],
            "buffers": [ { "byteLength": bin.len(), "uri": uri } ],
            "bufferViews": [ { "buffer": 0, "byteLength": bin.len() } ],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3" },
                { "bufferView": 0, "byteOffset": 36, "componentType": 5121, "count": 3, "type": "VEC4" },
                { "bufferView": 0, "byteOffset": 48, "componentType": 5121, "normalized": normalized, "count": 3, "type": "VEC4" },
            ],
        }))
        .unwrap()
    }

    #[test]
    fn normalized_u8_weights_and_identity_bind() {
        // No inverseBindMatrices: identity, so the joint's translation moves the triangle.
        let c = decode_character(&tri([200, 0, 0, 0], true), &NoResources).unwrap();
        assert_eq!(c.meshes[0].triangles, vec![[0, 1, 2]]);
        assert_eq!(c.meshes[0].weights[..4], [1.0, 0.0, 0.0, 0.0]);
        assert!(c.notes.iter().any(|n| n.contains("renormalised")));
        assert_eq!(c.skinned_positions(None, 0.0)[1], [1.0, 0.0, 2.0]);
        let e = decode_character(&tri([255, 0, 0, 0], false), &NoResources).unwrap_err();
        assert!(e.message.contains("normalized"), "{e}");
        let e = decode_character(&tri([0; 4], true), &NoResources).unwrap_err();
        assert!(e.message.contains("all skin weights are 0"), "{e}");
    }
}
