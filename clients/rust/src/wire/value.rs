//! Reading a payload into a msgpack value tree with the reference decoder's strictness:
//! anything its msgpack reader refuses (trailing bytes, invalid UTF-8 anywhere, map keys
//! other than `str`/`bin`, a broken timestamp extension) is `malformed`.

use std::collections::HashMap;

use rmpv::ValueRef;

use super::reasons::ErrorReason;
use super::rejection::{Checked, Invalid};

/// A map key as the reference decoder sees it: a string, or bytes (a `bin` key).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Key<'a> {
    Str(&'a str),
    Bin(&'a [u8]),
}

/// A decoded map: keys in first-seen order, a repeated key keeps its first place and its
/// last value (what a Python dict built from the pairs holds).
pub(crate) struct Map<'v> {
    entries: Vec<(Key<'v>, &'v ValueRef<'v>)>,
}

impl<'v> Map<'v> {
    pub fn of(pairs: &'v [(ValueRef<'v>, ValueRef<'v>)]) -> Self {
        let mut entries: Vec<(Key<'v>, &'v ValueRef<'v>)> = Vec::with_capacity(pairs.len());
        let mut index: HashMap<Key<'v>, usize> = HashMap::with_capacity(pairs.len());
        for (k, v) in pairs {
            // unpack() has checked every key already; anything else cannot occur here.
            let key = match k {
                ValueRef::String(s) => Key::Str(s.as_str().unwrap_or_default()),
                ValueRef::Binary(b) => Key::Bin(b),
                _ => continue,
            };
            match index.get(&key) {
                Some(&i) => entries[i].1 = v,
                None => {
                    index.insert(key, entries.len());
                    entries.push((key, v));
                }
            }
        }
        Self { entries }
    }

    /// The map of a value (empty for anything else: callers check the type first).
    pub fn of_value(value: &'v ValueRef<'v>) -> Self {
        match value {
            ValueRef::Map(pairs) => Self::of(pairs),
            _ => Self {
                entries: Vec::new(),
            },
        }
    }

    pub fn get(&self, name: &str) -> Option<&'v ValueRef<'v>> {
        self.entries
            .iter()
            .find(|(k, _)| *k == Key::Str(name))
            .map(|(_, v)| *v)
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn keys(&self) -> impl Iterator<Item = Key<'v>> + '_ {
        self.entries.iter().map(|(k, _)| *k)
    }
}

fn malformed(detail: impl Into<String>) -> Invalid {
    Invalid::at(ErrorReason::Malformed, "payload", detail)
}

/// The payload's value tree (steps 1 and 2 of the validation order: size cap, then msgpack).
pub(crate) fn unpack(payload: &[u8], max_bytes: usize) -> Checked<ValueRef<'_>> {
    if payload.len() > max_bytes {
        return Err(Invalid::at(
            ErrorReason::TooLarge,
            "payload",
            format!("{} bytes exceeds the cap of {}", payload.len(), max_bytes),
        ));
    }
    let mut rest = payload;
    let value = rmpv::decode::read_value_ref(&mut rest)
        .map_err(|e| malformed(format!("not msgpack: {e}")))?;
    if !rest.is_empty() {
        return Err(malformed(format!(
            "not msgpack: {} trailing bytes",
            rest.len()
        )));
    }
    check_tree(&value)?;
    Ok(value)
}

fn check_tree(value: &ValueRef<'_>) -> Checked<()> {
    match value {
        ValueRef::String(s) if s.is_err() => Err(malformed("not msgpack: invalid UTF-8 in a str")),
        ValueRef::Array(items) => items.iter().try_for_each(check_tree),
        ValueRef::Map(pairs) => pairs.iter().try_for_each(|(k, v)| {
            if !matches!(k, ValueRef::String(_) | ValueRef::Binary(_)) {
                return Err(malformed(
                    "not msgpack: a map key that is neither str nor bin",
                ));
            }
            check_tree(k)?;
            check_tree(v)
        }),
        ValueRef::Ext(-1, data) => check_timestamp(data),
        _ => Ok(()),
    }
}

/// The msgpack timestamp extension: 4, 8 or 12 bytes, nanoseconds below 1e9.
fn check_timestamp(data: &[u8]) -> Checked<()> {
    let nanoseconds = match data.len() {
        4 => 0,
        8 => u64::from_be_bytes(data.try_into().unwrap_or_default()) >> 34,
        12 => u64::from(u32::from_be_bytes(data[..4].try_into().unwrap_or_default())),
        n => {
            return Err(malformed(format!(
                "not msgpack: invalid timestamp data (length {n})"
            )))
        }
    };
    if nanoseconds > 999_999_999 {
        return Err(malformed(
            "not msgpack: timestamp nanoseconds over 999999999",
        ));
    }
    Ok(())
}

/// How the reference decoder prints a `bin` key in a field path: Python's bytes repr.
pub(crate) fn bytes_repr(b: &[u8]) -> String {
    let quote = if b.contains(&b'\'') && !b.contains(&b'"') {
        '"'
    } else {
        '\''
    };
    let mut out = String::from("b");
    out.push(quote);
    for &c in b {
        match c {
            b'\\' => out.push_str("\\\\"),
            b'\t' => out.push_str("\\t"),
            b'\n' => out.push_str("\\n"),
            b'\r' => out.push_str("\\r"),
            c if char::from(c) == quote => {
                out.push('\\');
                out.push(quote);
            }
            0x20..=0x7e => out.push(char::from(c)),
            c => out.push_str(&format!("\\x{c:02x}")),
        }
    }
    out.push(quote);
    out
}
