//! The crate's error: one line naming the bad value.

use std::fmt;

use crate::wire::Rejection;

#[derive(Debug)]
pub enum Error {
    /// Zenoh refused something (opening the session, declaring, putting, querying).
    Zenoh(zenoh::Error),
    /// A vehicle, sensor or other option with a bad value.
    InvalidOption(String),
    /// A frame the service would refuse, refused before sending.
    Invalid(Rejection),
    /// `seq` may skip ahead, never go back.
    SeqBackwards { seq: u64, next: u64 },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Zenoh(e) => write!(f, "zenoh: {e}"),
            Self::InvalidOption(msg) => f.write_str(msg),
            Self::Invalid(r) => write!(f, "frame refused before sending: {r}"),
            Self::SeqBackwards { seq, next } => {
                write!(f, "seq {seq} is below the next one, {next}: seq only grows")
            }
        }
    }
}

impl std::error::Error for Error {}

impl From<zenoh::Error> for Error {
    fn from(e: zenoh::Error) -> Self {
        Self::Zenoh(e)
    }
}

impl From<Rejection> for Error {
    fn from(r: Rejection) -> Self {
        Self::Invalid(r)
    }
}

pub type Result<T> = std::result::Result<T, Error>;

pub(crate) fn check_id(kind: &str, value: &str) -> Result<()> {
    if crate::wire::is_name(value) {
        Ok(())
    } else {
        Err(Error::InvalidOption(format!(
            "{kind} id {value:?} must be 1-64 letters, digits, '_', '.' or '-' (no '/' or '*')"
        )))
    }
}
