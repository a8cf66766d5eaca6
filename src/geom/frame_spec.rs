//! Frame specs as farm schedulers write them: `1001-1100`, `1-100x5`, `1,5,7-20`.

use std::fmt;
use std::str::FromStr;

/// A parsed frame spec: comma-separated items, each `N`, `A-B` or `A-BxS` (step S).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameSpec {
    items: Vec<(i64, i64, i64)>,
    text: String,
}

/// Largest number of frames a spec may expand to (guards `1-99999999999`).
pub const MAX_SPEC_FRAMES: u64 = 10_000_000;

/// Largest magnitude of a frame number (a spec item, `--first-frame`): far
/// beyond any shot, and small enough that no frame arithmetic overflows
/// (`--frames 9223372036854775807` would wrap `i64`).
pub const MAX_FRAME_NUMBER: i64 = 1_000_000_000;

/// A frame number beyond [`MAX_FRAME_NUMBER`]; `what` names it
/// (`--first-frame`, a spec's frame).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{what} {frame} is beyond the supported frame numbers (-{max} to {max})", max = MAX_FRAME_NUMBER)]
pub struct FrameNumberError {
    /// What the number is.
    pub what: String,
    /// The number.
    pub frame: i64,
}

/// Why a frame spec does not parse; `spec` is the spec as given (cut to
/// an excerpt), `item` the item at fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameSpecError {
    /// An empty item between commas.
    #[error("frame spec '{spec}': empty item")]
    EmptyItem { spec: String },
    /// The step after `x` is not a number.
    #[error("frame spec '{spec}': bad step in '{item}'")]
    BadStep { spec: String, item: String },
    /// A step below 1.
    #[error("frame spec '{spec}': step must be at least 1 in '{item}'")]
    StepBelowOne { spec: String, item: String },
    /// An end of a range that is not a frame number.
    #[error("frame spec '{spec}': '{text}' is not a frame number")]
    NotAFrame { spec: String, text: String },
    /// A frame number beyond [`MAX_FRAME_NUMBER`].
    #[error(transparent)]
    FrameNumber(#[from] FrameNumberError),
    /// A step larger than `limit`.
    #[error("frame spec '{spec}': step {step} is larger than the limit of {limit}")]
    StepTooLarge { spec: String, step: i64, limit: i64 },
    /// A range whose end comes before its start.
    #[error("frame spec '{spec}': range '{item}' runs backwards")]
    Backwards { spec: String, item: String },
    /// The spec selects more than [`MAX_SPEC_FRAMES`] frames.
    #[error("frame spec '{spec}' selects more than {MAX_SPEC_FRAMES} frames")]
    TooManyFrames { spec: String },
}

/// Checks a frame number against [`MAX_FRAME_NUMBER`]; the error names `what`.
pub fn check_frame_number(what: &str, f: i64) -> Result<i64, FrameNumberError> {
    if f.unsigned_abs() > MAX_FRAME_NUMBER as u64 {
        return Err(FrameNumberError {
            what: what.to_string(),
            frame: f,
        });
    }
    Ok(f)
}

impl FrameSpec {
    /// The frames in spec order, duplicates removed (first occurrence kept).
    pub fn frames(&self) -> Vec<i64> {
        let mut seen = std::collections::BTreeSet::new();
        let mut out = Vec::new();
        for &(a, b, s) in &self.items {
            let mut f = a;
            // Parsing bounds a, b and s by MAX_FRAME_NUMBER and the
            // count by MAX_SPEC_FRAMES, so this never overflows.
            while f <= b {
                if seen.insert(f) {
                    out.push(f);
                }
                f += s;
            }
        }
        out
    }

    /// A spec selecting every frame in `0..n`.
    pub fn all(n: usize) -> FrameSpec {
        if n == 0 {
            return FrameSpec {
                items: Vec::new(),
                text: String::new(),
            };
        }
        FrameSpec {
            items: vec![(0, n as i64 - 1, 1)],
            text: format!("0-{}", n - 1),
        }
    }
}

impl fmt::Display for FrameSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

impl FromStr for FrameSpec {
    type Err = FrameSpecError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut items = Vec::new();
        let mut total: u64 = 0;
        let spec = super::excerpt(s);
        for raw in s.split(',') {
            let item = raw.trim();
            let shown_item = super::excerpt(item);
            if item.is_empty() {
                return Err(FrameSpecError::EmptyItem { spec });
            }
            let (range, step) = match item.split_once(['x', 'X', ':']) {
                Some((r, st)) => (
                    r,
                    st.trim()
                        .parse::<i64>()
                        .map_err(|_| FrameSpecError::BadStep {
                            spec: spec.clone(),
                            item: shown_item.clone(),
                        })?,
                ),
                None => (item, 1),
            };
            if step < 1 {
                return Err(FrameSpecError::StepBelowOne {
                    spec,
                    item: shown_item,
                });
            }
            // A leading '-' is a negative frame number, not a range separator.
            let split_at = range
                .char_indices()
                .skip(1)
                .find(|&(_, c)| c == '-')
                .map(|(i, _)| i);
            let (a, b) = match split_at {
                Some(i) => (&range[..i], &range[i + 1..]),
                None => (range, range),
            };
            let parse = |t: &str| {
                t.trim()
                    .parse::<i64>()
                    .map_err(|_| FrameSpecError::NotAFrame {
                        spec: spec.clone(),
                        text: super::excerpt(t),
                    })
            };
            let (a, b) = (parse(a)?, parse(b)?);
            for f in [a, b] {
                check_frame_number(&format!("frame spec '{spec}': frame"), f)?;
            }
            if step > 2 * MAX_FRAME_NUMBER {
                return Err(FrameSpecError::StepTooLarge {
                    spec,
                    step,
                    limit: 2 * MAX_FRAME_NUMBER,
                });
            }
            if b < a {
                return Err(FrameSpecError::Backwards {
                    spec,
                    item: shown_item,
                });
            }
            // |a|, |b| <= 1e9 and step <= 2e9: no overflow.
            total = total.saturating_add(((b - a) / step + 1) as u64);
            if total > MAX_SPEC_FRAMES {
                return Err(FrameSpecError::TooManyFrames { spec });
            }
            items.push((a, b, step));
        }
        Ok(FrameSpec {
            items,
            text: s.trim().to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn farm_style_specs() {
        let f = |s: &str| s.parse::<FrameSpec>().unwrap().frames();
        assert_eq!(f("1001-1004"), vec![1001, 1002, 1003, 1004]);
        assert_eq!(f("1-10x3"), vec![1, 4, 7, 10]);
        assert_eq!(f("1,5,7-9"), vec![1, 5, 7, 8, 9]);
        assert_eq!(f("3,1-3"), vec![3, 1, 2]);
        assert_eq!(f("-2--1"), vec![-2, -1]);
        assert_eq!(f("7"), vec![7]);
        for bad in [
            "",
            "1-",
            "a",
            "5-1",
            "1-10x0",
            "1,,2",
            "0-99999999999",
            "9223372036854775807",
            "-9223372036854775808-9223372036854775807",
            "-9223372036854775807-9223372036854775807x9223372036854775807",
            "1-5x9223372036854775807",
        ] {
            assert!(bad.parse::<FrameSpec>().is_err(), "{bad}");
        }
        assert_eq!(FrameSpec::all(3).frames(), vec![0, 1, 2]);
        let e = "9223372036854775807"
            .parse::<FrameSpec>()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("9223372036854775807") && e.contains("1000000000"),
            "{e}"
        );
        assert_eq!(f("999999999-1000000000"), vec![999_999_999, 1_000_000_000]);
    }
}
