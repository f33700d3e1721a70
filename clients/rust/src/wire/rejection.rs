//! Why a payload was refused: the reason, the dotted field, and a human-readable detail.

use std::fmt;

use super::reasons::ErrorReason;

/// A refused message. `seq`/`stamp_ns` are filled when the payload was a readable map holding
/// them in range (so a caller can still say which frame it was), as the service does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rejection {
    pub reason: ErrorReason,
    /// Dotted path of the offending field (`boxes.size`, `pose`, `boxes.classes.3`, `payload`).
    pub field: Option<String>,
    /// For people, not for parsing.
    pub detail: String,
    pub seq: Option<u64>,
    pub stamp_ns: Option<u64>,
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.field {
            Some(field) => write!(f, "{} ({}): {}", self.reason, field, self.detail),
            None => write!(f, "{}: {}", self.reason, self.detail),
        }
    }
}

impl std::error::Error for Rejection {}

/// A failed check while walking a message: `loc` grows outwards as the error leaves each
/// nested field, like the reference decoder's.
#[derive(Debug, Clone)]
pub(crate) struct Invalid {
    pub reason: ErrorReason,
    pub detail: String,
    pub loc: Vec<String>,
}

impl Invalid {
    pub fn new(reason: ErrorReason, detail: impl Into<String>) -> Self {
        Self {
            reason,
            detail: detail.into(),
            loc: Vec::new(),
        }
    }

    pub fn at(reason: ErrorReason, field: &str, detail: impl Into<String>) -> Self {
        Self {
            reason,
            detail: detail.into(),
            loc: vec![field.to_owned()],
        }
    }

    pub fn within(mut self, key: impl ToString) -> Self {
        self.loc.insert(0, key.to_string());
        self
    }

    pub fn field(&self) -> Option<String> {
        if self.loc.is_empty() {
            None
        } else {
            Some(self.loc.join("."))
        }
    }

    pub fn into_rejection(self, seq: Option<u64>, stamp_ns: Option<u64>) -> Rejection {
        let mut detail = self.detail.clone();
        truncate_chars(&mut detail, 300);
        Rejection {
            reason: self.reason,
            field: self.field(),
            detail,
            seq,
            stamp_ns,
        }
    }
}

pub(crate) type Checked<T> = Result<T, Invalid>;

fn truncate_chars(s: &mut String, max: usize) {
    if let Some((i, _)) = s.char_indices().nth(max) {
        s.truncate(i);
    }
}
