//! Golden-section search of a function of one variable on an interval, as
//! the fit's one-parameter searches use it (the scale stage's `ln c`, the
//! knit material's stiffening `ln(1 + β)`).

/// Searches `[lo, hi]` for the smallest `f`: two evaluations at the golden
/// points, then `refinements` more, each keeping the part of the bracket
/// around the lower value (0.618 of it). Where the two inner values tie,
/// `ties_go_low` keeps the lower part. Returns the better of the last two
/// inner points and its value (the lower one on a tie when `ties_go_low`);
/// an error of `f` ends the search.
pub fn golden_section<E>(
    (mut lo, mut hi): (f64, f64),
    refinements: usize,
    ties_go_low: bool,
    mut f: impl FnMut(f64) -> Result<f64, E>,
) -> Result<(f64, f64), E> {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let left = |a: f64, b: f64| a < b || (ties_go_low && a == b);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1)?, f(x2)?);
    for _ in 0..refinements {
        if left(f1, f2) {
            (hi, x2, f2) = (x2, x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = f(x1)?;
        } else {
            (lo, x1, f1) = (x1, x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = f(x2)?;
        }
    }
    Ok(if left(f1, f2) { (x1, f1) } else { (x2, f2) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_minimum_of_a_parabola_to_the_bracket_it_leaves() {
        let mut calls = 0;
        let (x, fx) = golden_section((0.0, 10.0), 30, true, |x| {
            calls += 1;
            Ok::<_, ()>((x - 3.7).powi(2))
        })
        .unwrap();
        assert_eq!(calls, 32);
        // The bracket shrinks to 10 x 0.618^30, about 5e-6.
        assert!((x - 3.7).abs() < 1e-5, "{x}");
        assert!(fx < 1e-10);
        // An error of the function ends the search.
        let mut n = 0;
        let e = golden_section((0.0, 1.0), 10, false, |x| {
            n += 1;
            if n == 3 {
                Err("failed")
            } else {
                Ok(x)
            }
        });
        assert_eq!(e, Err("failed"));
        // Ties: both values infinite, the bracket goes low or high as asked.
        let lows = golden_section((0.0, 1.0), 5, true, |_| Ok::<_, ()>(f64::INFINITY)).unwrap();
        let highs = golden_section((0.0, 1.0), 5, false, |_| Ok::<_, ()>(f64::INFINITY)).unwrap();
        assert!(lows.0 < 0.1 && highs.0 > 0.9, "{lows:?} {highs:?}");
    }
}
