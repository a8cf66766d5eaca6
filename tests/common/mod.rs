//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

pub mod daemon;
pub mod job;
pub mod mutate;

/// The external test data folder (`$KNITVOX_EXTERNAL_DATA`, else `../shared/data`
/// beside the checkout) joined with `sub`. Under CI (`CI` set) a missing folder
/// fails the test; elsewhere the test is skipped with a loud message.
pub fn external_data(sub: &str) -> Option<PathBuf> {
    let root = std::env::var_os("KNITVOX_EXTERNAL_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let dir = root.join(sub);
    if dir.is_dir() {
        return Some(dir);
    }
    let msg = format!(
        "external test data not found at {} (set KNITVOX_EXTERNAL_DATA to the shared data folder)",
        dir.display()
    );
    if std::env::var_os("CI").is_some() {
        panic!("{msg}");
    }
    eprintln!("\n!!!!!!!! SKIPPED: {msg} !!!!!!!!\n");
    None
}

/// Requires an external tool (node, python3 with h5py). Under CI its absence
/// fails the test; elsewhere the test is skipped loudly.
pub fn require_tool(available: bool, what: &str) -> bool {
    if available {
        return true;
    }
    let msg = format!("{what} is not available (run `bash .ci/setup-debian test`)");
    if std::env::var_os("CI").is_some() {
        panic!("{msg}");
    }
    eprintln!("\n!!!!!!!! SKIPPED: {msg} !!!!!!!!\n");
    false
}

/// Path of the built knitvox binary (for tests that run the real CLI).
pub fn knitvox_bin() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_knitvox"))
}

/// Slope of the friction scene of [`slide_on_incline`] (degrees): tan 20° =
/// 0.364.
pub const SLOPE_DEG: f64 = 20.0;

/// The friction-on-a-slope scene: a 3 x 2 x 3 cm block (1 cm Kuhn voxels, 200
/// kg/m³, 1e4 Pa) placed at rest on a plane through the origin tilted
/// [`SLOPE_DEG`] about z (downhill: +x), Coulomb coefficient `mu`, `steps`
/// steps of 1/150 s under gravity; `attach` may swap the solver's backend.
/// Returns the largest node displacement (m), the mass-weighted mean
/// displacement downhill (m) and the final positions.
pub fn slide_on_incline(
    mu: f64,
    global: knitvox::sim::pd::GlobalSolver,
    steps: usize,
    attach: &dyn Fn(&mut knitvox::sim::pd::PdSolver),
) -> (f64, f64, Vec<knitvox::geom::Vec3>) {
    use knitvox::embed::box_mesh;
    use knitvox::geom::Vec3;
    use knitvox::sim::collide::{Collider, ColliderSet, Shape};
    use knitvox::sim::pd::{PdParams, PdSolver};
    let (mesh, mass) = box_mesh([3, 2, 3], 0.01, 200.0);
    let nt = mesh.num_tets();
    let th = SLOPE_DEG.to_radians();
    let (c, s) = (th.cos(), th.sin());
    let normal = [s, c, 0.0];
    let thickness = 1e-3;
    // Rotate by -θ about z (the bottom face y = 0 then lies in the plane),
    // then lift by the thickness along the normal: touching, at rest.
    let x0: Vec<Vec3> = mesh
        .nodes
        .iter()
        .map(|p| {
            let r = [p[0] * c + p[1] * s, -p[0] * s + p[1] * c, p[2]];
            std::array::from_fn(|k| r[k] + thickness * normal[k])
        })
        .collect();
    let params = PdParams {
        global,
        ..Default::default()
    };
    let mut solver =
        PdSolver::new(&mesh, &mass, &vec![1e4; nt], &vec![1e4; nt], &[], params).unwrap();
    attach(&mut solver);
    let plane = ColliderSet {
        colliders: vec![Collider {
            shape: Shape::Plane {
                point: [0.0; 3],
                normal,
            },
            thickness,
        }],
        friction: mu,
    };
    let (mut x, mut v) = (x0.clone(), vec![[0.0; 3]; x0.len()]);
    for _ in 0..steps {
        solver
            .step_with_contacts(&mut x, &mut v, &[], &plane)
            .unwrap();
    }
    let d: Vec<Vec3> = x
        .iter()
        .zip(&x0)
        .map(|(a, b)| std::array::from_fn(|k| a[k] - b[k]))
        .collect();
    let largest = d
        .iter()
        .map(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt())
        .fold(0.0, f64::max);
    let total: f64 = mass.iter().sum();
    let along = d
        .iter()
        .zip(&mass)
        .map(|(u, m)| m * (u[0] * c - u[1] * s))
        .sum::<f64>()
        / total;
    (largest, along, x)
}

/// A flat swatch of the built-in `pattern`, `courses` x `wales`, laid out
/// as one yarn (the generator's default parameters).
pub fn flat_swatch(pattern: &str, courses: usize, wales: usize) -> knitvox::geom::Yarns {
    use knitvox::yarn::pattern::{build_tile, builtin, lay_out, Layout, PatternParams};
    let tile = build_tile(&builtin(pattern).unwrap(), &PatternParams::default()).unwrap();
    lay_out(
        &tile,
        &Layout {
            courses,
            wales,
            tube_radius: None,
            helix: false,
            separate_courses: false,
        },
    )
    .unwrap()
}

/// Whether python3 with h5py and numpy runs (under CI its absence fails).
pub fn have_h5py() -> bool {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import h5py, numpy"])
        .status()
        .is_ok_and(|s| s.success());
    require_tool(ok, "python3 with h5py")
}

/// Runs a Python script in `dir`; a failing script fails the test.
pub fn python(dir: &std::path::Path, script: &str) {
    let o = std::process::Command::new("python3")
        .args(["-c", script])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Every file under `dir` (relative path -> bytes), for comparing a run's
/// outputs with another's.
pub fn files_under(dir: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    fn walk(base: &Path, d: &Path, m: &mut std::collections::BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, m);
            } else {
                m.insert(
                    p.strip_prefix(base).unwrap().into(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    let mut m = Default::default();
    walk(dir, dir, &mut m);
    m
}

/// splitmix64: a tiny deterministic generator.
pub struct Rng(pub u64);

impl Rng {
    /// Uniform in [0, 1).
    pub fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [-1, 1).
    pub fn sym(&mut self) -> f64 {
        2.0 * self.next() - 1.0
    }
    /// Components uniform in [-1, 1).
    pub fn vec(&mut self) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::new(self.sym(), self.sym(), self.sym())
    }
    /// Entries uniform in [-1, 1).
    pub fn mat(&mut self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::from_fn(|_, _| self.sym())
    }
    /// A rotation about a random axis by up to ~5 rad.
    pub fn rotation(&mut self) -> nalgebra::Matrix3<f64> {
        nalgebra::Rotation3::new(self.vec() * 3.0).into_inner()
    }
}

/// Opens an HDF5 file read-write to edit it, without libhdf5's file lock:
/// libhdf5 opens its descriptor without O_CLOEXEC, so a child process that
/// another test spawns meanwhile inherits it and keeps the lock after the
/// edit, and the next read of the file reports it busy (seen as rare
/// failures of the corrupting tests).
pub fn h5_edit(path: &Path) -> hdf5::File {
    hdf5::File::with_options()
        .with_fapl(|p| p.file_locking(false))
        .open_rw(path)
        .unwrap()
}

/// `knitvox pattern PATTERN --courses N --wales N` (relaxed into contact,
/// with its rod rest shape, lying flat in XZ) embedded with the defaults:
/// the asset `dir/NAME.vtkhdf` (its yarns beside it as `NAME.h5`).
pub fn embedded_pattern(
    dir: &Path,
    name: &str,
    pattern: &str,
    courses: usize,
    wales: usize,
) -> PathBuf {
    let sw = dir.join(format!("{name}.h5"));
    let asset = dir.join(format!("{name}.vtkhdf"));
    let (c, w) = (courses.to_string(), wales.to_string());
    for args in [
        vec![
            "pattern",
            pattern,
            "--courses",
            &c,
            "--wales",
            &w,
            "-o",
            sw.to_str().unwrap(),
        ],
        vec!["embed", sw.to_str().unwrap(), "-o", asset.to_str().unwrap()],
    ] {
        let o = std::process::Command::new(knitvox_bin())
            .args(&args)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    asset
}

/// Embedded contact points of a mesh: `points` located in `mesh`'s tets
/// (the first tet whose barycentric weights are all >= -1e-12), each
/// standing for an equal share of `total_mass` (kg). Panics on a point
/// outside the mesh (a test's own setup).
pub fn embed_points(
    mesh: &knitvox::geom::TetMesh,
    points: &[knitvox::geom::Vec3],
    total_mass: f64,
) -> knitvox::sim::contact::EmbeddedPoints {
    use knitvox::sim::contact::EmbeddedPoints;
    let mut e = EmbeddedPoints::default();
    for p in points {
        let (ids, w) = mesh
            .tets
            .iter()
            .find_map(|t| {
                let x: Vec<_> = t.iter().map(|&i| mesh.nodes[i as usize]).collect();
                let w = barycentric(&x, *p)?;
                w.iter().all(|&c| c >= -1e-12).then_some((*t, w))
            })
            .unwrap_or_else(|| panic!("point {p:?} is outside the mesh"));
        e.nodes.push(ids);
        e.weights.push(w.map(|c| c.max(0.0)));
        e.mass.push(total_mass / points.len() as f64);
    }
    e
}

/// Barycentric weights of `p` in the tet `x` (4 corners), None when flat.
fn barycentric(x: &[knitvox::geom::Vec3], p: knitvox::geom::Vec3) -> Option<[f64; 4]> {
    let e: Vec<[f64; 3]> = (1..4)
        .map(|a| std::array::from_fn(|k| x[a][k] - x[0][k]))
        .collect();
    let r: [f64; 3] = std::array::from_fn(|k| p[k] - x[0][k]);
    let det3 = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
        a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0])
    };
    let d = det3(e[0], e[1], e[2]);
    if d.abs() < 1e-300 {
        return None;
    }
    let l1 = det3(r, e[1], e[2]) / d;
    let l2 = det3(e[0], r, e[2]) / d;
    let l3 = det3(e[0], e[1], r) / d;
    Some([1.0 - l1 - l2 - l3, l1, l2, l3])
}

/// What [`slide_points_on_incline`] measured.
pub struct PointSlide {
    /// Largest displacement of a contact point (m).
    pub largest: f64,
    /// Mean displacement of the points downhill (m).
    pub along: f64,
    /// Smallest and largest signed distance of a bottom-layer point from
    /// the plane at the end, minus its radius (m): 0 is touching.
    pub gap: [f64; 2],
    /// Smallest signed distance of a node from the plane at the end (m).
    pub lowest_node: f64,
}

/// The friction-on-a-slope scene of [`slide_on_incline`] with the contact
/// acting on embedded points instead of on the nodes: the block's yarns
/// stand in as a 5 x 2 x 5 grid of points in each of its two layers of
/// voxels, at a quarter and three quarters of each voxel's height
/// (2.5 mm above the bottom face), each keeping a radius of 1 mm from the
/// plane; the block starts with its lowest points touching. The bottom
/// nodes then lie 1.5 mm inside the plane.
pub fn slide_points_on_incline(mu: f64, steps: usize) -> PointSlide {
    slide_points_on_incline_at(mu, steps, knitvox::sim::pd::PdParams::default().dt)
}

/// [`slide_points_on_incline`] with steps of `dt` (s).
pub fn slide_points_on_incline_at(mu: f64, steps: usize, dt: f64) -> PointSlide {
    use knitvox::embed::box_mesh;
    use knitvox::geom::Vec3;
    use knitvox::sim::contact::{Contact, PointProjector};
    use knitvox::sim::pd::{PdParams, PdSolver};
    let (mesh, mass) = box_mesh([3, 2, 3], 0.01, 200.0);
    let nt = mesh.num_tets();
    let th = SLOPE_DEG.to_radians();
    let (c, s) = (th.cos(), th.sin());
    let normal = [s, c, 0.0];
    let radius = 1e-3;
    let lift = radius - 2.5e-3;
    let place = |p: &Vec3| -> Vec3 {
        let r = [p[0] * c + p[1] * s, -p[0] * s + p[1] * c, p[2]];
        std::array::from_fn(|k| r[k] + lift * normal[k])
    };
    // Points in the rest block, then the block placed on the slope.
    let mut rest_points = Vec::new();
    for i in 0..5 {
        for j in 0..4 {
            for k in 0..5 {
                rest_points.push([
                    0.003 + 0.006 * i as f64,
                    0.0025 + 0.005 * j as f64,
                    0.003 + 0.006 * k as f64,
                ]);
            }
        }
    }
    let total: f64 = mass.iter().sum();
    let points = embed_points(&mesh, &rest_points, total);
    let x0: Vec<Vec3> = mesh.nodes.iter().map(place).collect();
    let mut solver = PdSolver::new(
        &mesh,
        &mass,
        &vec![1e4; nt],
        &vec![1e4; nt],
        &[],
        PdParams {
            dt,
            ..PdParams::default()
        },
    )
    .unwrap();
    struct Slope {
        normal: Vec3,
        radius: f64,
        mu: f64,
    }
    impl PointProjector for Slope {
        fn contact(&self, _point: usize, p: Vec3) -> Option<Contact> {
            let d: f64 = (0..3).map(|k| p[k] * self.normal[k]).sum();
            (d < self.radius).then(|| Contact {
                target: std::array::from_fn(|k| p[k] + (self.radius - d) * self.normal[k]),
                surface_motion: [0.0; 3],
                friction: self.mu,
            })
        }
    }
    let slope = Slope { normal, radius, mu };
    let (mut x, mut v) = (x0.clone(), vec![[0.0; 3]; x0.len()]);
    for _ in 0..steps {
        solver
            .step_with_point_contacts(&mut x, &mut v, &[], &points, &slope)
            .unwrap();
    }
    let y0: Vec<Vec3> = (0..points.len()).map(|j| points.position(j, &x0)).collect();
    let y: Vec<Vec3> = (0..points.len()).map(|j| points.position(j, &x)).collect();
    let dot = |a: Vec3, b: Vec3| (0..3).map(|k| a[k] * b[k]).sum::<f64>();
    let d: Vec<Vec3> = y
        .iter()
        .zip(&y0)
        .map(|(a, b)| std::array::from_fn(|k| a[k] - b[k]))
        .collect();
    let largest = d.iter().map(|u| dot(*u, *u).sqrt()).fold(0.0, f64::max);
    let along = d.iter().map(|u| u[0] * c - u[1] * s).sum::<f64>() / d.len() as f64;
    // The bottom layer: points 0, 4, 8, ... (j = 0).
    let bottom: Vec<f64> = (0..points.len())
        .filter(|j| (j / 5) % 4 == 0)
        .map(|j| dot(y[j], normal) - radius)
        .collect();
    let gap = [
        bottom.iter().cloned().fold(f64::INFINITY, f64::min),
        bottom.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    ];
    let lowest_node = x
        .iter()
        .map(|p| dot(*p, normal))
        .fold(f64::INFINITY, f64::min);
    PointSlide {
        largest,
        along,
        gap,
        lowest_node,
    }
}
