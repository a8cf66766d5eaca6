//! Value parsers of command-line options: checked before any work, each
//! error naming what it expected.

/// Why an option value was refused; `text` is the value as given (cut to
/// an excerpt where it may be long).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ValueError {
    /// Not a byte count with an optional K, M, G or T suffix.
    #[error("'{text}': expected BYTES with an optional K, M, G or T suffix, e.g. 4G")]
    Bytes { text: String },
    /// A byte count below 1 byte or not below 2^64.
    #[error("'{text}': the budget must be at least 1 byte and below 2^64")]
    BytesRange { text: String },
    /// Not a finite number > 0.
    #[error("'{text}': expected a finite number > 0")]
    NotPositive { text: String },
    /// Not a finite number >= 0.
    #[error("'{text}': expected a finite number >= 0")]
    Negative { text: String },
    /// Not a number from 0 to 1.
    #[error("'{text}': expected a number from 0 to 1")]
    NotFraction { text: String },
    /// Not an integer from 1 to `max`.
    #[error("'{text}': expected an integer from 1 to {max}")]
    IntegerRange { text: String, max: usize },
    /// Not of the form `NxM`.
    #[error("'{text}': expected NxM, e.g. 3x3")]
    TileSyntax { text: String },
    /// An `NxM` with N or M outside 1 to 10000.
    #[error("'{text}': expected NxM with N and M between 1 and 10000")]
    TileRange { text: String },
    /// Not three comma-separated numbers.
    #[error("'{text}': expected X,Y,Z")]
    Vec3Syntax { text: String },
    /// Three numbers, not all finite, or another count of numbers.
    #[error("'{text}': expected three finite numbers X,Y,Z")]
    Vec3Values { text: String },
    /// Not a number in `[lo, hi]`.
    #[error("'{text}': expected a number in [{lo:e}, {hi:e}]")]
    OutOfRange { text: String, lo: f64, hi: f64 },
    /// A harmonic rank that is not a whole number.
    #[error("'{text}' is not a rank (a whole number, e.g. 1,10,30)")]
    Rank { text: String },
    /// A harmonic rank above 10000.
    #[error("rank {rank} is above 10000")]
    RankTooLarge { rank: usize },
    /// A prior weight that is not a finite number >= 0.
    #[error("{text:?}: a number >= 0")]
    Prior { text: String },
    /// A stall decrease that is not a fraction in `[0, 1)`.
    #[error("'{text}' is not a stall decrease (a fraction in [0, 1))")]
    Stall { text: String },
    /// A contrast factor that is not a number >= 1.
    #[error("'{text}' is not a contrast factor (a number >= 1, or inf)")]
    Contrast { text: String },
}

/// Parses a byte count with an optional binary suffix: `4096`, `512K`,
/// `512M`, `4G`, `1T` (also `MB`, `MiB`, ...).
pub fn parse_bytes(s: &str) -> Result<u64, ValueError> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, suffix) = t.split_at(split);
    let shift = match suffix.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => {
            return Err(ValueError::Bytes {
                text: s.to_string(),
            })
        }
    };
    let v: f64 = num.parse().map_err(|_| ValueError::Bytes {
        text: s.to_string(),
    })?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(ValueError::BytesRange {
            text: s.to_string(),
        });
    }
    Ok(bytes as u64)
}

/// A finite number > 0 (lengths, densities, weights), checked by clap so a
/// bad value is a usage error naming the option.
pub fn parse_positive(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(ValueError::NotPositive {
            text: crate::geom::excerpt(s),
        }),
    }
}

/// A finite number >= 0.
pub fn parse_non_negative(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(ValueError::Negative {
            text: crate::geom::excerpt(s),
        }),
    }
}

/// A fraction in [0, 1].
pub fn parse_fraction(s: &str) -> Result<f64, ValueError> {
    match s.trim().parse::<f64>() {
        Ok(v) if (0.0..=1.0).contains(&v) => Ok(v),
        _ => Err(ValueError::NotFraction {
            text: crate::geom::excerpt(s),
        }),
    }
}

/// BCC spline samples per span: 1 to `io::bcc::MAX_SPLINE_SAMPLES`.
pub fn parse_spline_samples(s: &str) -> Result<usize, ValueError> {
    let max = crate::io::bcc::MAX_SPLINE_SAMPLES;
    match s.trim().parse::<usize>() {
        Ok(v) if (1..=max).contains(&v) => Ok(v),
        _ => Err(ValueError::IntegerRange {
            text: crate::geom::excerpt(s),
            max,
        }),
    }
}

/// Parses `--tile NxM` (each between 1 and 10000).
pub fn parse_tile(s: &str) -> Result<[usize; 2], ValueError> {
    let (a, b) = s
        .to_ascii_lowercase()
        .split_once('x')
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .ok_or_else(|| ValueError::TileSyntax {
            text: s.to_string(),
        })?;
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|n| (1..=crate::io::MAX_TILE_REPEATS).contains(n))
    };
    match (parse(&a), parse(&b)) {
        (Some(n), Some(m)) => Ok([n, m]),
        _ => Err(ValueError::TileRange {
            text: s.to_string(),
        }),
    }
}
