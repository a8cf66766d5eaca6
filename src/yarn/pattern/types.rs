//! The pattern generator's types: stitch codes, knit grids and weave
//! matrices, the shape parameters and the periodic tile of one repeat.

use crate::geom::GeomError;
use crate::yarn::PeriodicTile;

/// A knit stitch code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stitch {
    /// K: the new loop is pulled through the old one from back to front.
    Knit,
    /// P: from front to back (a knit mirrored through the fabric plane).
    Purl,
}

/// Why a pattern could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PatternError {
    /// A grid text is malformed; `line` and `column` are 1-based.
    #[error("line {line}, column {column}: {message}")]
    Grid {
        line: usize,
        column: usize,
        message: String,
    },
    /// No built-in pattern has this name.
    #[error("unknown pattern '{name}'; known patterns: {}", known.join(", "))]
    UnknownPattern {
        name: String,
        known: Vec<&'static str>,
    },
    /// A size or shape parameter is out of range.
    #[error("{name} = {value}: {message}")]
    BadParameter {
        name: &'static str,
        value: f64,
        message: String,
    },
    /// The generated curves are not well formed (a bug or absurd parameters).
    #[error("generated curves are invalid: {0}")]
    Geometry(#[from] GeomError),
}

/// A knit pattern: a rectangular grid of stitch codes, `rows[j][i]` the stitch
/// of course `j` (bottom course first) and wale `i`.
#[derive(Debug, Clone, PartialEq)]
pub struct KnitGrid {
    pub rows: Vec<Vec<Stitch>>,
}

/// A single-layer weave (Leaf §4): `rows[i][j]` is true where weft `i`
/// (bottom weft first) passes over warp `j` (left warp first), false where
/// the warp is on top.
#[derive(Debug, Clone, PartialEq)]
pub struct WeaveMatrix {
    pub rows: Vec<Vec<bool>>,
}

/// A stitch pattern: knit or woven.
#[derive(Debug, Clone, PartialEq)]
pub enum Pattern {
    Knit(KnitGrid),
    Woven(WeaveMatrix),
}

impl Pattern {
    /// `[columns, rows]` of one repeat: wales x courses (knit), warps x wefts (woven).
    pub fn repeat(&self) -> [usize; 2] {
        let dims = |rows: usize, cols: usize| [cols, rows];
        match self {
            Pattern::Knit(g) => dims(g.rows.len(), g.rows.first().map_or(0, Vec::len)),
            Pattern::Woven(w) => dims(w.rows.len(), w.rows.first().map_or(0, Vec::len)),
        }
    }

    /// "knit" or "woven".
    pub fn kind(&self) -> &'static str {
        match self {
            Pattern::Knit(_) => "knit",
            Pattern::Woven(_) => "woven",
        }
    }

    pub(crate) fn check_rectangular(&self) -> Result<(), PatternError> {
        let [cols, rows] = self.repeat();
        let lens: Vec<usize> = match self {
            Pattern::Knit(g) => g.rows.iter().map(Vec::len).collect(),
            Pattern::Woven(w) => w.rows.iter().map(Vec::len).collect(),
        };
        if rows == 0 || cols == 0 || lens.iter().any(|&l| l != cols) {
            return Err(PatternError::BadParameter {
                name: "pattern",
                value: rows as f64,
                message: "a pattern needs a non-empty rectangular grid".into(),
            });
        }
        Ok(())
    }
}

/// Shape of knit loops, in multiples of the yarn radius r. The loop centre
/// line of course j, parameter t (one wale per 2 pi, t = 0 at a sinker loop,
/// t = pi at the needle-loop head) is the classic loop curve
/// x = W (t + a sin 2t) / (2 pi), y = j H - b cos t (Kaldor 2011-style
/// interlocking loops, as in `yarn::analytic`), and z follows the stitch codes
/// (see [`knit`]).
///
/// The defaults were chosen by a search over (W, H, a, b, c) for the largest
/// clearance of all built-ins (every one >= 1.0 * 2r before relaxation). They
/// give a loop length of about 38 r = 19 yarn diameters (HYLC's relaxed
/// stockinette tile in `data/yarns/madypg_stockinette.pyp` has 17 d), but a
/// looser, larger stitch (5.25 d x 3.25 d against HYLC's relaxed 3.8 d x 2.0 d):
/// like Leaf's generated curves (§6.2) they hold slack that relaxation removes.
#[derive(Debug, Clone, PartialEq)]
pub struct KnitShape {
    /// Wale width W (stitch width, along courses) / r. Default 10.5.
    pub wale_width: f64,
    /// Course height H (course spacing) / r. Default 6.5.
    pub course_height: f64,
    /// Loop half-height b / r (head top to sinker bottom is 2b). Default 5.0.
    pub loop_height: f64,
    /// Loop bulge a (dimensionless; > 1/2 makes the legs double back so that
    /// the head is wider than the neck). Default 1.6.
    pub bulge: f64,
    /// Depth c / r: the yarn sits at z = +-c where it crosses another. Default 1.6.
    pub depth: f64,
}

impl Default for KnitShape {
    fn default() -> Self {
        KnitShape {
            wale_width: 10.5,
            course_height: 6.5,
            loop_height: 5.0,
            bulge: 1.6,
            depth: 1.6,
        }
    }
}

/// Shape of woven yarns, in multiples of the yarn radius r: sinusoidal
/// (cosine-eased) crimp between crossings.
#[derive(Debug, Clone, PartialEq)]
pub struct WovenShape {
    /// Spacing S between neighbouring parallel yarns / r. Default 5.0: a
    /// cosine crimp of amplitude A bends with radius S^2 / (pi^2 A) at a
    /// crossing and must wrap the other yarn at >= 2A, so S >= pi sqrt(2) A
    /// (4.9 r for A = 1.1 r). Looser than HYLC's relaxed basket and satin
    /// tiles (2.7 r and 2.2 r): relaxation tightens it.
    pub spacing: f64,
    /// Crimp amplitude / r: at a crossing the upper yarn is at +A, the lower
    /// at -A, so the crossing clearance is 2A. Default 1.1 (clearance 1.1 * 2r).
    pub crimp: f64,
}

impl Default for WovenShape {
    fn default() -> Self {
        WovenShape {
            spacing: 5.0,
            crimp: 1.1,
        }
    }
}

/// Parameters of the pattern generator.
#[derive(Debug, Clone, PartialEq)]
pub struct PatternParams {
    /// Yarn radius r (m). Default 1 mm: HYLC (Sperl et al. 2020, §7 and
    /// Table 1) rescales all its patterns to r = 1 mm (also `geom::DEFAULT_RADIUS_M`).
    pub yarn_radius: f64,
    /// Target vertex spacing along the yarn / r. Default 1.25 (HYLC's
    /// stockinette tile samples at 1.37 r; Leaf §3.1 needs fewer than one
    /// contact sample per 2r, so spacing < 2r).
    pub spacing: f64,
    pub knit: KnitShape,
    pub woven: WovenShape,
}

impl Default for PatternParams {
    fn default() -> Self {
        PatternParams {
            yarn_radius: crate::geom::DEFAULT_RADIUS_M,
            spacing: 1.25,
            knit: KnitShape::default(),
            woven: WovenShape::default(),
        }
    }
}

impl PatternParams {
    pub(crate) fn check(&self) -> Result<(), PatternError> {
        let checks: [(&'static str, f64, f64, f64); 9] = [
            ("yarn_radius", self.yarn_radius, 1e-7, 1.0),
            ("spacing", self.spacing, 0.05, 4.0),
            ("knit.wale_width", self.knit.wale_width, 2.0, 100.0),
            ("knit.course_height", self.knit.course_height, 1.0, 100.0),
            ("knit.loop_height", self.knit.loop_height, 0.5, 100.0),
            ("knit.bulge", self.knit.bulge, 0.0, 10.0),
            ("knit.depth", self.knit.depth, 0.1, 100.0),
            ("woven.spacing", self.woven.spacing, 2.0, 100.0),
            ("woven.crimp", self.woven.crimp, 0.0, 100.0),
        ];
        for (name, value, lo, hi) in checks {
            if !(value.is_finite() && value >= lo && value <= hi) {
                return Err(PatternError::BadParameter {
                    name,
                    value,
                    message: format!("must be between {lo} and {hi}"),
                });
            }
        }
        Ok(())
    }
}

/// One repeat of a pattern as a periodic tile, with what is needed to lay it
/// out as swatches: which way every curve runs and which lane it occupies.
#[derive(Debug, Clone, PartialEq)]
pub struct PatternTile {
    /// The tile (curves open, continuations, lattice = repeat * pitch).
    pub tile: PeriodicTile,
    /// Per curve: 0 when it runs along `lattice[0]` (a course, a weft),
    /// 1 when along `lattice[1]` (a warp).
    pub axis: Vec<u8>,
    /// Per curve: its lane within the tile across its running direction
    /// (course row, weft row, warp column).
    pub lane: Vec<usize>,
    /// `[columns, rows]` of the repeat (wales x courses; warps x wefts).
    pub repeat: [usize; 2],
    /// Pitch (m) along x and y: wale width and course height; yarn spacing.
    pub pitch: [f64; 2],
    /// Yarn radius (m).
    pub radius: f64,
    /// Length (in `pitch[0]`) over which a tube's helix eases from the end of
    /// one course into the next (see [`lay_out`]): the sinker region of a knit
    /// (0.15), a whole crossing interval of a weave (1).
    pub seam: f64,
}
