//! Numbers in messages: a value the user gave, echoed in an error, at a readable length.

/// A number for an error message: plain when of a usual size, else in scientific notation (so
/// `--seconds 1e308` is echoed as `1e308`, not as 309 digits).
pub fn num(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::num;

    #[test]
    fn usual_sizes_print_plain_and_the_rest_in_scientific_notation() {
        for (v, shown) in [
            (0.0, "0"),
            (-1.0, "-1"),
            (3600.5, "3600.5"),
            (0.05, "0.05"),
            (999_999.0, "999999"),
            (1e308, "1e308"),
            (-2.5e6, "-2.5e6"),
            (1e-300, "1e-300"),
            (f64::INFINITY, "inf"),
            (f64::NAN, "NaN"),
        ] {
            assert_eq!(num(v), shown, "{v:?}");
        }
    }
}
