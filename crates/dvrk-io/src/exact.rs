//! Fixed-size arrays read from a file, with their length checked exactly.
//!
//! serde's `[T; N]` reads N elements and stops; the `toml` crate does not check that no more
//! follow, so a 4x5 coupling matrix was read as its 4x4 part (issue 22). The coupling matrix is
//! read through [`matrix`], which refuses any other shape with "invalid length 5, expected an
//! array of exactly 4 values"; the format adds the field and the line. (dvrk-compliance has the
//! same helper for its files: the two crates may not import each other, ARCHITECTURE.md.)

use core::fmt;
use core::marker::PhantomData;

use serde::de::{Deserialize, Deserializer, Error, SeqAccess, Visitor};

/// A `[T; N]` whose input must have exactly N elements.
struct Exact<T, const N: usize>([T; N]);

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

/// `deserialize_with` for a `[[T; C]; R]` field: exactly R rows of exactly C elements.
pub(crate) fn matrix<'de, D, T, const R: usize, const C: usize>(
    d: D,
) -> Result<[[T; C]; R], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    let rows = Exact::<Exact<T, C>, R>::deserialize(d)?;
    Ok(rows.0.map(|r| r.0))
}

#[cfg(test)]
mod tests {
    #[derive(Debug, serde::Deserialize)]
    struct T {
        #[serde(deserialize_with = "super::matrix")]
        m: [[f64; 2]; 2],
    }

    #[test]
    fn only_the_exact_shape_is_read() {
        let t: T = toml::from_str("m = [[1.0, 0.0], [0.0, 1.0]]").unwrap();
        assert_eq!(t.m, [[1.0, 0.0], [0.0, 1.0]]);
        for (text, given) in [
            ("m = [[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]", 3),
            ("m = [[1.0, 0.0], [0.0, 1.0, 2.0]]", 3),
            ("m = [[1.0, 0.0]]", 1),
        ] {
            let mut e = toml::from_str::<T>(text).unwrap_err();
            e.set_input(None);
            let e = e.to_string();
            assert!(
                e.contains(&format!(
                    "invalid length {given}, expected an array of exactly 2"
                )) && e.contains("in `m`"),
                "{text}: {e}"
            );
        }
    }
}
