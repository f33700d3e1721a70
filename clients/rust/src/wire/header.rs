//! What every message shares: the version check, the header peek of a refused frame, the
//! class table, and the pose (its field check and its rigidity and bounds).

use rmpv::ValueRef;

use super::fields::{
    self, array, int_value, nullable, number, string, Fields, MAX_CLASSES, MAX_CLASS_NAME, V,
};
use super::reasons::{ErrorReason, SCHEMA_VERSION};
use super::rejection::{Checked, Invalid};
use super::value::{self, Map};

/// Caps a decoder applies before looking into a payload (the service's defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeLimits {
    pub max_bytes: usize,
    /// Most rows of a frame's columns (`boxes.count`, `tracks.count`).
    pub max_boxes: usize,
}

impl Default for DecodeLimits {
    fn default() -> Self {
        Self {
            max_bytes: 8 << 20,
            max_boxes: 10_000,
        }
    }
}

/// Rotation part of a pose must be orthonormal to this tolerance (float32-sourced poses pass).
pub const POSE_TOLERANCE: f64 = 1e-4;
/// |x|, |y|, |z| of a box centre and of a pose's translation (metres).
pub const MAX_COORDINATE_M: f64 = 1e5;
/// Each of l, w, h (metres).
pub const MAX_SIZE_M: f64 = 100.0;
pub const MAX_YAW_RAD: f64 = 1e4;
/// |vx|, |vy| (m/s).
pub const MAX_SPEED_MPS: f64 = 200.0;

/// The payload as a map (anything else is `malformed`).
pub(crate) fn unpack_map(payload: &[u8], max_bytes: usize) -> Checked<ValueRef<'_>> {
    let v = value::unpack(payload, max_bytes)?;
    if !matches!(v, ValueRef::Map(_)) {
        return Err(Invalid::at(
            ErrorReason::Malformed,
            "payload",
            "expected a map",
        ));
    }
    Ok(v)
}

/// Step 3: `schema_version` present, an int, and 1.
pub(crate) fn check_version(map: &Map<'_>) -> Checked<()> {
    check_version_in(map, SCHEMA_VERSION, SCHEMA_VERSION).map(|_| ())
}

/// Step 3 for a message read in several versions: the version, one of `lo ..= hi`.
pub(crate) fn check_version_in(map: &Map<'_>, lo: u64, hi: u64) -> Checked<u64> {
    let v = map.get("schema_version").ok_or_else(|| {
        Invalid::at(
            ErrorReason::MissingField,
            "schema_version",
            "field required",
        )
    })?;
    let n = int_value(v).ok_or_else(|| {
        Invalid::at(
            ErrorReason::WrongType,
            "schema_version",
            "must be an integer",
        )
    })?;
    if n < i128::from(lo) || n > i128::from(hi) {
        let speaks: Vec<String> = (lo..=hi).map(|v| v.to_string()).collect();
        return Err(Invalid::at(
            ErrorReason::WrongVersion,
            "schema_version",
            format!(
                "version {n} not supported (this client speaks {})",
                speaks.join(", ")
            ),
        ));
    }
    Ok(n as u64)
}

/// `seq` and `stamp_ns` of a readable map, each when it is an int in 0 … 2^63−1.
pub(crate) fn peek(map: &Map<'_>) -> (Option<u64>, Option<u64>) {
    let get = |name: &str| {
        map.get(name)
            .and_then(int_value)
            .filter(|n| (0..=i128::from(fields::INT64_MAX)).contains(n))
            .map(|n| n as u64)
    };
    (get("seq"), get("stamp_ns"))
}

/// `schema_version` as the field table sees it, after `check_version` passed.
pub(crate) fn version_field(f: &mut Fields<'_>) -> Checked<()> {
    f.required("schema_version", |_| Ok(()))
}

pub(crate) fn classes(v: &V<'_>) -> Checked<Vec<String>> {
    array(v, 0, Some(MAX_CLASSES), |s| {
        string(s, 1, Some(MAX_CLASS_NAME)).map(str::to_owned)
    })
}

/// The same rules for a class table built in memory.
pub(crate) fn check_classes(classes: &[String]) -> Checked<()> {
    if classes.len() > MAX_CLASSES {
        return Err(Invalid::new(
            ErrorReason::InvalidValue,
            format!(
                "List should have at most {MAX_CLASSES} items after validation, not {}",
                classes.len()
            ),
        )
        .within("classes"));
    }
    for (i, name) in classes.iter().enumerate() {
        fields::check_length(name, 1, Some(MAX_CLASS_NAME))
            .map_err(|e| e.within(i).within("classes"))?;
    }
    Ok(())
}

pub(crate) fn pose_field(v: &V<'_>) -> Checked<Option<[f64; 16]>> {
    nullable(v, |v| {
        let p = array(v, 16, Some(16), number)?;
        let mut out = [0.0; 16];
        out.copy_from_slice(&p);
        Ok(out)
    })
}

fn det3(p: &[f64; 16]) -> f64 {
    p[0] * (p[5] * p[10] - p[6] * p[9]) - p[1] * (p[4] * p[10] - p[6] * p[8])
        + p[2] * (p[4] * p[9] - p[5] * p[8])
}

fn orthonormal(p: &[f64; 16]) -> bool {
    let r = |i: usize, j: usize| p[4 * i + j];
    (0..3).all(|i| {
        (0..3).all(|k| {
            let dot: f64 = (0..3).map(|j| r(i, j) * r(k, j)).sum();
            let eye = if i == k { 1.0 } else { 0.0 };
            (dot - eye).abs() <= POSE_TOLERANCE
        })
    })
}

/// Step 10: finite, rigid (last row `0 0 0 1`, orthonormal rotation, no reflection), and a
/// translation within bounds.
pub(crate) fn check_pose(p: &[f64; 16]) -> Checked<()> {
    check_transform(p, "pose")
}

/// The rules of a pose for any rigid transform (a pose, an extrinsic), named by `field`.
pub(crate) fn check_transform(p: &[f64; 16], field: &str) -> Checked<()> {
    if !p.iter().all(|v| v.is_finite()) {
        return Err(Invalid::at(
            ErrorReason::NonFinite,
            field,
            format!("NaN or inf in the {field}"),
        ));
    }
    let last_row = [p[12].abs(), p[13].abs(), p[14].abs(), (p[15] - 1.0).abs()];
    let rigid = last_row.iter().all(|&v| v <= POSE_TOLERANCE) && orthonormal(p) && det3(p) > 0.0;
    if !rigid {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            field,
            "not a rigid transform (row-major 4x4)",
        ));
    }
    if [p[3], p[7], p[11]]
        .iter()
        .any(|v| v.abs() > MAX_COORDINATE_M)
    {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            field,
            format!("translation over {MAX_COORDINATE_M} m"),
        ));
    }
    Ok(())
}

/// A vehicle, sensor or instance id built in memory, checked as the decoder would.
pub(crate) fn check_name_field(name: &'static str, value: &str) -> Checked<()> {
    fields::check_name(value).map_err(|e| e.within(name))
}

pub(crate) fn check_int64_field(name: &'static str, value: u64) -> Checked<()> {
    if value > fields::INT64_MAX {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            name,
            format!(
                "Input should be less than or equal to {}",
                fields::INT64_MAX
            ),
        ));
    }
    Ok(())
}
