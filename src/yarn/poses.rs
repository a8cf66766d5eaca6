//! Scripted boundary motions of a flat swatch: the deformations of the
//! yarn-level scenes (uniaxial, biaxial, shear) and the training poses of
//! VH §8.6 Fig. 19 (following the HYLC data protocol): bending about the
//! central axis and about the diagonal, a fan-like expansion, a twist into a
//! helix and a multi-folded bend, each with its mirrored counterpart.
//!
//! A pose clamps bands of vertices near the swatch's edges (or along lines
//! across it) and moves them along a prescribed map of the rest position and
//! the progress `s ∈ [0, 1]`; the interior is left to the simulator. The
//! progress ramps from 0 to 1 over the ramp time with a smoothstep, so the
//! handles start and stop without a velocity jump.
//!
//! Fabric frame: the swatch lies in the XZ plane with its normal along +Y
//! (the convention of knitvox's pattern generator and of the `.pyp` reader):
//! courses run along +X, wales along +Z. Extents come from the rest
//! bounding box.
//!
//! Pure: no files, no printing.

use crate::geom::Vec3;

/// The kind of scripted deformation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseKind {
    /// Uniaxial stretch along the courses (X): the left band is held, the
    /// right band moves by `amount · Lx` along +X (mirrored: the left band
    /// moves by `-amount · Lx`, the right one is held).
    StretchCourses,
    /// Uniaxial stretch along the wales (Z), as [`PoseKind::StretchCourses`].
    StretchWales,
    /// Biaxial stretch: all four edge bands scale by `1 + amount` in the
    /// fabric plane about the centre.
    Biaxial,
    /// Shear: the band at -Z is held, the band at +Z moves by
    /// `amount · Lz` along +X (mirrored: along -X).
    Shear,
    /// Bending about the central axis (parallel to Z) by a total angle
    /// `amount` (rad): the left and right bands follow the arc of radius
    /// `Lx / amount` curving toward +Y (mirrored: toward -Y).
    BendCentral,
    /// Bending about the diagonal axis: as [`PoseKind::BendCentral`] with
    /// the arc along the other diagonal; the two corner bands across it are
    /// clamped.
    BendDiagonal,
    /// Fan-like expansion: the band at -Z is held, the band at +Z spreads
    /// along X by `1 + amount` about the centre (mirrored: the +Z band is
    /// held and the -Z band spreads).
    Fan,
    /// Twist into a helix: the left band is held, the right band turns by
    /// `amount` (rad) about the X axis through the centre (mirrored: by
    /// `-amount`).
    Twist,
    /// Multi-folded bend: `folds + 1` bands across X at equal spacing move
    /// to a zigzag of alternating heights `±amount · Lx / folds`, pulled
    /// together so each fold keeps its rest length (mirrored: heights
    /// negated).
    MultiFold,
    /// Hanging: the two corner bands at +Z are held in place; gravity does
    /// the rest.
    Hang,
    /// Cantilever (the textile lab's Peirce bending test, ASTM D1388): the
    /// left band is held flat in place and the rest overhangs under
    /// gravity, so its droop measures the bending stiffness against the
    /// weight. `amount` is unused.
    Cantilever,
    /// No scripted motion (drape over a collider, or a collider-driven
    /// scene): nothing is clamped.
    Free,
}

impl PoseKind {
    /// Every kind, in documentation order.
    pub const ALL: [PoseKind; 12] = [
        PoseKind::StretchCourses,
        PoseKind::StretchWales,
        PoseKind::Biaxial,
        PoseKind::Shear,
        PoseKind::BendCentral,
        PoseKind::BendDiagonal,
        PoseKind::Fan,
        PoseKind::Twist,
        PoseKind::MultiFold,
        PoseKind::Hang,
        PoseKind::Cantilever,
        PoseKind::Free,
    ];
}

/// Most folds of a `MultiFold` pose (every fold is a band of handles).
pub const MAX_FOLDS: u32 = 10_000;

/// Parameters of a pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseParams {
    /// Which deformation.
    pub kind: PoseKind,
    /// Its magnitude: strain (dimensionless) for stretches, shear and fan,
    /// angle (rad) for bends and twist, fold height over fold length for the
    /// multi-fold (< 0.5). Unused by `Hang` and `Free`.
    pub amount: f64,
    /// Number of folds of `MultiFold` (1 to [`MAX_FOLDS`]). Default 3.
    pub folds: u32,
    /// The mirrored counterpart (VH Fig. 19 uses both). Default false.
    pub mirror: bool,
    /// Width of a clamped band as a fraction of the swatch extent across it
    /// (dimensionless, (0, 0.5); (0, 0.95) for `Cantilever`, whose one band
    /// sets the overhang). Default 0.06: about one stitch row on a
    /// 16-course swatch, enough to grip whole loops.
    pub band: f64,
    /// Time (s) over which the progress ramps from 0 to 1. Default 1.
    pub ramp: f64,
}

impl PoseParams {
    /// The bound `band` stays below: 0.5 where two bands face each other,
    /// 0.95 for `Cantilever`, whose one band sets the overhang.
    fn max_band(&self) -> f64 {
        if self.kind == PoseKind::Cantilever {
            0.95
        } else {
            0.5
        }
    }

    /// What is wrong with `band` (None: within (0, [`Self::max_band`])).
    pub fn band_error(&self) -> Option<String> {
        let max_band = self.max_band();
        (!(self.band > 0.0 && self.band < max_band))
            .then(|| format!("band is {} (must be in (0, {max_band}))", self.band))
    }

    /// Checks the parameters alone (amount, band, ramp, folds), before
    /// any swatch is built: a scene's count is refused at once.
    pub fn check(&self) -> Result<(), PoseError> {
        let p = self;
        let bad = |what: String| Err(PoseError::Parameter(what));
        if !p.amount.is_finite() {
            return bad(format!("amount is {}", p.amount));
        }
        if let Some(e) = p.band_error() {
            return bad(e);
        }
        if !(p.ramp.is_finite() && p.ramp >= 0.0) {
            return bad(format!("ramp is {} s (must be >= 0)", p.ramp));
        }
        match p.kind {
            PoseKind::MultiFold => {
                if p.folds == 0 || p.folds > MAX_FOLDS {
                    return bad(format!("folds is {} (must be 1 to {MAX_FOLDS})", p.folds));
                }
                if !(p.amount.abs() < 0.5) {
                    return bad(format!(
                        "amount is {} for multi_fold (fold height / fold length, must be < 0.5)",
                        p.amount
                    ));
                }
            }
            PoseKind::StretchCourses
            | PoseKind::StretchWales
            | PoseKind::Biaxial
            | PoseKind::Fan
                if p.amount <= -1.0 =>
            {
                return bad(format!("amount is {} (a strain must be > -1)", p.amount));
            }
            _ => {}
        }
        Ok(())
    }

    /// A pose of `kind` with `amount` and the other fields at their defaults.
    pub fn new(kind: PoseKind, amount: f64) -> PoseParams {
        PoseParams {
            kind,
            amount,
            folds: 3,
            mirror: false,
            band: 0.06,
            ramp: 1.0,
        }
    }
}

/// Errors of pose construction.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseError {
    #[error("pose parameter {0}")]
    Parameter(String),
    #[error("the rest state is degenerate: {0}")]
    Degenerate(String),
    /// A flat swatch that does not lie in the fabric frame's XZ plane.
    #[error("{0}")]
    Plane(String),
    /// A clamped band that holds too few vertices.
    #[error("{0}")]
    Band(String),
}

/// Fewest yarn vertices a clamped band must hold: a grip needs three points
/// off one line (a knit stitch has about 32 vertices; a coarse woven's band
/// holds one end per yarn), and a band that selects fewer is a band across
/// the wrong extent or too narrow for the swatch.
pub const MIN_BAND_VERTICES: usize = 3;

/// A swatch is flat when its thinnest bounding-box extent is under this
/// fraction of the middle one; a flat swatch must then lie in XZ.
pub const FLAT_RATIO: f64 = 0.5;

/// The schema name of a kind (`stretch_courses`, ...).
pub fn kind_name(kind: PoseKind) -> String {
    serde_json::to_value(kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_else(|| format!("{kind:?}"))
}

/// Refuses a flat swatch whose normal is not Y: its bands would select a
/// thin face instead of an edge, and gravity and the scenes' colliders
/// (a sphere under the swatch) would act along the fabric, also in a scene
/// that clamps nothing. Solid or curved bodies (a tube, a garment) are not
/// checked.
fn check_plane(b: &FabricBox, kind: PoseKind) -> Result<(), PoseError> {
    let e = [b.len(0), b.len(1), b.len(2)];
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| e[i].total_cmp(&e[j]));
    let (thin, mid) = (order[0], order[1]);
    if thin == 1 || !(e[thin] < FLAT_RATIO * e[mid]) {
        return Ok(());
    }
    let axis = ["X", "Y", "Z"][thin];
    let plane = if thin == 2 { "XY" } else { "YZ" };
    let fix = if thin == 2 {
        "read the yarns with `--up-axis z` (embed, yls, train, or `[garment] up_axis = \"z\"`), \
         which lays an XY swatch flat"
    } else {
        "turn the yarns into the XZ plane before embedding"
    };
    Err(PoseError::Plane(format!(
        "the {} pose needs a flat swatch lying in the XZ plane (normal +Y, the fabric frame \
         `knitvox pattern` writes), but this one lies in the {plane} plane: it is {:.4} m thin \
         along {axis} against {:.4} x {:.4} m, so bands would clamp a face and gravity \
         would act along the fabric; {fix}",
        kind_name(kind),
        e[thin],
        e[order[1]],
        e[order[2]]
    )))
}

/// The swatch's frame: centre and extents along X (courses) and Z (wales).
#[derive(Debug, Clone, Copy, PartialEq)]
struct FabricBox {
    min: Vec3,
    max: Vec3,
}

impl FabricBox {
    fn center(&self) -> Vec3 {
        std::array::from_fn(|k| 0.5 * (self.min[k] + self.max[k]))
    }
    fn len(&self, k: usize) -> f64 {
        self.max[k] - self.min[k]
    }
}

/// One group of clamped vertices moving under one map.
#[derive(Debug, Clone, PartialEq)]
struct Group {
    /// Index into [`PoseDriver::pinned`] of the group's first vertex.
    start: usize,
    /// Number of vertices.
    count: usize,
    /// The map's parameter (e.g. which edge, which fold line).
    role: Role,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Hold,
    /// Translate by `s · offset`.
    Translate(Vec3),
    /// Scale the in-plane (X, Z) offset from the centre by `1 + s · (f - 1)`
    /// along the listed axes.
    Scale {
        fx: f64,
        fz: f64,
    },
    /// Follow the bend arc; `sign` = ±1 (up/down); `diag`: along the
    /// diagonal.
    Bend {
        sign: f64,
        diag: bool,
    },
    /// Turn about the X axis through the centre by `s · angle`.
    Turn(f64),
    /// Fold line `j` of `folds`, `sign` of the zigzag.
    Fold {
        j: u32,
        sign: f64,
    },
}

/// The scripted motion of the clamped vertices of one swatch.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseDriver {
    params: PoseParams,
    fabric: FabricBox,
    /// Clamped vertices, grouped, each once.
    pinned: Vec<usize>,
    /// Their rest positions (m).
    rest: Vec<Vec3>,
    groups: Vec<Group>,
}

/// `3s² - 2s³` of `t / ramp` clamped to [0, 1].
pub fn smooth_progress(t: f64, ramp: f64) -> f64 {
    let s = if ramp > 0.0 {
        (t / ramp).clamp(0.0, 1.0)
    } else {
        1.0
    };
    s * s * (3.0 - 2.0 * s)
}

impl PoseDriver {
    /// Selects the clamped bands of `rest` (all yarn vertices, m) for
    /// `params`. Errors for out-of-range parameters and flat or empty rest
    /// states.
    pub fn new(rest: &[Vec3], params: PoseParams) -> Result<PoseDriver, PoseError> {
        params.check()?;
        let p = params;
        let Some(first) = rest.first() else {
            return Err(PoseError::Degenerate("no vertices".into()));
        };
        let mut fabric = FabricBox {
            min: *first,
            max: *first,
        };
        for q in rest {
            if !q.iter().all(|c| c.is_finite()) {
                return Err(PoseError::Degenerate("a vertex is not finite".into()));
            }
            for k in 0..3 {
                fabric.min[k] = fabric.min[k].min(q[k]);
                fabric.max[k] = fabric.max[k].max(q[k]);
            }
        }
        check_plane(&fabric, p.kind)?;
        let (lx, lz) = (fabric.len(0), fabric.len(2));
        if !(lx > 0.0 && lz > 0.0) {
            return Err(PoseError::Degenerate(format!(
                "the swatch spans {lx} m along X and {lz} m along Z; poses need both"
            )));
        }
        let c = fabric.center();
        let sign = if p.mirror { -1.0 } else { 1.0 };
        let (bx, bz) = (p.band * lx, p.band * lz);
        let left = |q: &Vec3| q[0] <= fabric.min[0] + bx;
        let right = |q: &Vec3| q[0] >= fabric.max[0] - bx;
        let back = |q: &Vec3| q[2] <= fabric.min[2] + bz;
        let front = |q: &Vec3| q[2] >= fabric.max[2] - bz;

        // Selection rules: (predicate, role), first match wins per vertex;
        // each rule is one named band.
        type Pred<'a> = Box<dyn Fn(&Vec3) -> bool + 'a>;
        let mut rules: Vec<(Pred, Role)> = Vec::new();
        let mut names: Vec<String> = Vec::new();
        let x_band = |side: &str| format!("{side} band (the {:.3} m of X at the {side} edge)", bx);
        let z_band = |side: &str| format!("{side} band (the {:.3} m of Z at the {side} edge)", bz);
        match p.kind {
            PoseKind::StretchCourses => {
                names.extend([x_band("left"), x_band("right")]);
                let d = [p.amount * lx, 0.0, 0.0];
                if p.mirror {
                    rules.push((Box::new(left), Role::Translate(d.map(|v| -v))));
                    rules.push((Box::new(right), Role::Hold));
                } else {
                    rules.push((Box::new(left), Role::Hold));
                    rules.push((Box::new(right), Role::Translate(d)));
                }
            }
            PoseKind::StretchWales => {
                names.extend([z_band("back"), z_band("front")]);
                let d = [0.0, 0.0, p.amount * lz];
                if p.mirror {
                    rules.push((Box::new(back), Role::Translate(d.map(|v| -v))));
                    rules.push((Box::new(front), Role::Hold));
                } else {
                    rules.push((Box::new(back), Role::Hold));
                    rules.push((Box::new(front), Role::Translate(d)));
                }
            }
            PoseKind::Biaxial => {
                names.push(format!(
                    "edge bands ({:.3} m of X, {:.3} m of Z at the four edges)",
                    bx, bz
                ));
                let f = 1.0 + p.amount;
                let any = move |q: &Vec3| left(q) || right(q) || back(q) || front(q);
                rules.push((Box::new(any), Role::Scale { fx: f, fz: f }));
            }
            PoseKind::Shear => {
                names.extend([z_band("back"), z_band("front")]);
                rules.push((Box::new(back), Role::Hold));
                rules.push((
                    Box::new(front),
                    Role::Translate([sign * p.amount * lz, 0.0, 0.0]),
                ));
            }
            PoseKind::BendCentral => {
                names.push(format!(
                    "left and right bands ({:.3} m of X at each edge)",
                    bx
                ));
                let role = Role::Bend { sign, diag: false };
                rules.push((Box::new(move |q: &Vec3| left(q) || right(q)), role));
            }
            PoseKind::BendDiagonal => {
                // Arc coordinate along the diagonal d2 = (X - Z)/√2 through
                // the centre; the corner bands at both ends of d2 are held
                // on the arc.
                // The bands are measured from the vertices farthest along d2
                // (the box corners may hold no yarn, e.g. beside the edge
                // turns of a flat-knitted swatch).
                let half = 0.5 * (lx + lz) / std::f64::consts::SQRT_2;
                let band = p.band * 2.0 * half;
                let d2_of =
                    move |q: &Vec3| ((q[0] - c[0]) - (q[2] - c[2])) / std::f64::consts::SQRT_2;
                let (lo, hi) = rest
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), q| {
                        (lo.min(d2_of(q)), hi.max(d2_of(q)))
                    });
                let role = Role::Bend { sign, diag: true };
                names.push(format!(
                    "corner bands ({band:.3} m along the diagonal at each end)"
                ));
                rules.push((
                    Box::new(move |q: &Vec3| {
                        let d2 = d2_of(q);
                        d2 >= hi - band || d2 <= lo + band
                    }),
                    role,
                ));
            }
            PoseKind::Fan => {
                if p.mirror {
                    names.extend([z_band("front"), z_band("back")]);
                } else {
                    names.extend([z_band("back"), z_band("front")]);
                }
                let f = Role::Scale {
                    fx: 1.0 + p.amount,
                    fz: 1.0,
                };
                if p.mirror {
                    rules.push((Box::new(front), Role::Hold));
                    rules.push((Box::new(back), f));
                } else {
                    rules.push((Box::new(back), Role::Hold));
                    rules.push((Box::new(front), f));
                }
            }
            PoseKind::Twist => {
                names.extend([x_band("left"), x_band("right")]);
                rules.push((Box::new(left), Role::Hold));
                rules.push((Box::new(right), Role::Turn(sign * p.amount)));
            }
            PoseKind::MultiFold => {
                let k = p.folds;
                let spacing = lx / k as f64;
                for j in 0..=k {
                    let x = fabric.min[0] + j as f64 * spacing;
                    let half_band = 0.5 * bx;
                    names.push(format!(
                        "fold line {j} band (the {bx:.3} m of X about x = {x:.4} m)"
                    ));
                    rules.push((
                        Box::new(move |q: &Vec3| (q[0] - x).abs() <= half_band.max(0.0)),
                        Role::Fold { j, sign },
                    ));
                }
            }
            PoseKind::Hang => {
                // The corners of the top band, measured from the extremes of
                // the vertices in it (a flat-knitted swatch's edge turns
                // reach farther out in X lower down).
                let (lo, hi) = rest
                    .iter()
                    .filter(|q| front(q))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), q| {
                        (lo.min(q[0]), hi.max(q[0]))
                    });
                rules.push((
                    Box::new(move |q: &Vec3| front(q) && (q[0] <= lo + bx || q[0] >= hi - bx)),
                    Role::Hold,
                ));
                names.push(format!("top corner bands ({bx:.3} m of X, {bz:.3} m of Z)"));
            }
            PoseKind::Cantilever => {
                names.push(x_band("held"));
                rules.push((Box::new(left), Role::Hold));
            }
            PoseKind::Free => {}
        }

        let mut pinned = Vec::new();
        let mut rest_pinned = Vec::new();
        let mut groups = Vec::new();
        let mut taken = vec![false; rest.len()];
        debug_assert_eq!(names.len(), rules.len());
        for ((pred, role), name) in rules.iter().zip(&names) {
            let start = pinned.len();
            for (i, q) in rest.iter().enumerate() {
                if !taken[i] && pred(q) {
                    taken[i] = true;
                    pinned.push(i);
                    rest_pinned.push(*q);
                }
            }
            let count = pinned.len() - start;
            if count < MIN_BAND_VERTICES {
                return Err(PoseError::Band(format!(
                    "the {name} of {} holds {count} yarn vertices (a band needs at least \
                     {MIN_BAND_VERTICES} to grip the swatch): widen the band (--band, `[pose] band`; \
                     now {}) or use a larger swatch",
                    kind_name(p.kind),
                    p.band
                )));
            }
            groups.push(Group {
                start,
                count,
                role: *role,
            });
        }
        if p.kind != PoseKind::Free && pinned.is_empty() {
            return Err(PoseError::Degenerate(format!(
                "no vertex lies in the clamped bands of {:?} (band {})",
                p.kind, p.band
            )));
        }
        Ok(PoseDriver {
            params,
            fabric,
            pinned,
            rest: rest_pinned,
            groups,
        })
    }

    /// The clamped vertices (indices into the rest state), in the order of
    /// [`Self::targets`].
    pub fn pinned(&self) -> &[usize] {
        &self.pinned
    }

    /// The parameters.
    pub fn params(&self) -> &PoseParams {
        &self.params
    }

    /// Target positions (m) of the clamped vertices at time `t` (s).
    pub fn targets(&self, t: f64) -> Vec<Vec3> {
        let s = smooth_progress(t, self.params.ramp);
        let mut out = self.rest.clone();
        for g in &self.groups {
            for q in &mut out[g.start..g.start + g.count] {
                *q = self.map(g.role, *q, s);
            }
        }
        out
    }

    /// Number of clamped groups (vertices sharing one map).
    pub fn num_groups(&self) -> usize {
        self.groups.len()
    }

    /// The vertices of group `g` (indices into the rest state).
    pub fn group_vertices(&self, g: usize) -> &[usize] {
        let gr = &self.groups[g];
        &self.pinned[gr.start..gr.start + gr.count]
    }

    /// Position (m) at time `t` (s) of a vertex of group `g` whose rest
    /// position is `anchor` (m).
    pub fn group_target(&self, g: usize, anchor: Vec3, t: f64) -> Vec3 {
        let s = smooth_progress(t, self.params.ramp);
        self.map(self.groups[g].role, anchor, s)
    }

    /// An upper bound (m/s) of the speed of any clamped vertex: the largest
    /// displacement between fine samples of the ramp over their spacing,
    /// with a 25% margin (the maps are smooth in the progress; the
    /// smoothstep's speed peaks at 1.5 / ramp).
    pub fn max_speed(&self) -> f64 {
        if self.params.ramp <= 0.0 {
            return f64::INFINITY;
        }
        const SAMPLES: usize = 256;
        let h = self.params.ramp / SAMPLES as f64;
        let mut prev = self.targets(0.0);
        let mut best: f64 = 0.0;
        for k in 1..=SAMPLES {
            let cur = self.targets(k as f64 * h);
            for (a, b) in prev.iter().zip(&cur) {
                let d =
                    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
                best = best.max(d / h);
            }
            prev = cur;
        }
        1.25 * best
    }

    fn map(&self, role: Role, q: Vec3, s: f64) -> Vec3 {
        let c = self.fabric.center();
        match role {
            Role::Hold => q,
            Role::Translate(d) => std::array::from_fn(|k| q[k] + s * d[k]),
            Role::Scale { fx, fz } => [
                c[0] + (1.0 + s * (fx - 1.0)) * (q[0] - c[0]),
                q[1],
                c[2] + (1.0 + s * (fz - 1.0)) * (q[2] - c[2]),
            ],
            Role::Bend { sign, diag } => {
                // In-plane unit direction of the arc coordinate.
                let (ex, ez) = if diag {
                    let h = std::f64::consts::FRAC_1_SQRT_2;
                    (h, -h)
                } else {
                    (1.0, 0.0)
                };
                let length = if diag {
                    (self.fabric.len(0) + self.fabric.len(2)) * std::f64::consts::FRAC_1_SQRT_2
                } else {
                    self.fabric.len(0)
                };
                let theta = s * self.params.amount;
                let u = (q[0] - c[0]) * ex + (q[2] - c[2]) * ez;
                let h = q[1] - c[1];
                // Arc of radius R = L/θ tangent to the fabric at the centre:
                // arc length u -> angle φ = u/R; normal offsets h rotate too.
                let (du, dy) = if theta.abs() < 1e-12 {
                    (0.0, 0.0)
                } else {
                    let r = length / theta;
                    let phi = u / r;
                    // Mirrored, the arc curves toward -Y while the normal
                    // offset `h` keeps its side of the fabric.
                    let along = r * phi.sin() - sign * h * phi.sin();
                    let up = sign * r * (1.0 - phi.cos()) + h * phi.cos();
                    (along - u, up - h)
                };
                [q[0] + du * ex, q[1] + dy, q[2] + du * ez]
            }
            Role::Turn(angle) => {
                let a = s * angle;
                let (y, z) = (q[1] - c[1], q[2] - c[2]);
                [
                    q[0],
                    c[1] + a.cos() * y - a.sin() * z,
                    c[2] + a.sin() * y + a.cos() * z,
                ]
            }
            Role::Fold { j, sign } => {
                let k = self.params.folds as f64;
                let fold_len = self.fabric.len(0) / k;
                let rise = s * self.params.amount * fold_len;
                let run = (fold_len * fold_len - rise * rise).max(0.0).sqrt();
                // Line j moves to x_j = min + j run (the zigzag keeps each
                // fold's length), centred on the rest centre, height ±rise/2.
                let jf = j as f64;
                let x_rest = self.fabric.min[0] + jf * fold_len;
                let total = k * run;
                let x_new = c[0] - 0.5 * total + jf * run;
                let height = if j % 2 == 0 { 0.5 } else { -0.5 } * sign * rise;
                [q[0] - x_rest + x_new, q[1] + height, q[2]]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid of points in the XZ plane, 1 m x 0.5 m.
    fn grid() -> Vec<Vec3> {
        let mut v = Vec::new();
        for i in 0..=20 {
            for j in 0..=10 {
                v.push([i as f64 * 0.05, 0.0, j as f64 * 0.05]);
            }
        }
        v
    }

    use crate::geom::dist;

    #[test]
    fn start_at_rest_for_every_kind() {
        let rest = grid();
        for kind in PoseKind::ALL {
            let mut p = PoseParams::new(kind, 0.3);
            p.folds = 2;
            let d = PoseDriver::new(&rest, p).unwrap();
            for (i, q) in d.pinned().iter().zip(d.targets(0.0)) {
                assert!(dist(rest[*i], q) < 1e-15, "{kind:?}");
            }
            if kind == PoseKind::Free {
                assert!(d.pinned().is_empty());
            } else {
                assert!(!d.pinned().is_empty(), "{kind:?}");
            }
        }
    }

    #[test]
    fn cantilever_holds_only_the_left_band_in_place() {
        let rest = grid();
        let d = PoseDriver::new(&rest, PoseParams::new(PoseKind::Cantilever, 0.0)).unwrap();
        assert_eq!(d.num_groups(), 1);
        let band = PoseParams::new(PoseKind::Cantilever, 0.0).band;
        for (i, q) in d.pinned().iter().zip(d.targets(1.0)) {
            assert!(rest[*i][0] <= band + 1e-12, "{:?}", rest[*i]);
            assert_eq!(q, rest[*i]);
        }
        let left = rest.iter().filter(|q| q[0] <= band + 1e-12).count();
        assert_eq!(d.pinned().len(), left);
        // A wide band sets a short overhang; two-band poses stay below half.
        let mut wide = PoseParams::new(PoseKind::Cantilever, 0.0);
        wide.band = 0.62;
        let d = PoseDriver::new(&rest, wide).unwrap();
        let held = rest.iter().filter(|q| q[0] <= 0.62).count();
        assert_eq!(d.pinned().len(), held);
        assert!(held > rest.len() / 2);
        wide.kind = PoseKind::StretchCourses;
        assert!(PoseDriver::new(&rest, wide).is_err());
        wide.kind = PoseKind::Cantilever;
        wide.band = 0.95;
        assert!(PoseDriver::new(&rest, wide).is_err());
    }

    #[test]
    fn stretch_moves_right_band_by_strain() {
        let rest = grid();
        let d = PoseDriver::new(&rest, PoseParams::new(PoseKind::StretchCourses, 0.3)).unwrap();
        let t = d.targets(5.0);
        for (i, q) in d.pinned().iter().zip(&t) {
            let r = rest[*i];
            let want = if r[0] > 0.5 { r[0] + 0.3 } else { r[0] };
            assert!((q[0] - want).abs() < 1e-12);
        }
    }

    #[test]
    fn bend_keeps_arc_length_and_mirror_flips() {
        let rest = grid();
        let angle = 1.2;
        let up = PoseDriver::new(&rest, PoseParams::new(PoseKind::BendCentral, angle)).unwrap();
        let mut mp = PoseParams::new(PoseKind::BendCentral, angle);
        mp.mirror = true;
        let down = PoseDriver::new(&rest, mp).unwrap();
        let (tu, td) = (up.targets(1.0), down.targets(1.0));
        // The outermost band vertices lie on the arc of radius L/θ around
        // the centre of curvature at height R above the centre.
        let r = 1.0 / angle;
        for (k, &i) in up.pinned().iter().enumerate() {
            let q = tu[k];
            let centre = [0.5, r, rest[i][2]];
            assert!((dist(q, centre) - r).abs() < 1e-12);
            assert!((td[k][1] + q[1]).abs() < 1e-12, "mirror negates height");
            // The end point turned by θ/2 relative to the centre tangent.
            if rest[i][0] == 1.0 {
                assert!((q[1] - r * (1.0 - (0.5 * angle).cos())).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn twist_preserves_distance_to_axis() {
        let rest = grid();
        let d = PoseDriver::new(&rest, PoseParams::new(PoseKind::Twist, 2.0)).unwrap();
        for (i, q) in d.pinned().iter().zip(d.targets(1.0)) {
            let r = rest[*i];
            let before = (r[1].powi(2) + (r[2] - 0.25).powi(2)).sqrt();
            let after = (q[1].powi(2) + (q[2] - 0.25).powi(2)).sqrt();
            assert!((before - after).abs() < 1e-12);
        }
    }

    #[test]
    fn multifold_keeps_fold_lengths() {
        let rest = grid();
        let mut p = PoseParams::new(PoseKind::MultiFold, 0.3);
        p.folds = 4;
        let d = PoseDriver::new(&rest, p).unwrap();
        let t = d.targets(1.0);
        // Consecutive fold lines at the same z stay one fold length apart.
        let line = |x: f64| {
            d.pinned()
                .iter()
                .position(|&i| (rest[i][0] - x).abs() < 1e-9 && rest[i][2] == 0.0)
                .map(|k| t[k])
                .unwrap()
        };
        for j in 0..4 {
            let (a, b) = (line(j as f64 * 0.25), line((j + 1) as f64 * 0.25));
            assert!((dist(a, b) - 0.25).abs() < 1e-12, "fold {j}");
        }
    }

    #[test]
    fn bad_parameters_are_errors() {
        let rest = grid();
        assert!(PoseDriver::new(&rest, PoseParams::new(PoseKind::Fan, f64::NAN)).is_err());
        assert!(PoseDriver::new(&rest, PoseParams::new(PoseKind::MultiFold, 0.6)).is_err());
        assert!(PoseDriver::new(&[], PoseParams::new(PoseKind::Shear, 0.1)).is_err());
        let flat: Vec<Vec3> = (0..10).map(|i| [i as f64, 0.0, 0.0]).collect();
        assert!(PoseDriver::new(&flat, PoseParams::new(PoseKind::Shear, 0.1)).is_err());
        let mut p = PoseParams::new(PoseKind::Shear, 0.1);
        p.band = 0.7;
        assert!(PoseDriver::new(&rest, p).is_err());
    }

    #[test]
    fn a_flat_swatch_outside_the_xz_plane_is_refused_with_the_fix() {
        // The grid stood up in XY (as a pattern swatch read +Y up), a thin
        // depth along Z: every kind refuses it, clamped or not.
        let standing: Vec<Vec3> = grid()
            .iter()
            .enumerate()
            .map(|(i, q)| [q[0], q[2], 0.002 * (i % 2) as f64])
            .collect();
        for kind in [PoseKind::Fan, PoseKind::StretchCourses, PoseKind::Free] {
            let e = PoseDriver::new(&standing, PoseParams::new(kind, 0.2)).unwrap_err();
            let m = e.to_string();
            assert!(matches!(e, PoseError::Plane(_)), "{kind:?}: {m}");
            assert!(
                m.contains("XY plane") && m.contains("--up-axis z") && m.contains("along Z"),
                "{kind:?}: {m}"
            );
        }
        // Lying in YZ: the fix is to turn it.
        let side: Vec<Vec3> = grid().iter().map(|q| [0.0, q[0], q[2]]).collect();
        let m = PoseDriver::new(&side, PoseParams::new(PoseKind::Shear, 0.1))
            .unwrap_err()
            .to_string();
        assert!(m.contains("YZ plane") && m.contains("turn"), "{m}");
        // A solid body (as thick as it is wide) is not a flat swatch.
        let cube: Vec<Vec3> = grid().iter().map(|q| [q[0], q[2], q[2]]).collect();
        assert!(PoseDriver::new(&cube, PoseParams::new(PoseKind::Shear, 0.1)).is_ok());
    }

    #[test]
    fn a_band_holding_too_few_vertices_is_named() {
        // The left column holds only two points; a narrow band selects just
        // them.
        let sparse: Vec<Vec3> = grid()
            .into_iter()
            .filter(|q| q[0] > 0.0 || q[2] < 0.06)
            .collect();
        let mut p = PoseParams::new(PoseKind::StretchCourses, 0.1);
        p.band = 0.02;
        let e = PoseDriver::new(&sparse, p).unwrap_err();
        let m = e.to_string();
        assert!(matches!(e, PoseError::Band(_)), "{m}");
        assert!(
            m.contains("left band") && m.contains("holds 2 yarn vertices") && m.contains("--band"),
            "{m}"
        );
        // Wider, it grips the next column too.
        p.band = 0.06;
        let d = PoseDriver::new(&sparse, p).unwrap();
        assert!(d.group_vertices(0).len() >= MIN_BAND_VERTICES);
    }

    #[test]
    fn groups_cover_pinned_and_speed_bounds_motion() {
        let rest = grid();
        let mut p = PoseParams::new(PoseKind::Twist, 2.0);
        p.ramp = 0.5;
        let d = PoseDriver::new(&rest, p).unwrap();
        let total: usize = (0..d.num_groups()).map(|g| d.group_vertices(g).len()).sum();
        assert_eq!(total, d.pinned().len());
        let vmax = d.max_speed();
        assert!(vmax.is_finite() && vmax > 0.0);
        // Finite differences of every group target stay under the bound.
        for g in 0..d.num_groups() {
            for &v in d.group_vertices(g) {
                for k in 0..50 {
                    let (t0, t1) = (k as f64 * 0.01, k as f64 * 0.01 + 1e-4);
                    let (a, b) = (
                        d.group_target(g, rest[v], t0),
                        d.group_target(g, rest[v], t1),
                    );
                    assert!(dist(a, b) / 1e-4 <= vmax);
                }
            }
        }
    }
}
