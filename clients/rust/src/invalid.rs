//! Payloads on a subscribed key that do not decode are never silent: counted by reason, kept
//! (the last one), logged as a warning at most once a second, and handed to a callback.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::wire::{ErrorReason, Rejection};

/// Called with the key and the refusal of every payload that did not decode.
pub type InvalidCallback = Arc<dyn Fn(&str, &Rejection) + Send + Sync>;

const LOG_INTERVAL: Duration = Duration::from_secs(1);

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

pub(crate) struct Invalids {
    what: &'static str,
    count: AtomicU64,
    reasons: Mutex<HashMap<ErrorReason, u64>>,
    last: Mutex<Option<Rejection>>,
    // When the last warning went out, and how many were not logged since.
    log: Mutex<(Option<Instant>, u64)>,
    callback: Option<InvalidCallback>,
}

impl Invalids {
    pub fn new(what: &'static str, callback: Option<InvalidCallback>) -> Self {
        Self {
            what,
            count: AtomicU64::new(0),
            reasons: Mutex::new(HashMap::new()),
            last: Mutex::new(None),
            log: Mutex::new((None, 0)),
            callback,
        }
    }

    pub fn record(&self, key: &str, r: Rejection) {
        let total = self.count.fetch_add(1, Ordering::Relaxed) + 1;
        *lock(&self.reasons).entry(r.reason).or_insert(0) += 1;
        {
            let mut log = lock(&self.log);
            let due = log.0.is_none_or(|at| at.elapsed() >= LOG_INTERVAL);
            if due {
                tracing::warn!(
                    key,
                    reason = r.reason.as_str(),
                    field = r.field.as_deref().unwrap_or(""),
                    "invalid {} on {key}: {r}; {total} invalid so far, {} more since the last line",
                    self.what,
                    log.1
                );
                *log = (Some(Instant::now()), 0);
            } else {
                log.1 += 1;
            }
        }
        if let Some(cb) = &self.callback {
            cb(key, &r);
        }
        *lock(&self.last) = Some(r);
    }

    pub fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    pub fn reasons(&self) -> HashMap<ErrorReason, u64> {
        lock(&self.reasons).clone()
    }

    pub fn last(&self) -> Option<Rejection> {
        lock(&self.last).clone()
    }
}
