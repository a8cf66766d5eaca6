//! Length units and up-axis conventions, and the conversions between them.

use std::fmt;
use std::str::FromStr;

use super::Vec3;

/// A length unit: how many metres one file unit is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Units {
    /// Metres per file unit (1.0 for metres, 0.01 for centimetres, 0.001 for millimetres).
    pub metres_per_unit: f64,
}

impl Units {
    pub const METRES: Units = Units {
        metres_per_unit: 1.0,
    };
    pub const CENTIMETRES: Units = Units {
        metres_per_unit: 0.01,
    };
    pub const MILLIMETRES: Units = Units {
        metres_per_unit: 0.001,
    };

    /// Builds a unit from a positive finite scale (metres per file unit).
    pub fn from_scale(metres_per_unit: f64) -> Option<Units> {
        (metres_per_unit.is_finite() && metres_per_unit > 0.0).then_some(Units { metres_per_unit })
    }

    /// Short name: `m`, `cm`, `mm`, or the scale itself.
    pub fn name(&self) -> String {
        let s = self.metres_per_unit;
        if s == 1.0 {
            "m".into()
        } else if s == 0.01 {
            "cm".into()
        } else if s == 0.001 {
            "mm".into()
        } else {
            format!("{s}")
        }
    }
}

impl fmt::Display for Units {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// A unit name that is neither `mm`, `cm`, `m` nor a positive number of
/// metres per unit.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown unit '{text}': expected mm, cm, m or a positive number of metres per unit")]
pub struct UnknownUnit {
    /// The name as given (cut to an excerpt).
    pub text: String,
}

impl FromStr for Units {
    type Err = UnknownUnit;
    /// Parses `mm`, `cm`, `m`, or a positive number of metres per file unit.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "m" | "metre" | "meter" | "metres" | "meters" => Ok(Units::METRES),
            "cm" => Ok(Units::CENTIMETRES),
            "mm" => Ok(Units::MILLIMETRES),
            other => other
                .parse::<f64>()
                .ok()
                .and_then(Units::from_scale)
                .ok_or_else(|| UnknownUnit {
                    text: super::excerpt(s),
                }),
        }
    }
}

/// Which file axis points up. knitvox's internal frame is +Y up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +Y up (glTF, Maya, knitvox internal).
    Y,
    /// +Z up (Blender, Houdini's option, most yarn swatch files).
    Z,
}

impl UpAxis {
    pub fn name(self) -> &'static str {
        match self {
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        }
    }

    /// Maps a point given in this up-axis convention into knitvox's +Y-up frame.
    /// Z-up -> Y-up is a -90 degree rotation about X: (x, y, z) -> (x, z, -y),
    /// the same right-handed mapping the Blender glTF exporter uses.
    #[inline]
    pub fn to_internal(self, p: Vec3) -> Vec3 {
        match self {
            UpAxis::Y => p,
            UpAxis::Z => [p[0], p[2], -p[1]],
        }
    }

    /// Inverse of [`UpAxis::to_internal`].
    #[inline]
    pub fn from_internal(self, p: Vec3) -> Vec3 {
        match self {
            UpAxis::Y => p,
            UpAxis::Z => [p[0], -p[2], p[1]],
        }
    }
}

impl fmt::Display for UpAxis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An up axis other than `y` and `z`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown up axis '{text}': expected y or z")]
pub struct UnknownUpAxis {
    /// The name as given (cut to an excerpt).
    pub text: String,
}

impl FromStr for UpAxis {
    type Err = UnknownUpAxis;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "y" | "+y" => Ok(UpAxis::Y),
            "z" | "+z" => Ok(UpAxis::Z),
            _ => Err(UnknownUpAxis {
                text: super::excerpt(s),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn up_axis_round_trip_and_is_rotation() {
        let p = [1.0, 2.0, 3.0];
        for a in [UpAxis::Y, UpAxis::Z] {
            assert_eq!(a.from_internal(a.to_internal(p)), p);
        }
        // Z-up "up" vector maps onto +Y.
        assert_eq!(UpAxis::Z.to_internal([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]);
        // Right-handedness kept: x cross y = z in both frames.
        let (x, y) = (
            UpAxis::Z.to_internal([1.0, 0.0, 0.0]),
            UpAxis::Z.to_internal([0.0, 1.0, 0.0]),
        );
        let z = [
            x[1] * y[2] - x[2] * y[1],
            x[2] * y[0] - x[0] * y[2],
            x[0] * y[1] - x[1] * y[0],
        ];
        assert_eq!(z, UpAxis::Z.to_internal([0.0, 0.0, 1.0]));
    }

    #[test]
    fn units_parse() {
        assert_eq!("cm".parse::<Units>().unwrap(), Units::CENTIMETRES);
        assert_eq!("0.0254".parse::<Units>().unwrap().metres_per_unit, 0.0254);
        assert!("-1".parse::<Units>().is_err());
        assert!("nan".parse::<Units>().is_err());
        assert!("furlong".parse::<Units>().is_err());
    }
}
