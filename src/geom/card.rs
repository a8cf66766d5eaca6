//! A material card: the homogenized material of one stitch pattern knitted
//! in one yarn, fitted once on a swatch (`knitvox card`) and carried onto
//! any garment knitted with it (`knitvox embed --card`). Small and
//! versioned (TOML, schemas/material-card.md), with its provenance.
//!
//! A card holds one homogeneous knit material in the fabric frame (the
//! swatch's uniform knit fit: VH Eq. 7 for the shear and bending, a course
//! and a wale fibre that stiffen with stretch, [`crate::sim::knit`]) and the
//! stitch geometry it was fitted at, so that a garment meshed at another
//! resolution or knitted at another scale gets the same fabric stiffness per
//! unit width ([`StitchGeometry`]). Heterogeneous garments are patchworks of
//! cards (du Pasquier et al. 2025: heterogeneous knits are well modelled as
//! patchworks of homogeneous samples). Pure: no files.

use serde::{Deserialize, Serialize};

use super::YarnMaterial;

/// The card format written ([`MaterialCard::format`]).
pub const CARD_FORMAT: &str = "knitvox-material-card";
/// The version written; readers refuse later ones.
pub const CARD_VERSION: u32 = 1;

/// One homogeneous knit material (Pa; stiffenings dimensionless).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CardMaterial {
    /// VH Eq. 7 shape stiffness `γs` (Pa).
    pub gamma_s_pa: f64,
    /// VH Eq. 7 volume stiffness `γv` (Pa).
    pub gamma_v_pa: f64,
    /// Course fibre small-strain stiffness `k` (Pa).
    pub course_pa: f64,
    /// Wale fibre small-strain stiffness `k` (Pa).
    pub wale_pa: f64,
    /// Course fibre stiffening `β` (energy `k V (ε² + β ε⁴ / 2)` in tension).
    pub course_beta: f64,
    /// Wale fibre stiffening `β`.
    pub wale_beta: f64,
}

impl CardMaterial {
    /// Every stiffness times `s` (the stiffenings are ratios and stay).
    pub fn scaled(&self, s: f64) -> CardMaterial {
        CardMaterial {
            gamma_s_pa: self.gamma_s_pa * s,
            gamma_v_pa: self.gamma_v_pa * s,
            course_pa: self.course_pa * s,
            wale_pa: self.wale_pa * s,
            ..*self
        }
    }
    fn fields(&self) -> [(&'static str, f64); 6] {
        [
            ("material.gamma_s_pa", self.gamma_s_pa),
            ("material.gamma_v_pa", self.gamma_v_pa),
            ("material.course_pa", self.course_pa),
            ("material.wale_pa", self.wale_pa),
            ("material.course_beta", self.course_beta),
            ("material.wale_beta", self.wale_beta),
        ]
    }
}

/// The stitch geometry a card was fitted at: what a transfer needs to keep
/// the fabric's stiffness per unit width on a mesh of another thickness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StitchGeometry {
    /// Yarn radius `r` (m).
    pub yarn_radius_m: f64,
    /// Yarn length per unit fabric area `λ` (1/m): the swatch's yarn length
    /// over its fabric area. The same stitch knitted `s` times larger has
    /// `λ / s`.
    pub yarn_length_per_area_per_m: f64,
    /// The swatch's fabric area (m², [`crate::embed::regions::fabric_area`]).
    pub fabric_area_m2: f64,
    /// The swatch mesh's volume over its fabric area `t` (m): the
    /// thickness its stiffnesses are spread over.
    pub mesh_thickness_m: f64,
    /// The swatch mesh's voxel edge (m).
    pub voxel_size_m: f64,
    /// The swatch's extent along its course and its wale (m).
    pub swatch_size_m: [f64; 2],
}

/// A training pose the card was fitted on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CardPose {
    /// Pose kind (`stretch_courses`, ...; schemas/yls-scene.md).
    pub kind: String,
    /// Amplitudes loaded through, in order.
    pub amounts: Vec<f64>,
    /// Load steps to each amplitude.
    pub steps: usize,
    /// Gravity along the fabric's normal (m/s²).
    pub gravity_m_s2: f64,
    /// SHA-256 of the pose file (hex).
    pub sha256: String,
}

/// How well the card's material carried the swatch on its training poses.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CardFit {
    /// RMS yarn distance (yarn diameters) of the mesh's equilibria from the
    /// yarn level over the fitted frames: at the card's material, at the
    /// placeholder material, and the floor no material can beat (Y2V).
    pub rms_yarn_diameters: f64,
    pub placeholder_rms_yarn_diameters: f64,
    pub floor_rms_yarn_diameters: f64,
    /// Relative clamp-force misfit of the card's material on the training
    /// poses (NaN-free; 0 where the poses record no reactions).
    pub force_misfit: f64,
    /// Position loss (m³, VH Eq. 10) at the card's material.
    pub loss_m3: f64,
    /// Wall time of training and fitting (s).
    pub seconds: f64,
}

/// Where a card came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CardProvenance {
    /// Built-in pattern name, grid file or swatch file the card was fitted on.
    pub swatch: String,
    /// SHA-256 of the swatch's yarn file (hex).
    pub swatch_sha256: String,
    /// Courses and wales of a generated swatch (0 for a given file).
    pub courses: usize,
    pub wales: usize,
    pub knitvox_version: String,
    pub command: String,
}

/// A material card.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialCard {
    /// Always [`CARD_FORMAT`].
    pub format: String,
    /// [`CARD_VERSION`] when written.
    pub version: u32,
    /// A name for reports (the pattern's, by default).
    pub name: String,
    pub material: CardMaterial,
    pub stitch: StitchGeometry,
    /// The yarn the swatch was knitted in (its rods and contact).
    pub yarn: CardYarn,
    /// Yarn-on-yarn friction coefficient of the training.
    pub friction: f64,
    pub poses: Vec<CardPose>,
    pub fit: CardFit,
    pub provenance: CardProvenance,
}

/// The yarn material of a card (as [`YarnMaterial`], with units in the names).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CardYarn {
    pub young_modulus_pa: f64,
    pub shear_modulus_pa: f64,
    pub bend_scale: f64,
    pub contact_stiffness_j_m2: f64,
}

impl From<YarnMaterial> for CardYarn {
    fn from(m: YarnMaterial) -> Self {
        CardYarn {
            young_modulus_pa: m.young_modulus,
            shear_modulus_pa: m.shear_modulus,
            bend_scale: m.bend_scale,
            contact_stiffness_j_m2: m.contact_stiffness,
        }
    }
}

/// What is wrong with a card's contents: the field (as in the file) and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {message}")]
pub struct CardError {
    pub field: String,
    pub message: String,
}

/// Largest stiffness a card may carry (Pa): far above any fabric (a yarn's
/// own Young's modulus is below 1e10), so a larger one is a broken file.
pub const MAX_CARD_STIFFNESS_PA: f64 = 1e12;
/// Largest stiffening: the fit's own bound ([`crate::sim::knit`] searches to 1e6).
pub const MAX_CARD_BETA: f64 = 1e7;

impl MaterialCard {
    /// Refuses what a transfer cannot use: another format or a later
    /// version, a stiffness that is not positive and finite or absurd, a
    /// geometry that is not positive.
    pub fn check(&self) -> Result<(), CardError> {
        let bad = |field: &str, message: String| CardError {
            field: field.into(),
            message,
        };
        if self.format != CARD_FORMAT {
            return Err(bad(
                "format",
                format!("{:?} is not {CARD_FORMAT:?}", self.format),
            ));
        }
        if self.version == 0 || self.version > CARD_VERSION {
            return Err(bad(
                "version",
                format!(
                    "version {} is not one this knitvox reads (1..={CARD_VERSION}); a later knitvox wrote it",
                    self.version
                ),
            ));
        }
        for (name, v) in self.material.fields() {
            let beta = name.ends_with("_beta");
            let max = if beta {
                MAX_CARD_BETA
            } else {
                MAX_CARD_STIFFNESS_PA
            };
            let ok = v.is_finite() && if beta { v >= 0.0 } else { v > 0.0 } && v <= max;
            if !ok {
                let want = if beta { "non-negative" } else { "positive" };
                return Err(bad(
                    name,
                    format!("{v} is not a {want} number up to {max:e}"),
                ));
            }
        }
        let s = &self.stitch;
        // 1 km bounds every length of a swatch; below 1 nm is no yarn.
        let lengths = [
            ("stitch.yarn_radius_m", s.yarn_radius_m),
            ("stitch.fabric_area_m2", s.fabric_area_m2),
            ("stitch.mesh_thickness_m", s.mesh_thickness_m),
            ("stitch.voxel_size_m", s.voxel_size_m),
            ("stitch.swatch_size_m[0]", s.swatch_size_m[0]),
            ("stitch.swatch_size_m[1]", s.swatch_size_m[1]),
        ];
        for (name, v) in lengths {
            if !(v.is_finite() && (1e-9..=1e3).contains(&v)) {
                return Err(bad(
                    name,
                    format!("{v} is not a length of a swatch (1 nm to 1 km)"),
                ));
            }
        }
        // A yarn between 1 nm and 1 km in radius fills its fabric with
        // lambda r between about 1e-3 and 1e3.
        let shape = s.yarn_length_per_area_per_m * s.yarn_radius_m;
        if !(shape.is_finite() && (1e-3..=1e3).contains(&shape)) {
            return Err(bad(
                "stitch.yarn_length_per_area_per_m",
                format!(
                    "{} per m at yarn radius {} m is no knit (yarn length per area times radius {shape:e}, \
                     knits lie near 1)",
                    s.yarn_length_per_area_per_m, s.yarn_radius_m
                ),
            ));
        }
        Ok(())
    }
}

/// How a card's stiffnesses are carried onto a garment's mesh.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CardScale {
    /// The garment region's fabric area (m²).
    pub fabric_area_m2: f64,
    /// Its yarn length per fabric area `λ` (1/m).
    pub yarn_length_per_area_per_m: f64,
    /// Its stitches' size over the card's, `λ_card / λ`, assuming the
    /// same stitch shape.
    pub stitch_scale: f64,
    /// The region mesh's volume over its fabric area `t` (m).
    pub mesh_thickness_m: f64,
    /// The factor on every stiffness: `(t_card / t) · stitch_scale`, so
    /// that the fabric's stretch stiffness per unit width (`γ t`, which a
    /// knit of the same stitch shape scales as its size: rods of radius
    /// `r` bent over loops of size `r`) is the card's, scaled.
    pub factor: f64,
}

/// The factor that keeps a card's stiffness per unit width on a garment
/// region with `yarn_length` (m) of yarn over `fabric_area` (m²) in a mesh
/// of volume `mesh_volume` (m³). On the card's own swatch it is 1.
pub fn card_scale(
    card: &StitchGeometry,
    yarn_length: f64,
    mesh_volume: f64,
    fabric_area: f64,
) -> CardScale {
    let lambda = yarn_length / fabric_area;
    let t = mesh_volume / fabric_area;
    let stitch_scale = card.yarn_length_per_area_per_m / lambda;
    CardScale {
        fabric_area_m2: fabric_area,
        yarn_length_per_area_per_m: lambda,
        stitch_scale,
        mesh_thickness_m: t,
        factor: (card.mesh_thickness_m / t) * stitch_scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry() -> StitchGeometry {
        StitchGeometry {
            yarn_radius_m: 1e-3,
            yarn_length_per_area_per_m: 300.0,
            fabric_area_m2: 9e-4,
            mesh_thickness_m: 4e-3,
            voxel_size_m: 2.3e-3,
            swatch_size_m: [0.03, 0.03],
        }
    }

    #[test]
    fn card_scale_is_one_on_the_cards_own_swatch() {
        let g = geometry();
        let a = g.fabric_area_m2;
        let s = card_scale(&g, 300.0 * a, 4e-3 * a, a);
        assert!((s.factor - 1.0).abs() < 1e-12, "{s:?}");
        assert!((s.stitch_scale - 1.0).abs() < 1e-12);
    }

    #[test]
    fn card_scale_keeps_stiffness_per_width_on_a_thicker_mesh_and_a_scaled_stitch() {
        let g = geometry();
        let a = 0.01;
        // The same stitch, a mesh twice as thick: half the stiffness.
        let s = card_scale(&g, 300.0 * a, 2.0 * 4e-3 * a, a);
        assert!((s.factor - 0.5).abs() < 1e-12, "{s:?}");
        // Stitches half the size (twice the yarn per area) on a mesh half as
        // thick: similar in every length, so the stiffness in Pa is the card's.
        let s = card_scale(&g, 600.0 * a, 2e-3 * a, a);
        assert!((s.stitch_scale - 0.5).abs() < 1e-12, "{s:?}");
        assert!((s.factor - 1.0).abs() < 1e-12, "{s:?}");
    }

    fn card() -> MaterialCard {
        MaterialCard {
            format: CARD_FORMAT.into(),
            version: CARD_VERSION,
            name: "t".into(),
            material: CardMaterial {
                gamma_s_pa: 60.0,
                gamma_v_pa: 180.0,
                course_pa: 0.03,
                wale_pa: 1.7,
                course_beta: 1.6e5,
                wale_beta: 1.5e4,
            },
            stitch: geometry(),
            yarn: CardYarn {
                young_modulus_pa: 5e5,
                shear_modulus_pa: 2e5,
                bend_scale: 0.3,
                contact_stiffness_j_m2: 60.0,
            },
            friction: 0.25,
            poses: Vec::new(),
            fit: CardFit {
                rms_yarn_diameters: 0.4,
                placeholder_rms_yarn_diameters: 1.3,
                floor_rms_yarn_diameters: 0.15,
                force_misfit: 0.1,
                loss_m3: 4e-6,
                seconds: 100.0,
            },
            provenance: CardProvenance {
                swatch: "stockinette".into(),
                swatch_sha256: String::new(),
                courses: 6,
                wales: 6,
                knitvox_version: "0".into(),
                command: String::new(),
            },
        }
    }

    #[test]
    fn card_check_refuses_later_versions_and_absurd_numbers() {
        assert_eq!(card().check(), Ok(()));
        let mut c = card();
        c.version = CARD_VERSION + 1;
        assert_eq!(c.check().unwrap_err().field, "version");
        let mut c = card();
        c.format = "something".into();
        assert_eq!(c.check().unwrap_err().field, "format");
        for (set, field) in [
            (0.0, "material.gamma_s_pa"),
            (f64::NAN, "material.gamma_s_pa"),
            (1e13, "material.gamma_s_pa"),
        ] {
            let mut c = card();
            c.material.gamma_s_pa = set;
            assert_eq!(c.check().unwrap_err().field, field, "{set}");
        }
        let mut c = card();
        c.material.wale_beta = -1.0;
        assert_eq!(c.check().unwrap_err().field, "material.wale_beta");
        // A stiffening of 0 is a quadratic fibre: allowed.
        let mut c = card();
        c.material.wale_beta = 0.0;
        assert_eq!(c.check(), Ok(()));
        let mut c = card();
        c.stitch.mesh_thickness_m = f64::INFINITY;
        assert_eq!(c.check().unwrap_err().field, "stitch.mesh_thickness_m");
        let mut c = card();
        c.stitch.yarn_length_per_area_per_m = 1e9;
        assert_eq!(
            c.check().unwrap_err().field,
            "stitch.yarn_length_per_area_per_m"
        );
    }
}
