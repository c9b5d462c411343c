//! How some values are written and read: numbers that may be non-finite (written as `null`,
//! read back as NaN), and strategies by name.

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serializer};

use crate::resolve::Strategy;

/// Every strategy, in the order `describe` lists them.
pub const STRATEGIES: [Strategy; 2] = [Strategy::Overall, Strategy::Sequential];

/// The strategy of this name; `None` for a name this version does not know.
pub fn strategy_named(name: &str) -> Option<Strategy> {
    STRATEGIES.into_iter().find(|s| s.name() == name)
}

/// Where a strategy stands in [`STRATEGIES`]: the exhaustive match makes a new strategy fail
/// to compile until it is listed.
#[cfg(test)]
pub(super) fn strategy_index(strategy: Strategy) -> usize {
    match strategy {
        Strategy::Overall => 0,
        Strategy::Sequential => 1,
    }
}

/// A [`Strategy`] as its name.
pub(super) mod strategy {
    use super::*;

    pub fn serialize<S: Serializer>(strategy: &Strategy, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(strategy.name())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Strategy, D::Error> {
        let name = std::borrow::Cow::<str>::deserialize(d)?;
        strategy_named(&name).ok_or_else(|| D::Error::custom(format!("unknown strategy `{name}`")))
    }
}

/// A list of [`Strategy`]s as their names.
pub(super) mod strategies {
    use serde::ser::SerializeSeq;

    use super::*;

    pub fn serialize<S: Serializer>(list: &[Strategy], s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(list.len()))?;
        for strategy in list {
            seq.serialize_element(strategy.name())?;
        }
        seq.end()
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Strategy>, D::Error> {
        Vec::<String>::deserialize(d)?
            .iter()
            .map(|name| {
                strategy_named(name)
                    .ok_or_else(|| D::Error::custom(format!("unknown strategy `{name}`")))
            })
            .collect()
    }
}

/// A number written as `null` when it is not finite (as serde_json writes one), read back as
/// NaN.
pub(super) mod number {
    use super::*;

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}

/// An `[x, y]` pair of [`number`]s.
pub(super) mod point {
    use super::*;

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
        let [x, y] = <[Option<f64>; 2]>::deserialize(d)?;
        Ok([x.unwrap_or(f64::NAN), y.unwrap_or(f64::NAN)])
    }
}

/// An optional `[x, y]` pair of [`number`]s (`null` for none).
pub(super) mod optional_point {
    use super::*;

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
        Ok(Option::<[Option<f64>; 2]>::deserialize(d)?
            .map(|[x, y]| [x.unwrap_or(f64::NAN), y.unwrap_or(f64::NAN)]))
    }
}

/// A list of [`number`]s.
pub(super) mod numbers {
    use super::*;

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Ok(Vec::<Option<f64>>::deserialize(d)?
            .into_iter()
            .map(|x| x.unwrap_or(f64::NAN))
            .collect())
    }
}
