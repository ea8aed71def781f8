//! Fixed-size arrays read from a file, with their length checked exactly.
//!
//! serde's `[T; N]` reads N elements and stops: whether the input had more is left to the
//! format, and the `toml` crate does not check it, so `[1.0, 2.0, 3.0, 4.0, 5.0]` read as a
//! `[f64; 4]` silently drops the 5 (issue 22). Every fixed-size array of a parameter file is
//! therefore read through [`array()`] (or [`matrix`], [`option_matrix`]), which refuses any other
//! length with "invalid length 5, expected exactly 4 values"; the format adds the field
//! (`toml`: "in `joint.inverse_compliance_nm_per_rad`") and the line.
//!
//! ```ignore
//! #[serde(deserialize_with = "crate::exact::array")]
//! pub insertion_range_m: [f64; 2],
//! ```

use core::fmt;
use core::marker::PhantomData;

use serde::de::{Deserialize, Deserializer, Error, SeqAccess, Visitor};

/// A `[T; N]` whose input must have exactly N elements.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exact<T, const N: usize>(pub [T; N]);

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exact<T, N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T, const N: usize>(PhantomData<T>);
        impl<'de, T: Deserialize<'de>, const N: usize> Visitor<'de> for V<T, N> {
            type Value = Exact<T, N>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "an array of exactly {N} values")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut items = Vec::with_capacity(N);
                while let Some(x) = seq.next_element::<T>()? {
                    items.push(x);
                }
                let given = items.len();
                items
                    .try_into()
                    .map(Exact)
                    .map_err(|_| A::Error::invalid_length(given, &self))
            }
        }
        d.deserialize_seq(V::<T, N>(PhantomData))
    }
}

/// `deserialize_with` for a `[T; N]` field: exactly N elements.
pub fn array<'de, D, T, const N: usize>(d: D) -> Result<[T; N], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Exact::<T, N>::deserialize(d).map(|e| e.0)
}

/// `deserialize_with` for a `[[T; C]; R]` field: exactly R rows of exactly C elements.
pub fn matrix<'de, D, T, const R: usize, const C: usize>(d: D) -> Result<[[T; C]; R], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    let rows = Exact::<Exact<T, C>, R>::deserialize(d)?;
    Ok(rows.0.map(|r| r.0))
}

/// `deserialize_with` for an `Option<[[T; C]; R]>` field (with `#[serde(default)]`).
pub fn option_matrix<'de, D, T, const R: usize, const C: usize>(
    d: D,
) -> Result<Option<[[T; C]; R]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    let rows = Option::<Exact<Exact<T, C>, R>>::deserialize(d)?;
    Ok(rows.map(|m| m.0.map(|r| r.0)))
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct T {
        #[serde(deserialize_with = "super::array")]
        a: [f64; 2],
        #[serde(default, deserialize_with = "super::option_matrix")]
        m: Option<[[f64; 2]; 2]>,
    }

    #[test]
    fn exact_lengths_pass() {
        let t: T = toml::from_str("a = [1.0, 2.0]\nm = [[1.0, 0.0], [0.0, 1.0]]").unwrap();
        assert_eq!(t.a, [1.0, 2.0]);
        assert_eq!(t.m, Some([[1.0, 0.0], [0.0, 1.0]]));
        let t: T = toml::from_str("a = [1.0, 2.0]").unwrap();
        assert_eq!(t.m, None);
    }

    #[test]
    fn extra_and_missing_values_are_refused_with_field_and_lengths() {
        for (text, given, key) in [
            ("a = [1.0, 2.0, 3.0]", "3", "a"),
            ("a = [1.0]", "1", "a"),
            (
                "a = [1.0, 2.0]\nm = [[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]",
                "3",
                "m",
            ),
            (
                "a = [1.0, 2.0]\nm = [[1.0, 0.0, 5.0], [0.0, 1.0]]",
                "3",
                "m",
            ),
        ] {
            let mut e = toml::from_str::<T>(text).unwrap_err();
            e.set_input(None);
            let e = e.to_string();
            assert!(
                e.contains(&format!(
                    "invalid length {given}, expected an array of exactly 2"
                )) && e.contains(&format!("in `{key}`")),
                "{text}: {e}"
            );
        }
    }
}
