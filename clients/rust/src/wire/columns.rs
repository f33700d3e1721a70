//! Box columns: C-order arrays of little-endian numbers carried as one msgpack `bin` each.
//! Row i of a column of width k occupies bytes `[i·k·s, (i+1)·k·s)`, s the item size.

use super::reasons::ErrorReason;
use super::rejection::{Checked, Invalid};

/// One row of a column: a number (width 1) or `[number; k]`.
pub(crate) trait Row: Copy {
    const BYTES: usize;
    fn read(b: &[u8]) -> Self;
    fn write(&self, out: &mut Vec<u8>);
    fn finite(&self) -> bool;
    /// Largest magnitude in the row (the bounds checks).
    fn max_abs(&self) -> f64;
}

macro_rules! scalar_row {
    ($t:ty, $finite:expr) => {
        impl Row for $t {
            const BYTES: usize = std::mem::size_of::<$t>();
            fn read(b: &[u8]) -> Self {
                let mut a = [0u8; std::mem::size_of::<$t>()];
                a.copy_from_slice(b);
                <$t>::from_le_bytes(a)
            }
            fn write(&self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn finite(&self) -> bool {
                let f: fn(&$t) -> bool = $finite;
                f(self)
            }
            fn max_abs(&self) -> f64 {
                (*self as f64).abs()
            }
        }
    };
}

scalar_row!(f32, |v| v.is_finite());
scalar_row!(f64, |v| v.is_finite());
scalar_row!(i32, |_| true);
scalar_row!(i64, |_| true);

impl<T: Row, const K: usize> Row for [T; K] {
    const BYTES: usize = T::BYTES * K;
    fn read(b: &[u8]) -> Self {
        std::array::from_fn(|i| T::read(&b[i * T::BYTES..(i + 1) * T::BYTES]))
    }
    fn write(&self, out: &mut Vec<u8>) {
        self.iter().for_each(|v| v.write(out));
    }
    fn finite(&self) -> bool {
        self.iter().all(Row::finite)
    }
    fn max_abs(&self) -> f64 {
        self.iter().map(Row::max_abs).fold(0.0, f64::max)
    }
}

pub(crate) fn to_bytes<R: Row>(rows: &[R]) -> Vec<u8> {
    let mut out = Vec::with_capacity(rows.len() * R::BYTES);
    rows.iter().for_each(|r| r.write(&mut out));
    out
}

/// A column read back: its byte length must be `count × row bytes` (`column_length`), and a
/// float column must hold no NaN or infinity (`non_finite`).
pub(crate) fn from_bytes<R: Row>(buf: &[u8], count: usize, field: &str) -> Checked<Vec<R>> {
    if count.checked_mul(R::BYTES) != Some(buf.len()) {
        return Err(Invalid::at(
            ErrorReason::ColumnLength,
            field,
            format!(
                "{} bytes, expected count {count} x {} bytes",
                buf.len(),
                R::BYTES
            ),
        ));
    }
    let rows: Vec<R> = buf.chunks_exact(R::BYTES).map(R::read).collect();
    check_finite(&rows, field)?;
    Ok(rows)
}

/// The same length rule for a column built in memory (an encoder's input).
pub(crate) fn check_count<R>(rows: &[R], count: usize, field: &str) -> Checked<()> {
    if rows.len() != count {
        return Err(Invalid::at(
            ErrorReason::ColumnLength,
            field,
            format!("{} rows, expected count {count}", rows.len()),
        ));
    }
    Ok(())
}

pub(crate) fn check_finite<R: Row>(rows: &[R], field: &str) -> Checked<()> {
    match rows.iter().position(|r| !r.finite()) {
        Some(row) => Err(Invalid::at(
            ErrorReason::NonFinite,
            field,
            format!("NaN or inf in row {row}"),
        )),
        None => Ok(()),
    }
}

/// `invalid_value` when some |value| exceeds `bound` (inclusive limit), naming the first row.
pub(crate) fn check_bound<R: Row>(rows: &[R], bound: f64, field: &str, unit: &str) -> Checked<()> {
    match rows.iter().position(|r| r.max_abs() > bound) {
        Some(row) => Err(Invalid::at(
            ErrorReason::InvalidValue,
            field,
            format!("|value| over {bound} {unit} in row {row}"),
        )),
        None => Ok(()),
    }
}
