//! The field checks of the reference validator (`simpletrack.wire.fields`): each message is
//! checked field by field in table order (absent -> `missing_field`, wrong msgpack type ->
//! `wrong_type`, out of range / bad pattern / bad length -> `invalid_value`), then its unknown
//! keys in the map's order (`extra_field`; a `bin` key -> `invalid_value`).

use rmpv::ValueRef;

use super::reasons::ErrorReason;
use super::rejection::{Checked, Invalid};
use super::value::{bytes_repr, Key, Map};

pub(crate) type V<'v> = ValueRef<'v>;

pub const INT64_MAX: u64 = i64::MAX as u64;
pub const INT32_MAX: u64 = i32::MAX as u64;
/// Most entries of a class table, and the longest class name (characters).
pub const MAX_CLASSES: usize = 1024;
pub const MAX_CLASS_NAME: usize = 64;
pub const MAX_FRAME_ID: usize = 128;
/// The most frames one coalesced drop notice names (`FrameError.seqs`).
pub const MAX_NOTICE_SEQS: usize = 1024;

fn wrong_type(detail: &str) -> Invalid {
    Invalid::new(ErrorReason::WrongType, detail)
}

fn invalid(detail: impl Into<String>) -> Invalid {
    Invalid::new(ErrorReason::InvalidValue, detail)
}

fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

/// The value of a msgpack int (any width).
pub(crate) fn int_value(v: &V<'_>) -> Option<i128> {
    match v {
        ValueRef::Integer(i) => i
            .as_i64()
            .map(i128::from)
            .or_else(|| i.as_u64().map(i128::from)),
        _ => None,
    }
}

/// An int (not a bool, not a float) in `[lo, hi]`.
pub(crate) fn integer(v: &V<'_>, lo: i128, hi: i128) -> Checked<i128> {
    let n = int_value(v).ok_or_else(|| wrong_type("Input should be a valid integer"))?;
    if n < lo {
        return Err(invalid(format!(
            "Input should be greater than or equal to {lo}"
        )));
    }
    if n > hi {
        return Err(invalid(format!(
            "Input should be less than or equal to {hi}"
        )));
    }
    Ok(n)
}

/// 0 … 2^63−1, the range of every seq, stamp and id on the wire.
pub(crate) fn int64(v: &V<'_>) -> Checked<u64> {
    integer(v, 0, i128::from(INT64_MAX)).map(|n| n as u64)
}

/// A float; an int (any width) is accepted and widened; a bool is not a number.
pub(crate) fn number(v: &V<'_>) -> Checked<f64> {
    match v {
        ValueRef::F64(x) => Ok(*x),
        ValueRef::F32(x) => Ok(f64::from(*x)),
        _ => int_value(v)
            .map(|n| n as f64)
            .ok_or_else(|| wrong_type("Input should be a valid number")),
    }
}

pub(crate) fn boolean(v: &V<'_>) -> Checked<bool> {
    match v {
        ValueRef::Boolean(b) => Ok(*b),
        _ => Err(wrong_type("Input should be a valid boolean")),
    }
}

pub(crate) fn binary<'v>(v: &'v V<'_>) -> Checked<&'v [u8]> {
    match v {
        ValueRef::Binary(b) => Ok(b),
        _ => Err(wrong_type("Input should be a valid bytes")),
    }
}

/// A `str` of `min..=max` characters (Unicode scalar values, as the reference counts them).
pub(crate) fn string<'v>(v: &'v V<'_>, min: usize, max: Option<usize>) -> Checked<&'v str> {
    let s = match v {
        ValueRef::String(s) => s
            .as_str()
            .ok_or_else(|| wrong_type("Input should be a valid string"))?,
        _ => return Err(wrong_type("Input should be a valid string")),
    };
    check_length(s, min, max)?;
    Ok(s)
}

pub(crate) fn check_length(s: &str, min: usize, max: Option<usize>) -> Checked<()> {
    let n = s.chars().count();
    if n < min {
        return Err(invalid(format!(
            "String should have at least {min} character{}",
            plural(min)
        )));
    }
    if let Some(max) = max {
        if n > max {
            return Err(invalid(format!(
                "String should have at most {max} character{}",
                plural(max)
            )));
        }
    }
    Ok(())
}

/// The pattern of vehicle, sensor and instance ids: `^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$`.
pub const NAME_PATTERN: &str = r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$";

pub fn is_name(s: &str) -> bool {
    let b = s.as_bytes();
    !b.is_empty()
        && b.len() <= 64
        && (b[0].is_ascii_alphanumeric() || b[0] == b'_')
        && b[1..]
            .iter()
            .all(|&c| c.is_ascii_alphanumeric() || matches!(c, b'_' | b'.' | b'-'))
}

pub(crate) fn check_name(s: &str) -> Checked<()> {
    if is_name(s) {
        Ok(())
    } else {
        Err(invalid(format!(
            "String should match pattern '{NAME_PATTERN}'"
        )))
    }
}

pub(crate) fn name<'v>(v: &'v V<'_>) -> Checked<&'v str> {
    let s = string(v, 0, None)?;
    check_name(s)?;
    Ok(s)
}

pub(crate) fn nullable<'v, T>(
    v: &'v V<'_>,
    check: impl FnOnce(&'v V<'_>) -> Checked<T>,
) -> Checked<Option<T>> {
    match v {
        ValueRef::Nil => Ok(None),
        _ => check(v).map(Some),
    }
}

/// A list: too long is refused before its items are looked at, too short after them.
pub(crate) fn array<'v, T>(
    v: &'v V<'_>,
    min: usize,
    max: Option<usize>,
    mut item: impl FnMut(&'v V<'_>) -> Checked<T>,
) -> Checked<Vec<T>> {
    let items = match v {
        ValueRef::Array(items) => items,
        _ => return Err(wrong_type("Input should be a valid list")),
    };
    let n = items.len();
    if let Some(max) = max {
        if n > max {
            return Err(invalid(format!(
                "List should have at most {max} item{} after validation, not {n}",
                plural(max)
            )));
        }
    }
    let out = items
        .iter()
        .enumerate()
        .map(|(i, x)| item(x).map_err(|e| e.within(i)))
        .collect::<Checked<Vec<T>>>()?;
    if n < min {
        return Err(invalid(format!(
            "List should have at least {min} item{} after validation, not {n}",
            plural(min)
        )));
    }
    Ok(out)
}

/// One of an enumeration's strings (a UTF-8 `bin` holding one is read too); else
/// `invalid_value` listing them, as the reference decoder words it.
pub(crate) fn one_of<T: Copy>(v: &V<'_>, all: &[T], name: fn(T) -> &'static str) -> Checked<T> {
    let text = match v {
        ValueRef::String(s) => s.as_str(),
        ValueRef::Binary(b) => std::str::from_utf8(b).ok(),
        _ => None,
    };
    if let Some(found) = text.and_then(|t| all.iter().copied().find(|&x| name(x) == t)) {
        return Ok(found);
    }
    let names: Vec<String> = all.iter().map(|&x| format!("'{}'", name(x))).collect();
    let (last, head) = names.split_last().unwrap_or((&names[0], &[]));
    Err(invalid(format!(
        "Input should be {} or {last}",
        head.join(", ")
    )))
}

pub(crate) fn map_of<'v>(v: &'v V<'v>, type_name: &str) -> Checked<Map<'v>> {
    match v {
        ValueRef::Map(pairs) => Ok(Map::of(pairs)),
        _ => Err(wrong_type(&format!(
            "Input should be a valid dictionary or instance of {type_name}"
        ))),
    }
}

/// One map being checked: ask for its fields in table order, then `finish()`.
pub(crate) struct Fields<'v> {
    map: Map<'v>,
    names: Vec<&'v str>,
    present: usize,
}

impl<'v> Fields<'v> {
    pub fn new(v: &'v V<'v>, type_name: &str) -> Checked<Self> {
        Ok(Self {
            map: map_of(v, type_name)?,
            names: Vec::new(),
            present: 0,
        })
    }

    fn take(&mut self, name: &'static str) -> Option<&'v V<'v>> {
        self.names.push(name);
        let v = self.map.get(name);
        if v.is_some() {
            self.present += 1;
        }
        v
    }

    pub fn required<T>(
        &mut self,
        name: &'static str,
        check: impl FnOnce(&'v V<'v>) -> Checked<T>,
    ) -> Checked<T> {
        match self.take(name) {
            None => Err(Invalid::at(
                ErrorReason::MissingField,
                name,
                "Field required",
            )),
            Some(v) => check(v).map_err(|e| e.within(name)),
        }
    }

    pub fn optional<T>(
        &mut self,
        name: &'static str,
        default: T,
        check: impl FnOnce(&'v V<'v>) -> Checked<T>,
    ) -> Checked<T> {
        match self.take(name) {
            None => Ok(default),
            Some(v) => check(v).map_err(|e| e.within(name)),
        }
    }

    /// Unknown keys, in the map's order.
    pub fn finish(self) -> Checked<()> {
        if self.map.len() <= self.present {
            return Ok(());
        }
        for key in self.map.keys() {
            match key {
                Key::Bin(b) => {
                    return Err(Invalid::at(
                        ErrorReason::InvalidValue,
                        &bytes_repr(b),
                        "Keys should be strings",
                    ))
                }
                Key::Str(s) if !self.names.contains(&s) => {
                    return Err(Invalid::at(
                        ErrorReason::ExtraField,
                        s,
                        "Extra inputs are not permitted",
                    ))
                }
                Key::Str(_) => {}
            }
        }
        Ok(())
    }
}
