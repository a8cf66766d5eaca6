//! Material cards on garments: reading a card
//! ([`crate::geom::card`], schemas/material-card.md) and `embed --card`,
//! which gives each tet its card's material ([`apply_cards`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::embed::orientation::course_and_wale;
use crate::embed::regions::{fabric_area, tet_labels};
use crate::geom::card::{card_scale, CardMaterial, CardScale, MaterialCard, CARD_FORMAT};
use crate::geom::{Asset, AssetFibres, Vec3, Yarns};
use crate::io::{self, IoError};
use crate::pipeline::Error;

/// Largest card file read (bytes): a card is a few kilobytes.
pub const MAX_CARD_BYTES: u64 = 1 << 20;

/// Why a card cannot be read or used.
#[derive(Debug, thiserror::Error)]
pub enum CardFileError {
    #[error(transparent)]
    Io(#[from] IoError),
    /// Not TOML, or not a card: `path: line L, column C: ...` or the field.
    #[error("{path}: {message}", path = path.display())]
    Invalid { path: PathBuf, message: String },
}

impl CardFileError {
    pub fn class(&self) -> crate::pipeline::ErrorClass {
        match self {
            CardFileError::Io(e) => e.class().into(),
            CardFileError::Invalid { .. } => crate::pipeline::ErrorClass::BadInput,
        }
    }
}

impl crate::pipeline::error::StageFailure for CardFileError {
    fn class(&self) -> crate::pipeline::ErrorClass {
        CardFileError::class(self)
    }
    fn file(&self) -> Option<PathBuf> {
        match self {
            CardFileError::Io(e) => Some(e.path().to_path_buf()),
            CardFileError::Invalid { path, .. } => Some(path.clone()),
        }
    }
    fn as_error(&self) -> &(dyn std::error::Error + 'static) {
        self
    }
}

impl From<CardFileError> for Error {
    fn from(e: CardFileError) -> Self {
        Error::stage(e)
    }
}

/// Reads and checks a card (bounded: [`MAX_CARD_BYTES`]).
/// It returns the card and the SHA-256 (hex) of the bytes it was read from,
/// so the provenance names exactly the card used.
pub fn read_card(path: &Path) -> Result<(MaterialCard, String), CardFileError> {
    use sha2::{Digest, Sha256};
    let text = io::input::read_input_text(path, "material card", MAX_CARD_BYTES)?;
    let card = decode_card(&text).map_err(|message| CardFileError::Invalid {
        path: path.to_path_buf(),
        message,
    })?;
    let sha = Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    Ok((card, sha))
}

/// A card from its TOML text, checked ([`MaterialCard::check`]).
pub fn decode_card(text: &str) -> Result<MaterialCard, String> {
    // The format line first, so that another file reads as "not a card".
    let value: toml::Value =
        toml::from_str(text).map_err(|e| super::sim_scene::toml_error_line(&e, text))?;
    match value.get("format").and_then(|f| f.as_str()) {
        Some(CARD_FORMAT) => {}
        Some(f) => {
            return Err(format!(
                "format {:?} is not a material card ({CARD_FORMAT:?})",
                crate::geom::excerpt(f)
            ))
        }
        None => {
            return Err(format!(
                "no `format = \"{CARD_FORMAT}\"`: not a material card"
            ))
        }
    }
    let card: MaterialCard =
        toml::from_str(text).map_err(|e| super::sim_scene::toml_error_line(&e, text))?;
    card.check().map_err(|e| e.to_string())?;
    Ok(card)
}

/// The card as TOML text (with a header comment).
pub fn encode_card(card: &MaterialCard) -> Result<String, Error> {
    let body = toml::to_string(card).map_err(|e| Error::Internal(format!("card: {e}")))?;
    Ok(format!(
        "# knitvox material card: the homogenized knit material of one stitch and yarn\n\
         # (schemas/material-card.md). `knitvox embed YARNS --card THIS` carries it onto a garment.\n{body}"
    ))
}

/// Total rest volume of `tets` of the mesh (all of them when `None`).
pub(crate) fn mesh_volume(asset: &Asset, tets: Option<&[bool]>) -> f64 {
    (0..asset.mesh.num_tets())
        .filter(|&t| tets.is_none_or(|m| m[t]))
        .map(|t| asset.mesh.volume(t))
        .sum()
}

/// Unit fabric normal per tet: course × wale.
fn tet_normals(cw: &crate::embed::orientation::CourseWale) -> Vec<Vec3> {
    cw.course
        .iter()
        .zip(&cw.wale)
        .map(|(c, w)| {
            use crate::geom::vec3::{cross, norm, scale};
            let n = cross(*c, *w);
            let l = norm(n);
            if l > 0.0 {
                scale(n, 1.0 / l)
            } else {
                [0.0; 3]
            }
        })
        .collect()
}

/// Where a card applies on a garment.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CardRegion {
    /// Every tet no other card claims.
    Rest,
    /// Yarn vertices of these curves (0-based, inclusive ranges).
    Curves(Vec<[usize; 2]>),
    /// Yarn vertices inside this box (m, knitvox's frame, +Y up).
    Box { min: Vec3, max: Vec3 },
}

impl CardRegion {
    /// `curves=0-3,7` or `box=x0,y0,z0,x1,y1,z1`.
    pub fn parse(s: &str) -> Result<CardRegion, String> {
        let (key, value) = s.split_once('=').ok_or_else(|| {
            format!(
                "region {:?}: give curves=A-B,C or box=X0,Y0,Z0,X1,Y1,Z1",
                crate::geom::excerpt(s)
            )
        })?;
        match key.trim() {
            "curves" => {
                let mut ranges = Vec::new();
                for part in value.split(',') {
                    let part = part.trim();
                    let (a, b) = part.split_once('-').unwrap_or((part, part));
                    let a: usize = a.trim().parse().map_err(|_| {
                        format!(
                            "curves: {:?} is not a curve number",
                            crate::geom::excerpt(a)
                        )
                    })?;
                    let b: usize = b.trim().parse().map_err(|_| {
                        format!(
                            "curves: {:?} is not a curve number",
                            crate::geom::excerpt(b)
                        )
                    })?;
                    if b < a {
                        return Err(format!("curves: range {a}-{b} runs backwards"));
                    }
                    ranges.push([a, b]);
                }
                Ok(CardRegion::Curves(ranges))
            }
            "box" => {
                let v: Vec<f64> = value
                    .split(',')
                    .map(|x| x.trim().parse::<f64>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| {
                        format!("box: {:?} is not six numbers", crate::geom::excerpt(value))
                    })?;
                if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
                    return Err(format!(
                        "box: give six finite numbers x0,y0,z0,x1,y1,z1 (m), not {}",
                        v.len()
                    ));
                }
                let min = [v[0].min(v[3]), v[1].min(v[4]), v[2].min(v[5])];
                let max = [v[0].max(v[3]), v[1].max(v[4]), v[2].max(v[5])];
                Ok(CardRegion::Box { min, max })
            }
            k => Err(format!(
                "region kind {:?}: knitvox knows curves=... and box=...",
                crate::geom::excerpt(k)
            )),
        }
    }

    fn holds(&self, yarns: &Yarns, curve: usize, v: usize) -> bool {
        match self {
            CardRegion::Rest => true,
            CardRegion::Curves(r) => r.iter().any(|[a, b]| (*a..=*b).contains(&curve)),
            CardRegion::Box { min, max } => {
                let p = yarns.points[v];
                (0..3).all(|k| p[k] >= min[k] && p[k] <= max[k])
            }
        }
    }
}

/// A card and where it applies.
#[derive(Debug, Clone)]
pub struct CardSpec {
    pub path: PathBuf,
    pub region: CardRegion,
}

impl CardSpec {
    /// `CARD` (every tet), `CARD@curves=..` or `CARD@box=..` (as `embed
    /// --card` and a manifest's `[embed] cards` give it).
    pub fn parse(s: &str) -> Result<CardSpec, String> {
        let split = s.rfind('@').filter(|&i| {
            ["curves=", "box="]
                .iter()
                .any(|k| s[i + 1..].trim_start().starts_with(k))
        });
        match split {
            Some(i) => Ok(CardSpec {
                path: PathBuf::from(&s[..i]),
                region: CardRegion::parse(&s[i + 1..])?,
            }),
            None => Ok(CardSpec {
                path: PathBuf::from(s),
                region: CardRegion::Rest,
            }),
        }
    }
}

/// What one card of a transfer did.
#[derive(Debug, Clone, Serialize)]
pub struct CardApplied {
    pub path: PathBuf,
    pub sha256: String,
    pub name: String,
    pub region: CardRegion,
    pub tets: usize,
    pub yarn_vertices: usize,
    /// The stiffness factor keeping the card's stiffness per unit width
    /// ([`card_scale`]) and what it came from.
    pub scale: CardScale,
    /// The card's material as assigned (Pa; the factor applied).
    pub material: CardMaterial,
}

/// What [`apply_cards`] did.
#[derive(Debug, Clone, Serialize)]
pub struct CardTransfer {
    pub cards: Vec<CardApplied>,
    /// Tets no card reached (they keep the placeholder material).
    pub uncovered_tets: usize,
    /// Mean chord anisotropy of the course directions found
    /// ([`crate::embed::orientation::CourseWale::mean_anisotropy`]).
    pub fibre_anisotropy: f64,
    pub warnings: Vec<String>,
    pub seconds: f64,
}

/// Bounds on the stiffness factor beyond which a transfer warns: the
/// garment's mesh is much thicker or thinner per fabric area than the
/// card's, so its bending (which grows as the mesh thickness cubed) is far
/// from the card's even where the stretch is kept.
pub const CARD_SCALE_WARN: [f64; 2] = [0.25, 4.0];

/// Gives each tet of `asset` its card's material (later specs win where
/// regions overlap; a [`CardRegion::Rest`] card takes every tet no other
/// claims): VH Eq. 7 and the knit fibres along the tet's own course and
/// wale (from the garment's rest yarns), every stiffness scaled per card
/// so that the fabric keeps the card's stiffness per unit width
/// ([`card_scale`]). Tets no card reaches keep their material.
pub fn apply_cards(
    asset: &mut Asset,
    specs: &[(CardSpec, MaterialCard)],
) -> Result<CardTransfer, crate::embed::EmbedError> {
    let t0 = Instant::now();
    let y = &asset.rest_yarns;
    let nv = y.num_points();
    // Label 0: no card; spec k: label k + 1, rest cards first so that any
    // region card overrides them.
    let mut order: Vec<usize> = (0..specs.len()).collect();
    order.sort_by_key(|&k| !matches!(specs[k].0.region, CardRegion::Rest));
    let mut label = vec![0u16; nv];
    for c in 0..y.num_curves() {
        for v in y.curve_range(c) {
            for &k in &order {
                if specs[k].0.region.holds(y, c, v) {
                    label[v] = k as u16 + 1;
                }
            }
        }
    }
    // Out of every vertex's reach a tet takes the last card for the rest.
    let rest = (0..specs.len())
        .rev()
        .find(|&k| matches!(specs[k].0.region, CardRegion::Rest))
        .map_or(0, |k| k as u16 + 1);
    let tet_label = tet_labels(
        &asset.grid,
        &asset.tet_voxel,
        &asset.embedding,
        &label,
        specs.len() + 1,
        rest,
    );
    let cw = course_and_wale(y, &asset.grid, &asset.tet_voxel, &Default::default())?;
    let nt = asset.mesh.num_tets();
    // A fresh embedding has no fibres: every tet gets the garment's own
    // directions, and no stiffness until a card reaches it.
    let fibre_anisotropy = cw.mean_anisotropy;
    let mut fibres = AssetFibres {
        course: cw.course,
        wale: cw.wale,
        gamma_course: vec![0.0; nt],
        gamma_wale: vec![0.0; nt],
        beta_course: vec![0.0; nt],
        beta_wale: vec![0.0; nt],
    };
    // Yarn length per label: each segment's half to each end vertex.
    let mut length = vec![0.0; specs.len() + 1];
    for [a, b] in y.segments() {
        let l = crate::geom::dist(y.points[a], y.points[b]);
        length[label[a] as usize] += 0.5 * l;
        length[label[b] as usize] += 0.5 * l;
    }
    // The fabric's normal for its area from a wider neighbourhood than the
    // fibres' (2 voxels): at voxels finer than the default a 1-voxel
    // neighbourhood sees single loops, and their tilt lowered a 16 x 16
    // stockinette's area by 24% at half the default voxel (4.5% with 2).
    let wide = crate::embed::orientation::OrientationParams {
        radius_voxels: 2,
        ..Default::default()
    };
    let normals = tet_normals(&course_and_wale(y, &asset.grid, &asset.tet_voxel, &wide)?);
    let mut warnings = Vec::new();
    let mut cards = Vec::new();
    for (k, (spec, card)) in specs.iter().enumerate() {
        let l = k as u16 + 1;
        let tets: Vec<bool> = tet_label.iter().map(|&t| t == l).collect();
        let count = tets.iter().filter(|&&x| x).count();
        let verts: Vec<usize> = (0..nv).filter(|&v| label[v] == l).collect();
        let radius = verts.iter().map(|&v| y.radius_at(v)).sum::<f64>() / verts.len().max(1) as f64;
        let volume = mesh_volume(asset, Some(&tets));
        let area = fabric_area(&asset.grid, &asset.tet_voxel, &normals, &tets);
        let scale = card_scale(&card.stitch, length[l as usize], volume, area);
        let what = format!("card {} ({})", spec.path.display(), card.name);
        if count == 0 || !(scale.factor.is_finite() && scale.factor > 0.0) {
            warnings.push(format!("{what}: its region holds no tet of the garment"));
            continue;
        } else if !(CARD_SCALE_WARN[0]..=CARD_SCALE_WARN[1]).contains(&scale.factor) {
            warnings.push(format!(
                "{what}: the garment's mesh is {:.2} mm thick per fabric area where the card's \
                 swatch was {:.2} mm, so its stiffnesses are scaled by {:.3} to keep the fabric's \
                 stretch; its bending is then {:.2}x the card's (a --voxel-size near {:.3e} m \
                 meshes it as the card's swatch was)",
                1e3 * scale.mesh_thickness_m,
                1e3 * card.stitch.mesh_thickness_m,
                scale.factor,
                // Bending per width grows as the mesh thickness cubed,
                // stretch as its first power: with the stretch kept, the
                // bending is off by 1 / factor².
                1.0 / (scale.factor * scale.factor),
                asset.grid.h * scale.factor
            ));
        }
        // Stitches `s` times the card's are knitted in yarn about `s` times
        // its radius; a radius far from that (often a file's assumed
        // 1 mm) would put the yarn-level contact, not the material, off.
        let expected = card.stitch.yarn_radius_m * scale.stitch_scale;
        let r_ratio = radius / expected;
        if !(0.5..=2.0).contains(&r_ratio) {
            warnings.push(format!(
                "{what}: the garment's stitches are {:.2}x the card's (from its yarn length per \
                 fabric area, {:.0} /m against {:.0} /m), so its yarn would be about {expected:.2e} m \
                 in radius, but it is {radius:.2e} m (give the yarn radius with --radius when the \
                 file does not say it; a card of that stitch at that scale fits best)",
                scale.stitch_scale,
                scale.yarn_length_per_area_per_m,
                card.stitch.yarn_length_per_area_per_m
            ));
        }
        let m = card.material.scaled(scale.factor);
        for t in (0..nt).filter(|&t| tets[t]) {
            asset.gamma_s[t] = m.gamma_s_pa;
            asset.gamma_v[t] = m.gamma_v_pa;
            fibres.gamma_course[t] = m.course_pa;
            fibres.gamma_wale[t] = m.wale_pa;
            fibres.beta_course[t] = m.course_beta;
            fibres.beta_wale[t] = m.wale_beta;
        }
        cards.push(CardApplied {
            path: spec.path.clone(),
            sha256: String::new(),
            name: card.name.clone(),
            region: spec.region.clone(),
            tets: count,
            yarn_vertices: verts.len(),
            scale,
            material: m,
        });
    }
    let uncovered = tet_label.iter().filter(|&&l| l == 0).count();
    if uncovered > 0 {
        warnings.push(format!(
            "{uncovered} of {nt} tets lie in no card's region and keep the placeholder material \
             (add a card without a region for the rest)"
        ));
    }
    asset.fibres = Some(fibres);
    Ok(CardTransfer {
        cards,
        uncovered_tets: uncovered,
        fibre_anisotropy,
        warnings,
        seconds: t0.elapsed().as_secs_f64(),
    })
}
