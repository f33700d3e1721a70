//! `FrameError` (`<prefix>/<vehicle>/<sensor>/errors`): a frame the service did not track,
//! or (drop notices) many frames it shed, or a run of frames lost in transport (`missed`).

use super::fields::{array, int64, name, nullable, one_of, string, Fields, MAX_NOTICE_SEQS, V};
use super::header::{
    check_int64_field, check_name_field, check_version, unpack_map, version_field, DecodeLimits,
};
use super::pack::Packer;
use super::reasons::{ErrorReason, SCHEMA_VERSION};
use super::rejection::{Checked, Invalid, Rejection};
use super::value::Map;

pub const MAX_ERROR_FIELD: usize = 256;
pub const MAX_ERROR_DETAIL: usize = 1024;

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameError {
    /// From the key the frame arrived on.
    pub vehicle: String,
    pub sensor: String,
    /// The frame's, when they could be read (never for `missed`).
    pub seq: Option<u64>,
    pub stamp_ns: Option<u64>,
    pub reason: ErrorReason,
    /// Dotted path of the offending field.
    pub field: Option<String>,
    /// For people, not for parsing.
    pub detail: String,
    pub instance: String,
    /// Service wall clock (Unix ns) when the frame arrived (a drop notice: its first frame).
    pub received_ns: u64,
    /// Drop notices only: the seq of every frame the notice stands for, in arrival order.
    pub seqs: Option<Vec<Option<u64>>>,
}

impl FrameError {
    /// The seqs of the frames this notice stands for: `seqs` when present, else its one
    /// `seq` (None where a seq could not be read, and for `missed`, which names none).
    pub fn frames(&self) -> Vec<Option<u64>> {
        match &self.seqs {
            Some(seqs) => seqs.clone(),
            None if self.reason == ErrorReason::Missed => Vec::new(),
            None => vec![self.seq],
        }
    }
}

fn reason(v: &V<'_>) -> Checked<ErrorReason> {
    one_of(v, &ErrorReason::ALL, ErrorReason::as_str)
}

fn decode_checked(map: &Map<'_>, value: &V<'_>) -> Checked<FrameError> {
    check_version(map)?;
    let mut f = Fields::new(value, "FrameError")?;
    version_field(&mut f)?;
    let e = FrameError {
        vehicle: f.required("vehicle", name)?.to_owned(),
        sensor: f.required("sensor", name)?.to_owned(),
        seq: f.optional("seq", None, |v| nullable(v, int64))?,
        stamp_ns: f.optional("stamp_ns", None, |v| nullable(v, int64))?,
        reason: f.required("reason", reason)?,
        field: f
            .optional("field", None, |v| {
                nullable(v, |v| string(v, 0, Some(MAX_ERROR_FIELD)))
            })?
            .map(str::to_owned),
        detail: f
            .required("detail", |v| string(v, 0, Some(MAX_ERROR_DETAIL)))?
            .to_owned(),
        instance: f.required("instance", name)?.to_owned(),
        received_ns: f.required("received_ns", int64)?,
        seqs: f.optional("seqs", None, |v| {
            nullable(v, |v| {
                array(v, 0, Some(MAX_NOTICE_SEQS), |s| nullable(s, int64))
            })
        })?,
    };
    f.finish()?;
    Ok(e)
}

pub fn decode_frame_error(payload: &[u8], limits: &DecodeLimits) -> Result<FrameError, Rejection> {
    let value = unpack_map(payload, limits.max_bytes).map_err(|e| e.into_rejection(None, None))?;
    let map = Map::of_value(&value);
    decode_checked(&map, &value).map_err(|e| e.into_rejection(None, None))
}

fn check_error(e: &FrameError) -> Checked<()> {
    check_name_field("vehicle", &e.vehicle)?;
    check_name_field("sensor", &e.sensor)?;
    for (name, v) in [("seq", e.seq), ("stamp_ns", e.stamp_ns)] {
        if let Some(v) = v {
            check_int64_field(name, v)?;
        }
    }
    if let Some(field) = &e.field {
        super::fields::check_length(field, 0, Some(MAX_ERROR_FIELD))
            .map_err(|x| x.within("field"))?;
    }
    super::fields::check_length(&e.detail, 0, Some(MAX_ERROR_DETAIL))
        .map_err(|x| x.within("detail"))?;
    check_name_field("instance", &e.instance)?;
    check_int64_field("received_ns", e.received_ns)?;
    if let Some(seqs) = &e.seqs {
        if seqs.len() > MAX_NOTICE_SEQS {
            return Err(Invalid::at(
                ErrorReason::InvalidValue,
                "seqs",
                format!("over {MAX_NOTICE_SEQS} seqs"),
            ));
        }
        for (i, s) in seqs.iter().enumerate() {
            if let Some(s) = s {
                check_int64_field("seqs", *s).map_err(|x| x.within(i))?;
            }
        }
    }
    Ok(())
}

/// The notice as msgpack, byte for byte what the service writes (`seqs` only when present).
pub fn encode_frame_error(e: &FrameError) -> Result<Vec<u8>, Rejection> {
    check_error(e).map_err(|x| x.into_rejection(None, None))?;
    let mut p = Packer::new(256);
    p.map(10 + usize::from(e.seqs.is_some()));
    p.key("schema_version").uint(SCHEMA_VERSION);
    p.key("vehicle").str(&e.vehicle);
    p.key("sensor").str(&e.sensor);
    p.key("seq").opt_uint(e.seq);
    p.key("stamp_ns").opt_uint(e.stamp_ns);
    p.key("reason").str(e.reason.as_str());
    p.key("field").opt_str(e.field.as_deref());
    p.key("detail").str(&e.detail);
    p.key("instance").str(&e.instance);
    p.key("received_ns").uint(e.received_ns);
    if let Some(seqs) = &e.seqs {
        p.key("seqs").array(seqs.len());
        for s in seqs {
            p.opt_uint(*s);
        }
    }
    Ok(p.finish())
}
