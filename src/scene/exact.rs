//! Fixed-length arrays in scene files take exactly their length: serde's arrays stop reading
//! after N values and would silently drop the rest (`size = [0.02, 0.01, 0.01, 0.5]`).
//! Use with `#[serde(deserialize_with = "…")]` on spec fields.

use serde::de::Error;
use serde::{Deserialize, Deserializer};

fn fixed<E: Error, T, const N: usize>(v: Vec<T>) -> Result<[T; N], E> {
    let n = v.len();
    v.try_into()
        .map_err(|_| E::invalid_length(n, &format!("an array of {N} values").as_str()))
}

/// `[T; N]`: exactly N values.
pub fn array<'de, D, T, const N: usize>(d: D) -> Result<[T; N], D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    fixed(Vec::<T>::deserialize(d)?)
}

/// `Option<[T; N]>` (with `#[serde(default)]`): exactly N values when given.
pub fn option<'de, D, T, const N: usize>(d: D) -> Result<Option<[T; N]>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<Vec<T>>::deserialize(d)?.map(fixed).transpose()
}

/// `Option<Vec<[T; N]>>` (with `#[serde(default)]`): rows of exactly N values.
pub fn option_rows<'de, D, T, const N: usize>(d: D) -> Result<Option<Vec<[T; N]>>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<Vec<Vec<T>>>::deserialize(d)?
        .map(|rows| rows.into_iter().map(fixed).collect())
        .transpose()
}
