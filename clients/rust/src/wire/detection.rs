//! `DetectionFrame` (`<prefix>/<vehicle>/<sensor>/detections`) and its `BoxColumns`.

use super::columns::{check_bound, check_count, check_finite, from_bytes, to_bytes};
use super::fields::{
    binary, int64, integer, name, nullable, string, Fields, INT32_MAX, MAX_FRAME_ID,
};
use super::header::{
    check_classes, check_int64_field, check_name_field, check_pose, check_transform,
    check_version_in, classes, peek, pose_field, unpack_map, version_field, DecodeLimits,
    MAX_COORDINATE_M, MAX_SIZE_M, MAX_SPEED_MPS, MAX_YAW_RAD,
};
use super::pack::Packer;
use super::reasons::{ErrorReason, DETECTION_SCHEMA_VERSION, SCHEMA_VERSION};
use super::rejection::{Checked, Invalid, Rejection};
use super::value::Map;

/// N detection boxes, column by column. `class_index[i]` indexes `classes`, this frame's own
/// class table. Every column holds one row per box; `velocity` is optional as a whole.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BoxColumns {
    pub classes: Vec<String>,
    pub class_index: Vec<i32>,
    /// x, y, z of the box's geometric centre (m).
    pub center: Vec<[f32; 3]>,
    /// l (along the heading), w, h (m), each > 0.
    pub size: Vec<[f32; 3]>,
    /// Heading about +z from +x (rad).
    pub yaw: Vec<f32>,
    pub score: Vec<f64>,
    /// vx, vy (m/s).
    pub velocity: Option<Vec<[f32; 2]>>,
}

/// One detection, for callers that think in objects: see `BoxColumns::from_detections`.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    pub class: String,
    pub center: [f32; 3],
    pub size: [f32; 3],
    pub yaw: f32,
    pub score: f64,
    pub velocity: Option<[f32; 2]>,
}

impl BoxColumns {
    /// Columns of `detections`. The table starts as `classes`; a class name not in it is
    /// appended (the service then refuses it as `unknown_class`, the honest outcome).
    /// `velocity` is sent only when every detection has one.
    pub fn from_detections<S: AsRef<str>>(classes: &[S], detections: &[Detection]) -> Self {
        let mut table: Vec<String> = classes.iter().map(|c| c.as_ref().to_owned()).collect();
        let mut out = BoxColumns::default();
        for d in detections {
            let index = match table.iter().position(|c| *c == d.class) {
                Some(i) => i,
                None => {
                    table.push(d.class.clone());
                    table.len() - 1
                }
            };
            out.class_index.push(index as i32);
            out.center.push(d.center);
            out.size.push(d.size);
            out.yaw.push(d.yaw);
            out.score.push(d.score);
        }
        let velocity: Option<Vec<[f32; 2]>> = detections.iter().map(|d| d.velocity).collect();
        out.velocity = velocity.filter(|v| !v.is_empty());
        out.classes = table;
        out
    }

    /// Number of boxes.
    pub fn count(&self) -> usize {
        self.class_index.len()
    }

    /// The class name of box `i`, None when its index is outside the table.
    pub fn class_name(&self, i: usize) -> Option<&str> {
        let index = usize::try_from(*self.class_index.get(i)?).ok()?;
        self.classes.get(index).map(String::as_str)
    }
}

/// One sensor frame of 3D detections.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectionFrame {
    pub vehicle: String,
    pub sensor: String,
    /// Per sensor and session, increasing.
    pub seq: u64,
    /// Sensor time of the frame (ns), strictly increasing.
    pub stamp_ns: u64,
    /// Coordinate frame of the boxes.
    pub frame_id: String,
    /// Sensor→world rigid transform, 4×4 row-major.
    pub pose: Option<[f64; 16]>,
    /// False marks a non-key frame (nuScenes 10 Hz mode). Default true.
    pub key_frame: bool,
    /// Random per publisher run: a new value tells the service the publisher restarted.
    pub session_id: Option<u64>,
    pub boxes: BoxColumns,
    /// Sensor→vehicle rigid transform, 4×4 row-major: the sensor's mounting, which a vehicle
    /// whose sensors are fused needs (schema version 2).
    pub extrinsic: Option<[f64; 16]>,
}

impl DetectionFrame {
    /// The version the encoder writes: 2 with an extrinsic, else 1 (the bytes a publisher
    /// of before version 2 sent). A version-2 frame without one decodes to the same frame.
    pub fn schema_version(&self) -> u64 {
        if self.extrinsic.is_some() {
            DETECTION_SCHEMA_VERSION
        } else {
            SCHEMA_VERSION
        }
    }
}

struct RawBoxes<'v> {
    count: usize,
    classes: Vec<String>,
    class_index: &'v [u8],
    center: &'v [u8],
    size: &'v [u8],
    yaw: &'v [u8],
    score: &'v [u8],
    velocity: Option<&'v [u8]>,
}

fn raw_boxes<'v>(v: &'v super::fields::V<'v>) -> Checked<RawBoxes<'v>> {
    let mut f = Fields::new(v, "BoxColumns")?;
    let raw = RawBoxes {
        count: f.required("count", |v| integer(v, 0, i128::from(INT32_MAX)))? as usize,
        classes: f.required("classes", classes)?,
        class_index: f.required("class_index", binary)?,
        center: f.required("center", binary)?,
        size: f.required("size", binary)?,
        yaw: f.required("yaw", binary)?,
        score: f.required("score", binary)?,
        velocity: f.optional("velocity", None, |v| nullable(v, binary))?,
    };
    f.finish()?;
    Ok(raw)
}

/// Steps 7-9: class indices inside the table, positive sizes, values within their bounds.
fn check_box_values(b: &BoxColumns) -> Checked<()> {
    let n = b.classes.len() as i64;
    if b.class_index.iter().any(|&i| i < 0 || i64::from(i) >= n) {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "boxes.class_index",
            format!("index outside the class table of {n} entries"),
        ));
    }
    if let Some(row) = b.size.iter().position(|s| s.iter().any(|&v| v <= 0.0)) {
        return Err(Invalid::at(
            ErrorReason::NonPositiveSize,
            "boxes.size",
            format!("size <= 0 in row {row}"),
        ));
    }
    check_bound(&b.center, MAX_COORDINATE_M, "boxes.center", "m")?;
    check_bound(&b.size, MAX_SIZE_M, "boxes.size", "m")?;
    check_bound(&b.yaw, MAX_YAW_RAD, "boxes.yaw", "rad")?;
    if let Some(v) = &b.velocity {
        check_bound(v, MAX_SPEED_MPS, "boxes.velocity", "m/s")?;
    }
    Ok(())
}

fn decode_checked(
    map: &Map<'_>,
    value: &super::fields::V<'_>,
    limits: &DecodeLimits,
) -> Checked<DetectionFrame> {
    let version = check_version_in(map, SCHEMA_VERSION, DETECTION_SCHEMA_VERSION)?;
    let mut f = Fields::new(value, "DetectionFrame")?;
    version_field(&mut f)?;
    let vehicle = f.required("vehicle", name)?.to_owned();
    let sensor = f.required("sensor", name)?.to_owned();
    let seq = f.required("seq", int64)?;
    let stamp_ns = f.required("stamp_ns", int64)?;
    let frame_id = f
        .required("frame_id", |v| string(v, 1, Some(MAX_FRAME_ID)))?
        .to_owned();
    let pose = f.optional("pose", None, pose_field)?;
    let key_frame = f.optional("key_frame", true, super::fields::boolean)?;
    let session_id = f.optional("session_id", None, |v| nullable(v, int64))?;
    let raw = f.required("boxes", raw_boxes)?;
    let extrinsic = match version {
        1 => None, // then an extrinsic key is an unknown one, as to a version-1 reader
        _ => f.optional("extrinsic", None, pose_field)?,
    };
    f.finish()?;

    let count = raw.count;
    if count > limits.max_boxes {
        return Err(Invalid::at(
            ErrorReason::TooLarge,
            "boxes.count",
            format!("{count} rows exceeds the cap of {}", limits.max_boxes),
        ));
    }
    let boxes = BoxColumns {
        class_index: from_bytes(raw.class_index, count, "boxes.class_index")?,
        center: from_bytes(raw.center, count, "boxes.center")?,
        size: from_bytes(raw.size, count, "boxes.size")?,
        yaw: from_bytes(raw.yaw, count, "boxes.yaw")?,
        score: from_bytes(raw.score, count, "boxes.score")?,
        velocity: raw
            .velocity
            .map(|b| from_bytes(b, count, "boxes.velocity"))
            .transpose()?,
        classes: raw.classes,
    };
    check_box_values(&boxes)?;
    if let Some(p) = &pose {
        check_pose(p)?;
    }
    if let Some(e) = &extrinsic {
        check_transform(e, "extrinsic")?;
    }
    Ok(DetectionFrame {
        vehicle,
        sensor,
        seq,
        stamp_ns,
        frame_id,
        pose,
        key_frame,
        session_id,
        boxes,
        extrinsic,
    })
}

/// Decode and validate a `DetectionFrame`, version 1 or 2 (schemas/README.md, "Validation
/// order and reasons", steps 1-10). Class names are not checked: see `check_known_classes`.
pub fn decode_detection_frame(
    payload: &[u8],
    limits: &DecodeLimits,
) -> Result<DetectionFrame, Rejection> {
    let value = unpack_map(payload, limits.max_bytes).map_err(|e| e.into_rejection(None, None))?;
    let map = Map::of_value(&value);
    let (seq, stamp_ns) = peek(&map);
    decode_checked(&map, &value, limits).map_err(|e| e.into_rejection(seq, stamp_ns))
}

/// Step 11, the service's: a box whose class is not in `known` is `unknown_class`, naming
/// the table entry (`boxes.classes.<i>`) of the first such box.
pub fn check_known_classes<S: AsRef<str>>(
    frame: &DetectionFrame,
    known: &[S],
) -> Result<(), Rejection> {
    let b = &frame.boxes;
    for (row, &index) in b.class_index.iter().enumerate() {
        let Some(name) = b.class_name(row) else {
            continue;
        };
        if !known.iter().any(|k| k.as_ref() == name) {
            let names: Vec<&str> = known.iter().map(AsRef::as_ref).collect();
            return Err(Invalid::at(
                ErrorReason::UnknownClass,
                &format!("boxes.classes.{index}"),
                format!(
                    "class '{name}' is not tracked here; known: {}",
                    names.join(", ")
                ),
            )
            .into_rejection(Some(frame.seq), Some(frame.stamp_ns)));
        }
    }
    Ok(())
}

/// A detection frame's fields but its boxes, borrowed: what a publisher encodes each frame
/// without copying the caller's columns.
pub(crate) struct Header<'a> {
    pub vehicle: &'a str,
    pub sensor: &'a str,
    pub seq: u64,
    pub stamp_ns: u64,
    pub frame_id: &'a str,
    pub pose: Option<&'a [f64; 16]>,
    pub key_frame: bool,
    pub session_id: Option<u64>,
    pub extrinsic: Option<&'a [f64; 16]>,
}

impl<'a> Header<'a> {
    fn of(d: &'a DetectionFrame) -> Self {
        Self {
            vehicle: &d.vehicle,
            sensor: &d.sensor,
            seq: d.seq,
            stamp_ns: d.stamp_ns,
            frame_id: &d.frame_id,
            pose: d.pose.as_ref(),
            key_frame: d.key_frame,
            session_id: d.session_id,
            extrinsic: d.extrinsic.as_ref(),
        }
    }
}

fn check_frame(h: &Header<'_>, b: &BoxColumns) -> Checked<()> {
    check_name_field("vehicle", h.vehicle)?;
    check_name_field("sensor", h.sensor)?;
    check_int64_field("seq", h.seq)?;
    check_int64_field("stamp_ns", h.stamp_ns)?;
    super::fields::check_length(h.frame_id, 1, Some(MAX_FRAME_ID))
        .map_err(|e| e.within("frame_id"))?;
    if let Some(id) = h.session_id {
        check_int64_field("session_id", id)?;
    }
    check_classes(&b.classes).map_err(|e| e.within("boxes"))?;
    let count = b.count();
    if count as u64 > INT32_MAX {
        return Err(Invalid::at(
            ErrorReason::InvalidValue,
            "boxes.count",
            "over 2^31-1 boxes",
        ));
    }
    check_count(&b.center, count, "boxes.center")?;
    check_count(&b.size, count, "boxes.size")?;
    check_count(&b.yaw, count, "boxes.yaw")?;
    check_count(&b.score, count, "boxes.score")?;
    if let Some(v) = &b.velocity {
        check_count(v, count, "boxes.velocity")?;
    }
    check_finite(&b.center, "boxes.center")?;
    check_finite(&b.size, "boxes.size")?;
    check_finite(&b.yaw, "boxes.yaw")?;
    check_finite(&b.score, "boxes.score")?;
    if let Some(v) = &b.velocity {
        check_finite(v, "boxes.velocity")?;
    }
    check_box_values(b)?;
    if let Some(p) = h.pose {
        check_pose(p)?;
    }
    if let Some(e) = h.extrinsic {
        check_transform(e, "extrinsic")?;
    }
    Ok(())
}

/// The frame as msgpack, byte for byte what the reference encoder writes for it: header,
/// `key_frame`, `boxes`, then `pose`, `session_id` and `extrinsic` when present (version 2
/// with an extrinsic, else 1). A frame the decoder would refuse (steps 4-10) is refused here
/// with the same reason and field.
pub fn encode_detection_frame(d: &DetectionFrame) -> Result<Vec<u8>, Rejection> {
    encode_parts(&Header::of(d), &d.boxes)
}

pub(crate) fn encode_parts(h: &Header<'_>, b: &BoxColumns) -> Result<Vec<u8>, Rejection> {
    check_frame(h, b).map_err(|e| e.into_rejection(Some(h.seq), Some(h.stamp_ns)))?;
    let rows = b.count();
    let mut p = Packer::new(256 + rows * 48);
    p.map(
        8 + usize::from(h.pose.is_some())
            + usize::from(h.session_id.is_some())
            + usize::from(h.extrinsic.is_some()),
    );
    let version = match h.extrinsic {
        Some(_) => DETECTION_SCHEMA_VERSION,
        None => SCHEMA_VERSION,
    };
    p.key("schema_version").uint(version);
    p.key("vehicle").str(h.vehicle);
    p.key("sensor").str(h.sensor);
    p.key("seq").uint(h.seq);
    p.key("stamp_ns").uint(h.stamp_ns);
    p.key("frame_id").str(h.frame_id);
    p.key("key_frame").bool(h.key_frame);
    p.key("boxes").map(7 + usize::from(b.velocity.is_some()));
    p.key("count").uint(rows as u64);
    p.key("classes").strs(&b.classes);
    p.key("class_index").bin(&to_bytes(&b.class_index));
    p.key("center").bin(&to_bytes(&b.center));
    p.key("size").bin(&to_bytes(&b.size));
    p.key("yaw").bin(&to_bytes(&b.yaw));
    p.key("score").bin(&to_bytes(&b.score));
    if let Some(v) = &b.velocity {
        p.key("velocity").bin(&to_bytes(v));
    }
    if let Some(pose) = h.pose {
        p.key("pose").f64s(pose);
    }
    if let Some(id) = h.session_id {
        p.key("session_id").uint(id);
    }
    if let Some(e) = h.extrinsic {
        p.key("extrinsic").f64s(e);
    }
    Ok(p.finish())
}
