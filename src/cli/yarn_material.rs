//! The yarn's material on the command line (`pattern`, `fabric-test`,
//! `train`): each option replaces one field of the material the yarns'
//! rest shape was relaxed under, or of the default yarn.

use clap::Args;

use super::parse::ValueError;
use crate::geom::{MaterialOverrides, YarnMaterial};
use crate::yarn::fabric::MaterialChoice;

/// A parser for field `i` of [`YarnMaterial::RANGES`]: a finite number in
/// its range, so an absurd value is a usage error naming the option.
fn in_range(i: usize) -> impl Fn(&str) -> Result<f64, ValueError> + Clone + Send + Sync + 'static {
    move |s: &str| {
        let (_, lo, hi) = YarnMaterial::RANGES[i];
        match s.trim().parse::<f64>() {
            Ok(v) if (lo..=hi).contains(&v) => Ok(v),
            _ => Err(ValueError::OutOfRange {
                text: crate::geom::excerpt(s),
                lo,
                hi,
            }),
        }
    }
}

/// Yarn material options. Without them a yarn file's recorded material
/// (the one its rest shape was relaxed under) applies, else the default
/// yarn: E 5e5 Pa, G 2e5 Pa, bend scale 0.3, contact stiffness 60 J/m^2.
#[derive(Debug, Clone, Default, Args)]
pub struct YarnMaterialArgs {
    /// Yarn Young's modulus E (Pa): stretch stiffness E pi r^2 per yarn;
    /// bending and twisting scale with it too (times --bend-scale).
    #[arg(long, value_name = "PA", value_parser = in_range(0))]
    pub young_modulus: Option<f64>,
    /// Yarn shear modulus G (Pa): twist stiffness --bend-scale x G pi r^4 / 2.
    #[arg(long, value_name = "PA", value_parser = in_range(1))]
    pub shear_modulus: Option<f64>,
    /// Bending and twisting stiffness relative to a solid rod of modulus E
    /// (HYLC's gamma): bending gamma E pi r^4 / 4 (N m^2). Lowering it with
    /// a raised --young-modulus keeps the bending and makes the yarn less
    /// extensible (real yarns are far stiffer in tension than a solid rod
    /// of their bending stiffness).
    #[arg(long, value_name = "GAMMA", value_parser = in_range(2))]
    pub bend_scale: Option<f64>,
    /// Kaldor contact stiffness (J/m^2).
    #[arg(long, value_name = "K", value_parser = in_range(3))]
    pub contact_stiffness: Option<f64>,
}

impl YarnMaterialArgs {
    pub fn overrides(&self) -> MaterialOverrides {
        MaterialOverrides {
            young_modulus: self.young_modulus,
            shear_modulus: self.shear_modulus,
            bend_scale: self.bend_scale,
            contact_stiffness: self.contact_stiffness,
        }
    }
}

/// The values, where they came from and what the command line set.
pub fn describe_choice(c: &MaterialChoice) -> String {
    let mut line = format!("{} ({}", c.material, c.source);
    if !c.overridden.is_empty() {
        line.push_str(&format!("; set here: {}", c.overridden.join(", ")));
    }
    line.push(')');
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::yarn::fabric::FabricParams;

    #[test]
    fn the_documented_default_yarn_is_the_default() {
        let m = FabricParams::default().material();
        assert_eq!(m, YarnMaterial::from_values([5e5, 2e5, 0.3, 60.0]));
        assert!(m.out_of_range().is_none());
    }

    #[test]
    fn ranges_are_enforced_per_field() {
        assert_eq!(in_range(0)("5e6"), Ok(5e6));
        for (i, bad) in [(0, "1e2"), (1, "1e13"), (2, "20"), (3, "nan"), (3, "x")] {
            assert!(in_range(i)(bad).is_err(), "{i} {bad}");
        }
    }
}
