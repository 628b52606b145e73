//! Decimal numbers from bytes, read exactly as `str::parse::<f64>` reads them: plain
//! decimals by a fast path, anything else by fast-float2.

/// A decimal number as `str::parse::<f64>` reads it (correctly rounded): plain decimals
/// by [`plain_decimal`], anything else by fast-float2.
pub(super) fn parse_number(f: &[u8]) -> Option<f64> {
    plain_decimal(f).or_else(|| fast_float2::parse::<f64, _>(f).ok())
}

/// The exact powers of ten in f64, and as integers.
const POW10: [f64; 16] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
];
const POW10_INT: [u64; 16] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
    10_000_000_000,
    100_000_000_000,
    1_000_000_000_000,
    10_000_000_000_000,
    100_000_000_000_000,
    1_000_000_000_000_000,
];

/// A plain decimal of at most 15 significant digits (`-12.5`, `0.009615`, `541`), which
/// are nearly all a recording holds, as `str::parse::<f64>` reads it; `None` for anything
/// else. Its digits are an integer below 2⁵³ and the power of ten is exact, so one
/// division rounds correctly (Clinger's fast path).
fn plain_decimal(f: &[u8]) -> Option<f64> {
    leading_decimal(f)
        .filter(|(_, len)| *len == f.len())
        .map(|(x, _)| x)
}

/// The digits of `rest` from byte `i` on into `mant` (wrapping past 19 digits: callers
/// refuse so many), and the byte after them.
pub(super) fn leading_digits(rest: &[u8], mut i: usize, mant: &mut u64) -> usize {
    // Two at a time while there are two (half the steps, half the dependent
    // multiplications), then one.
    while let Some(&[a, b]) = rest.get(i..i + 2) {
        let (a, b) = (a.wrapping_sub(b'0'), b.wrapping_sub(b'0'));
        if a > 9 {
            return i;
        }
        if b > 9 {
            *mant = mant.wrapping_mul(10).wrapping_add(u64::from(a));
            return i + 1;
        }
        *mant = mant
            .wrapping_mul(100)
            .wrapping_add(u64::from(a) * 10 + u64::from(b));
        i += 2;
    }
    while let Some(d) = rest
        .get(i)
        .map(|b| b.wrapping_sub(b'0'))
        .filter(|d| *d <= 9)
    {
        *mant = mant.wrapping_mul(10).wrapping_add(u64::from(d));
        i += 1;
    }
    i
}

/// Where the field that starts `rest` ends: its comma or newline, or the end (two bytes
/// a step, as [`leading_digits`]).
pub(super) fn field_end(rest: &[u8]) -> usize {
    let ends = |b: u8| b == b',' || b == b'\n';
    let mut i = 0;
    while let Some(&[a, b]) = rest.get(i..i + 2) {
        if ends(a) {
            return i;
        }
        if ends(b) {
            return i + 1;
        }
        i += 2;
    }
    i + usize::from(rest.get(i).is_some_and(|b| !ends(*b)))
}

/// The plain decimal that starts `rest` (see [`plain_decimal`]) and its length: the digits
/// are read in the walk that finds the number's end (the byte after it is the caller's to
/// check). `None` when what starts `rest` is not one.
// Inlined into plain_row's loop: a call per number was 5 % more instructions per calibration.
#[inline(always)]
pub(super) fn leading_decimal(rest: &[u8]) -> Option<(f64, usize)> {
    let neg = rest.first() == Some(&b'-');
    let start = usize::from(neg);
    let mut mant = 0;
    let point = leading_digits(rest, start, &mut mant);
    let (int, whole) = (mant, point - start);
    let (len, frac) = if rest.get(point) == Some(&b'.') {
        let end = leading_digits(rest, point + 1, &mut mant);
        // A digit on each side of a point ("5." and ".5" go the long way).
        if whole == 0 || end == point + 1 {
            return None;
        }
        (end, end - point - 1)
    } else {
        (point, 0)
    };
    if whole + frac == 0 || whole + frac > 15 {
        return None;
    }
    // Exact digits, an exact power of ten, one rounding; no division when the digits
    // after the point are all 0 ("541.0"), the value then the integer part's (which the
    // quotient would be, exactly).
    let v = if mant == int.wrapping_mul(*POW10_INT.get(frac)?) {
        int as f64
    } else {
        mant as f64 / POW10.get(frac)?
    };
    Some((if neg { -v } else { v }, len))
}

#[cfg(test)]
mod tests {
    use super::{parse_number, POW10, POW10_INT};
    use proptest::prelude::*;

    #[test]
    fn the_powers_of_ten_are_the_powers_of_ten() {
        let mut p = 1u64;
        for (int, float) in POW10_INT.iter().zip(POW10) {
            assert_eq!(*int, p);
            assert_eq!(float.to_bits(), (p as f64).to_bits());
            p *= 10;
        }
    }

    /// As `str::parse::<f64>` reads it, bit for bit (any NaN for a NaN).
    fn same(s: &str) {
        let ours = parse_number(s.as_bytes());
        let std = s.parse::<f64>().ok();
        match (ours, std) {
            (Some(a), Some(b)) if a.is_nan() && b.is_nan() => {}
            (a, b) => assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{s:?}"),
        }
    }

    #[test]
    fn numbers_read_as_the_standard_library_reads_them() {
        for s in [
            "0",
            "-0",
            "-0.0",
            "541.0",
            "0.009615",
            "3599.990385",
            "+1.5",
            ".5",
            "5.",
            "1e3",
            "1E-3",
            "-1e-300",
            "nan",
            "inf",
            "-",
            "",
            ".",
            "1.2.3",
            "00012.500",
            "999999999999999",
            "9999999999999999",
            "0.000000000000001",
            "123456789012345.6",
            "1_0",
            " 1",
            "1 ",
        ] {
            same(s);
        }
    }

    proptest! {
        #[test]
        fn any_decimal_reads_as_the_standard_library_reads_it(
            s in "-?[0-9]{0,18}(\\.[0-9]{0,18})?([eE][-+]?[0-9]{1,3})?"
        ) {
            same(&s);
        }
    }
}
