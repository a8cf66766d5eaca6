//! Skinning and animation: glTF characters from the shared data (anim/) and a
//! hand-made two-joint bar.

mod common;

use std::path::PathBuf;

use base64::Engine;
use knitvox::anim::{
    Animation, Channel, Character, CharacterMesh, Interpolation, LocalTransform, Mat4, Node,
    Sampler, Skin, TargetPath,
};
use knitvox::io::gltf_skin::{decode_character, read_character};
use knitvox::io::{Location, NoResources};
use serde_json::{json, Value};

fn anim_file(name: &str) -> Option<PathBuf> {
    common::external_data("anim").map(|d| d.join(name))
}

fn bbox(p: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for q in p {
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    (lo, hi)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn fox_joints_animations_and_bind_pose() {
    let Some(path) = anim_file("Fox.glb") else {
        return;
    };
    let c = read_character(&path).unwrap();
    assert_eq!(c.skins.len(), 1);
    assert_eq!(c.skins[0].joints.len(), 24);
    assert_eq!(c.animation_names(), ["Survey", "Walk", "Run"]);
    // Durations: the `max` of each animation's (single) sampler input accessor in
    // Fox.glb's JSON chunk, read with python3's json module (f32 values as printed).
    for (a, want) in [
        (0, 3.4166667461395264),
        (1, 0.7083333134651184),
        (2, 1.1583333015441895),
    ] {
        assert!(
            (c.duration(a) - want).abs() < 1e-12,
            "{a}: {}",
            c.duration(a)
        );
    }
    // Bind pose: with the joints at their rest TRS, world(joint) * invBind is the
    // identity up to f32 rounding for Fox, so skinning reproduces POSITION.
    assert_eq!(c.meshes.len(), 1);
    let bind = &c.meshes[0].positions;
    let posed = c.skinned_positions(None, 0.0);
    assert_eq!(posed.len(), bind.len());
    let (lo, hi) = bbox(bind);
    let diag = dist(lo, hi);
    let worst = bind
        .iter()
        .zip(&posed)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-4 * diag,
        "bind pose moved a vertex by {worst} (bbox diagonal {diag})"
    );
    // Animated frames move the body but keep it finite and about the same size.
    let walk = c.animation_index("Walk").unwrap();
    let m = c.body_mesh(Some(walk), 0.3);
    assert_eq!(m.triangles.len(), c.meshes[0].triangles.len());
    assert!(m.positions.iter().flatten().all(|x| x.is_finite()));
    let moved = bind
        .iter()
        .zip(&m.positions)
        .map(|(a, b)| dist(*a, *b))
        .fold(0.0, f64::max);
    assert!(moved > 1e-3 * diag && moved < diag, "{moved} vs {diag}");
}

#[test]
fn cesium_man_walks_at_human_size() {
    let Some(path) = anim_file("CesiumMan_lab0copy.glb") else {
        return;
    };
    let c = read_character(&path).unwrap();
    assert_eq!(c.skins[0].joints.len(), 19);
    assert_eq!(c.animations.len(), 1);
    // The max of the 19 sampler inputs is 2 (python3 json on the GLB JSON chunk;
    // the keys start at 0.0417 s, the first frame of 24 fps).
    assert_eq!(c.duration(0), 2.0);
    for t in [0.0, 0.5, 1.0, 1.37, 2.0, 3.0] {
        let p = c.skinned_positions(Some(0), t);
        assert!(p.iter().flatten().all(|x| x.is_finite()), "t = {t}");
        let (lo, hi) = bbox(&p);
        let size = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        // Metres; the joint hierarchy's root rotates the Z-up rig to glTF's +Y up,
        // so the height is along y: about 1.5 m.
        assert!(size[1] > 1.3 && size[1] < 2.0, "t = {t}: size {size:?}");
        assert!(size[0] < 1.2 && size[2] < 1.2, "t = {t}: size {size:?}");
    }
}

/// Expected skinned position in the SimpleSkin files, by hand: both joints'
/// inverse bind matrices translate by `ibm_t`, joint 0 sits at (0, 1, 0) and
/// joint 1 is its child at its origin, rotated by `theta` about z. So joint 0
/// maps v to v + ibm_t + (0, 1, 0) and joint 1 to R(theta) (v + ibm_t) + (0, 1, 0).
fn simple_skin_expected(v: [f64; 3], w: [f64; 2], ibm_t: [f64; 3], theta: f64) -> [f64; 3] {
    let l = [v[0] + ibm_t[0], v[1] + ibm_t[1], v[2] + ibm_t[2]];
    let j0 = [l[0], l[1] + 1.0, l[2]];
    let (s, c) = theta.sin_cos();
    let j1 = [c * l[0] - s * l[1], s * l[0] + c * l[1] + 1.0, l[2]];
    [0, 1, 2].map(|k| w[0] * j0[k] + w[1] * j1[k])
}

fn check_simple_skin(name: &str, ibm_t: [f64; 3]) {
    let Some(path) = anim_file(name) else {
        return;
    };
    let c = read_character(&path).unwrap();
    assert_eq!(c.skins[0].joints.len(), 2, "{name}");
    assert_eq!(c.duration(0), 5.5);
    let mesh = &c.meshes[0];
    // Keys (file): t = 0 identity; t = 1.0 quaternion (0, 0, 0.707, 0.707), i.e.
    // 90 degrees about z; t = 0.25 halfway to (0, 0, 0.383, 0.924) (22.5 deg).
    let q1: f64 = 0.707f32.into();
    let theta1 = 2.0 * q1.atan2(q1);
    let theta_half = 2.0 * f64::from(0.383f32).atan2(f64::from(0.924f32));
    for (t, theta) in [(0.0, 0.0), (1.0, theta1), (0.25, theta_half / 2.0)] {
        let p = c.skinned_positions(Some(0), t);
        for (v, q) in p.iter().enumerate() {
            // Weights from the file: (1 - y/2, y/2) for a vertex at height y
            // (Khronos file; assimp's mesh is the same shifted by +0.5 in x).
            let y = mesh.positions[v][1];
            let w = [1.0 - y / 2.0, y / 2.0];
            let want = simple_skin_expected(mesh.positions[v], w, ibm_t, theta);
            assert!(
                dist(*q, want) < 1e-6,
                "{name} t={t} vertex {v}: {q:?} != {want:?}"
            );
        }
    }
    // The top right vertex (weight 1 on joint 1) sits 1 above and 0.5 right of the
    // joint at (0, 1) in bind pose; turned 90 degrees it is 1 left and 0.5 up.
    let top = c.skinned_positions(Some(0), 1.0)[9];
    assert!(dist(top, [-1.0, 1.5, 0.0]) < 1e-6, "{name}: {top:?}");
}

#[test]
fn khronos_simple_skin_by_hand() {
    // inverseBindMatrices of both joints: translation (0, -1, 0).
    check_simple_skin("Khronos_SimpleSkin_glTF-Embedded.gltf", [0.0, -1.0, 0.0]);
}

#[test]
fn assimp_simple_skin_by_hand() {
    // inverseBindMatrices: translation (-0.5, -1, 0); its mesh is x in [0, 1], so the
    // bind pose shifts it by -0.5 in x (the mesh node, root of the joints, is identity).
    check_simple_skin("assimp_simple_skin.gltf", [-0.5, -1.0, 0.0]);
}

// ---------------------------------------------------------------------------
// Hand-made two-joint bar
// ---------------------------------------------------------------------------

const H: f64 = std::f64::consts::FRAC_1_SQRT_2;

fn bar(interpolation: Interpolation) -> Character {
    let mut positions = Vec::new();
    for k in 0..=4 {
        for x in [-0.1, 0.1] {
            positions.push([x, 0.5 * k as f64, 0.0]);
        }
    }
    let mut joints = Vec::new();
    let mut weights = Vec::new();
    for p in &positions {
        let j = u32::from(p[1] > 1.0);
        joints.extend([j, 0, 0, 0]);
        weights.extend([1.0, 0.0, 0.0, 0.0]);
    }
    let (input, output) = match interpolation {
        Interpolation::CubicSpline => (
            vec![0.0, 1.0],
            [
                [0.0; 4],
                [0.0, 0.0, 0.0, 1.0],
                [0.0; 4],
                [0.0; 4],
                [0.0, 0.0, H, H],
                [0.0; 4],
            ]
            .concat(),
        ),
        _ => (vec![0.0, 1.0], vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, H, H]),
    };
    Character {
        meshes: vec![CharacterMesh {
            node: 2,
            skin: Some(0),
            positions,
            triangles: (0..4)
                .flat_map(|k| {
                    [
                        [2 * k, 2 * k + 1, 2 * k + 2],
                        [2 * k + 1, 2 * k + 3, 2 * k + 2],
                    ]
                })
                .collect(),
            influences: 4,
            joints,
            weights,
        }],
        skeleton: vec![
            Node::default(),
            Node {
                name: Some("joint1".into()),
                parent: Some(0),
                rest: LocalTransform::Trs {
                    translation: [0.0, 1.0, 0.0],
                    rotation: [0.0, 0.0, 0.0, 1.0],
                    scale: [1.0; 3],
                },
            },
            // The mesh node, far away: a skinned mesh ignores its transform.
            Node {
                name: None,
                parent: None,
                rest: LocalTransform::Matrix(Mat4::new_translation(&[100.0, 0.0, 0.0].into())),
            },
        ],
        skins: vec![Skin {
            joints: vec![0, 1],
            inverse_bind: vec![
                Mat4::identity(),
                Mat4::new_translation(&[0.0, -1.0, 0.0].into()),
            ],
        }],
        animations: vec![Animation {
            name: Some("bend".into()),
            channels: vec![Channel {
                node: 1,
                path: TargetPath::Rotation,
                sampler: 0,
            }],
            samplers: vec![Sampler {
                input,
                output,
                interpolation,
            }],
        }],
        notes: vec![],
    }
}

/// Vertices above y = 1 rotated by `theta` about z around (0, 1, 0); the rest fixed.
fn bar_expected(c: &Character, theta: f64) -> Vec<[f64; 3]> {
    let (s, co) = theta.sin_cos();
    c.meshes[0]
        .positions
        .iter()
        .map(|p| {
            if p[1] > 1.0 {
                let (x, y) = (p[0], p[1] - 1.0);
                [co * x - s * y, s * x + co * y + 1.0, p[2]]
            } else {
                *p
            }
        })
        .collect()
}

fn assert_close(a: &[[f64; 3]], b: &[[f64; 3]], tol: f64, what: &str) {
    assert_eq!(a.len(), b.len());
    for (v, (p, q)) in a.iter().zip(b).enumerate() {
        assert!(dist(*p, *q) < tol, "{what}: vertex {v}: {p:?} != {q:?}");
    }
}

#[test]
fn bar_linear_slerp() {
    let c = bar(Interpolation::Linear);
    c.validate().unwrap();
    let q = std::f64::consts::FRAC_PI_2;
    assert_close(
        &c.skinned_positions(None, 0.0),
        &c.meshes[0].positions,
        1e-12,
        "bind",
    );
    assert_close(
        &c.skinned_positions(Some(0), 0.0),
        &c.meshes[0].positions,
        1e-12,
        "t=0",
    );
    assert_close(
        &c.skinned_positions(Some(0), 1.0),
        &bar_expected(&c, q),
        1e-12,
        "t=1",
    );
    assert_close(
        &c.skinned_positions(Some(0), 7.0),
        &bar_expected(&c, q),
        1e-12,
        "t>end",
    );
    // Slerp: half-way in time is half the angle.
    assert_close(
        &c.skinned_positions(Some(0), 0.5),
        &bar_expected(&c, q / 2.0),
        1e-12,
        "t=0.5",
    );
    assert_close(
        &c.skinned_positions(Some(0), 0.25),
        &bar_expected(&c, q / 4.0),
        1e-12,
        "t=0.25",
    );
    // The joint's world matrix agrees.
    let w = c.node_world_matrices(Some(0), 1.0);
    let o = w[1] * nalgebra::Vector4::new(1.0, 0.0, 0.0, 1.0);
    assert!((o.x).abs() < 1e-12 && (o.y - 2.0).abs() < 1e-12, "{o:?}");
    let m = c.body_mesh(Some(0), 1.0);
    assert_eq!(m.triangles.len(), 8);
}

#[test]
fn bar_step_holds_until_the_key() {
    let c = bar(Interpolation::Step);
    c.validate().unwrap();
    let bind = &c.meshes[0].positions;
    for t in [0.0, 0.5, 0.999] {
        assert_close(
            &c.skinned_positions(Some(0), t),
            bind,
            1e-12,
            "step before key",
        );
    }
    let q = std::f64::consts::FRAC_PI_2;
    assert_close(
        &c.skinned_positions(Some(0), 1.0),
        &bar_expected(&c, q),
        1e-12,
        "step at key",
    );
}

#[test]
fn bar_cubic_zero_tangents_passes_through_keys() {
    let c = bar(Interpolation::CubicSpline);
    c.validate().unwrap();
    let q = std::f64::consts::FRAC_PI_2;
    assert_close(
        &c.skinned_positions(Some(0), 0.0),
        &c.meshes[0].positions,
        1e-12,
        "key 0",
    );
    assert_close(
        &c.skinned_positions(Some(0), 1.0),
        &bar_expected(&c, q),
        1e-12,
        "key 1",
    );
    // Zero tangents, symmetric: the midpoint is the normalised mean quaternion (45 deg).
    assert_close(
        &c.skinned_positions(Some(0), 0.5),
        &bar_expected(&c, q / 2.0),
        1e-12,
        "mid",
    );
}

#[test]
fn hand_made_broken_characters() {
    let mut c = bar(Interpolation::Linear);
    c.meshes[0].joints[12] = 2;
    let e = c.validate().unwrap_err();
    assert!(e.message.contains("joint index 2 is out of range"), "{e}");
    let mut c = bar(Interpolation::Linear);
    c.animations[0].samplers[0].input = vec![1.0, 1.0];
    let e = c.validate().unwrap_err();
    assert!(e.message.contains("strictly increasing"), "{e}");
    let mut c = bar(Interpolation::Linear);
    c.animations[0].samplers[0].output.pop();
    let e = c.validate().unwrap_err();
    assert_eq!(e.path, "/animations/0/samplers/0/output", "{e}");
    // Evaluation of the broken character still does not panic.
    assert_eq!(c.skinned_positions(Some(0), 0.5).len(), 10);
    let mut c = bar(Interpolation::Linear);
    c.skins[0].inverse_bind[1][(1, 3)] = f64::NAN;
    let e = c.validate().unwrap_err();
    assert!(e.path.starts_with("/skins/0/inverseBindMatrices/1"), "{e}");
}

// ---------------------------------------------------------------------------
// Broken files
// ---------------------------------------------------------------------------

fn simple_skin_json() -> Option<Value> {
    let path = anim_file("Khronos_SimpleSkin_glTF-Embedded.gltf")?;
    Some(serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap())
}

/// Overwrites float component `comp` of element `elem` of accessor `a` in the
/// base64-embedded buffer.
fn patch_float(doc: &mut Value, a: usize, elem: usize, comp: usize, x: f32) {
    let acc = &doc["accessors"][a];
    let n = match acc["type"].as_str().unwrap() {
        "SCALAR" => 1,
        "VEC3" => 3,
        "VEC4" => 4,
        "MAT4" => 16,
        t => panic!("{t}"),
    };
    let view = &doc["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
    let stride = view["byteStride"].as_u64().unwrap_or(4 * n) as usize;
    let off = view["byteOffset"].as_u64().unwrap_or(0) as usize
        + acc["byteOffset"].as_u64().unwrap_or(0) as usize
        + elem * stride
        + comp * 4;
    let b = view["buffer"].as_u64().unwrap() as usize;
    let uri = doc["buffers"][b]["uri"].as_str().unwrap().to_string();
    let (head, b64) = uri.split_once(',').unwrap();
    let mut bytes = base64::engine::general_purpose::STANDARD
        .decode(b64)
        .unwrap();
    bytes[off..off + 4].copy_from_slice(&x.to_le_bytes());
    doc["buffers"][b]["uri"] = json!(format!(
        "{head},{}",
        base64::engine::general_purpose::STANDARD.encode(&bytes)
    ));
}

fn decode_err(doc: &Value) -> knitvox::io::FormatError {
    decode_character(&serde_json::to_vec(doc).unwrap(), &NoResources).unwrap_err()
}

#[test]
fn broken_files_give_clear_errors() {
    let Some(good) = simple_skin_json() else {
        return;
    };
    decode_character(&serde_json::to_vec(&good).unwrap(), &NoResources).unwrap();
    // Joint index out of range: the skin keeps only its first joint.
    let mut d = good.clone();
    d["skins"][0]["joints"] = json!([1]);
    let e = decode_err(&d);
    assert_eq!(
        e.location,
        Location::Path("/meshes/0/primitives/0/attributes/JOINTS_0".into())
    );
    assert!(e.message.contains("joint index 1 is out of range"), "{e}");
    // Sampler input not increasing.
    let input = good["animations"][0]["samplers"][0]["input"]
        .as_u64()
        .unwrap() as usize;
    let mut d = good.clone();
    patch_float(&mut d, input, 3, 0, 0.25);
    let e = decode_err(&d);
    assert_eq!(e.location, Location::Path(format!("/accessors/{input}")));
    assert!(e.message.contains("strictly increasing"), "{e}");
    // Output count mismatch.
    let output = good["animations"][0]["samplers"][0]["output"]
        .as_u64()
        .unwrap() as usize;
    let mut d = good.clone();
    d["accessors"][output]["count"] = json!(11);
    let e = decode_err(&d);
    assert_eq!(
        e.location,
        Location::Path("/animations/0/samplers/0/output".into())
    );
    assert!(e.message.contains("11 output elements for 12 keys"), "{e}");
    // CUBICSPLINE with LINEAR-sized output.
    let mut d = good.clone();
    d["animations"][0]["samplers"][0]["interpolation"] = json!("CUBICSPLINE");
    assert!(decode_err(&d).message.contains("needs 3 per key"));
    // NaN in an inverse bind matrix.
    let ibm = good["skins"][0]["inverseBindMatrices"].as_u64().unwrap() as usize;
    let mut d = good.clone();
    patch_float(&mut d, ibm, 1, 13, f32::NAN);
    let e = decode_err(&d);
    assert_eq!(e.location, Location::Path(format!("/accessors/{ibm}")));
    assert!(e.message.contains("not finite"), "{e}");
    // Infinite node translation (1e39 does not fit an f32).
    let mut d = good.clone();
    d["nodes"][1]["translation"] = json!([0.0, 1e39, 0.0]);
    let e = decode_err(&d);
    assert_eq!(
        e.location,
        Location::Path("/nodes/1/translation/1".into()),
        "{e}"
    );
    // A node with two parents, a channel on a missing node, an unknown skin.
    let mut d = good.clone();
    d["nodes"][0]["children"] = json!([2]);
    assert!(decode_err(&d).message.contains("at most one parent"));
    let mut d = good.clone();
    d["animations"][0]["channels"][0]["target"]["node"] = json!(7);
    assert_eq!(
        decode_err(&d).location,
        Location::Path("/animations/0/channels/0/target/node".into())
    );
    let mut d = good.clone();
    d["nodes"][0]["skin"] = json!(3);
    assert_eq!(
        decode_err(&d).location,
        Location::Path("/nodes/0/skin".into())
    );
    // Weights not summing to 1 are renormalised, with a note.
    let weights = good["meshes"][0]["primitives"][0]["attributes"]["WEIGHTS_0"]
        .as_u64()
        .unwrap() as usize;
    let mut d = good.clone();
    patch_float(&mut d, weights, 0, 0, 2.0);
    let c = decode_character(&serde_json::to_vec(&d).unwrap(), &NoResources).unwrap();
    assert!(
        c.notes.iter().any(|n| n.contains("renormalised")),
        "{:?}",
        c.notes
    );
    assert_eq!(c.meshes[0].weights[0], 1.0);
    // Empty and non-glTF input.
    assert!(decode_character(b"", &NoResources).is_err());
    assert!(decode_character(b"\xff\xfe not json", &NoResources).is_err());
}

#[test]
fn truncated_glb_never_panics() {
    let Some(path) = anim_file("Fox.glb") else {
        return;
    };
    let data = std::fs::read(path).unwrap();
    let mut lens: Vec<usize> = (0..64).collect();
    lens.extend((64..data.len()).step_by(997));
    for n in lens {
        assert!(
            decode_character(&data[..n], &NoResources).is_err(),
            "prefix {n}"
        );
    }
    // Flipped bytes across the file: Err or Ok, never a panic.
    for k in (0..data.len()).step_by(1009) {
        let mut d = data.clone();
        d[k] ^= 0xA5;
        let _ = decode_character(&d, &NoResources);
    }
}
