//! Numbers as people read them, one rule for the pages (`report`, `index`)
//! and the figures (tick labels, colour bars, legends): a number keeps its
//! meaningful digits and no more, never reads `-0`, and switches to
//! `m×10ⁿ` outside [1e-3, 1e5) so that a column or an axis never mixes
//! `1e-5` with `0.00001`.

/// `v` with at most `digits` significant digits, trailing zeros trimmed:
/// plain in [1e-3, 1e5) (and 0), `m×10ⁿ` outside; a value that rounds to
/// zero is `0`, never `-0`. Infinite and NaN values read `∞`, `−∞`, `NaN`.
pub fn meaningful(v: f64, digits: usize) -> String {
    let digits = digits.max(1);
    if v.is_nan() {
        return "NaN".into();
    }
    if v.is_infinite() {
        return if v > 0.0 {
            "∞".into()
        } else {
            "−∞".into()
        };
    }
    if v == 0.0 {
        return "0".into();
    }
    // Rounded first: 99999.7 at 4 digits is 1.000×10⁵, not "100000".
    let rounded: f64 = format!("{v:.*e}", digits - 1).parse().unwrap_or(v);
    let e = rounded.abs().log10().floor() as i32;
    if (-3..5).contains(&e) {
        let decimals = (digits as i32 - 1 - e).max(0) as usize;
        let s = trim_zeros(format!("{rounded:.decimals$}"));
        if s == "-0" {
            "0".into()
        } else {
            s
        }
    } else {
        scientific(rounded, digits)
    }
}

/// `v` as `m×10ⁿ` with at most `digits` significant digits in m, trailing
/// zeros trimmed, `10ⁿ` when m is 1: the form of [`meaningful`] outside
/// [1e-3, 1e5), for every tick of an axis that reaches out of it.
pub fn scientific(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return meaningful(v, digits);
    }
    let s = format!("{:.*e}", digits.max(1) - 1, v);
    let (m, ex) = s.split_once('e').unwrap_or((&s, "0"));
    let m = trim_zeros(m.to_string());
    let ex = superscript(ex.parse().unwrap_or(0));
    match m.as_str() {
        "1" => format!("10{ex}"),
        "-1" => format!("-10{ex}"),
        _ => format!("{m}×10{ex}"),
    }
}

/// `n` and the noun, singular for exactly one: "1 iteration",
/// "3 iterations", "0 vertices".
pub fn count(n: u64, singular: &str, plural: &str) -> String {
    format!("{n} {}", if n == 1 { singular } else { plural })
}

/// A duration in seconds with 3 meaningful digits and its unit: `0.309 s`,
/// `2.5 ms`, `57.3 s`.
pub fn seconds(s: f64) -> String {
    if s.is_finite() && s > 0.0 && s < 1.0 {
        format!("{} ms", meaningful(1e3 * s, 3))
    } else {
        format!("{} s", meaningful(s, 3))
    }
}

/// An amount of memory given in MiB, with 3 meaningful digits, in GiB from
/// 1024 MiB on: `34.5 MiB`, `1.21 GiB`.
pub fn mebibytes(mib: f64) -> String {
    if mib >= 1024.0 {
        format!("{} GiB", meaningful(mib / 1024.0, 3))
    } else {
        format!("{} MiB", meaningful(mib, 3))
    }
}

/// The digits of `n` as superscripts (`-3` → `⁻³`).
pub fn superscript(n: i32) -> String {
    n.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            '0' => '⁰',
            '1' => '¹',
            '2' => '²',
            '3' => '³',
            '4' => '⁴',
            '5' => '⁵',
            '6' => '⁶',
            '7' => '⁷',
            '8' => '⁸',
            _ => '⁹',
        })
        .collect()
}

/// A decimal text without trailing zeros after its point (`0.2500` →
/// `0.25`, `3.000` → `3`); integers unchanged.
fn trim_zeros(s: String) -> String {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn meaningful_digits() {
        assert_eq!(meaningful(0.30936923800000005, 3), "0.309");
        assert_eq!(meaningful(0.30000000000000004, 4), "0.3");
        assert_eq!(meaningful(1234.6, 4), "1235");
        assert_eq!(meaningful(-0.0, 3), "0");
        assert_eq!(meaningful(-1e-20, 3), "-10⁻²⁰");
        assert_eq!(meaningful(-0.0001, 3), "-10⁻⁴");
        assert_eq!(meaningful(-0.00049, 1), "-5×10⁻⁴");
        assert_eq!(meaningful(1.5e-7, 4), "1.5×10⁻⁷");
        assert_eq!(meaningful(1e-3, 3), "0.001");
        assert_eq!(meaningful(99999.7, 4), "10⁵");
        assert_eq!(meaningful(28500.0, 4), "28500");
        assert_eq!(meaningful(2.3e-3, 2), "0.0023");
        assert_eq!(meaningful(1e-8, 2), "10⁻⁸");
        assert_eq!(meaningful(f64::NAN, 2), "NaN");
        assert_eq!(meaningful(f64::NEG_INFINITY, 2), "−∞");
        // Rounds to zero at the shown decimals: no "-0".
        assert_eq!(meaningful(-0.0004999, 1), "-5×10⁻⁴");
    }

    #[test]
    fn counts_and_units() {
        assert_eq!(count(1, "iteration", "iterations"), "1 iteration");
        assert_eq!(count(0, "vertex", "vertices"), "0 vertices");
        assert_eq!(count(803, "iteration", "iterations"), "803 iterations");
        assert_eq!(seconds(0.30936923800000005), "309 ms");
        assert_eq!(seconds(57.31), "57.3 s");
        assert_eq!(seconds(0.0), "0 s");
        assert_eq!(mebibytes(34.51), "34.5 MiB");
        assert_eq!(mebibytes(1240.0), "1.21 GiB");
        assert_eq!(superscript(-12), "⁻¹²");
    }
}
