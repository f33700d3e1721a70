//! `EpochFilter`: drops what a fenced holder of a tracks stream sends (schemas/README.md,
//! "Custody epoch (fencing)"). Each time custody of a stream moves, the new holder publishes
//! with a higher `epoch`; an instance that was paused or cut off may still publish with its
//! old one, and a reader must not take that.

use std::collections::HashMap;

/// Streams remembered at most; past it the filter starts afresh (as the repeat filter does).
pub const MAX_EPOCH_KEYS: usize = 100_000;

/// The highest epoch seen per stream key (a sensor's or a vehicle's tracks key). Not
/// synchronised: a subscriber keeps it under the lock of its other per-key state.
#[derive(Debug, Default, Clone)]
pub struct EpochFilter {
    highest: HashMap<String, u64>,
}

impl EpochFilter {
    pub fn new() -> Self {
        Self::default()
    }

    /// False when `epoch` is below the highest `key` has shown: the message comes from a
    /// fenced holder; drop it. Otherwise true, and `epoch` is the stream's highest from now
    /// on. A message without an epoch (`None`: a service of before epochs) is accepted and
    /// changes nothing; an equal epoch is accepted (the repeat rule decides).
    pub fn accept(&mut self, key: &str, epoch: Option<u64>) -> bool {
        let Some(epoch) = epoch else {
            return true;
        };
        if let Some(highest) = self.highest.get_mut(key) {
            if epoch < *highest {
                return false;
            }
            *highest = epoch;
            return true;
        }
        if self.highest.len() >= MAX_EPOCH_KEYS {
            self.highest.clear();
        }
        self.highest.insert(key.to_owned(), epoch);
        true
    }

    /// The highest epoch `key` has shown; None when none (or forgotten).
    pub fn highest(&self, key: &str) -> Option<u64> {
        self.highest.get(key).copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const K: &str = "fleet/car-1/lidar/tracks";

    #[test]
    fn a_lower_epoch_is_refused_an_equal_or_higher_one_accepted() {
        let mut f = EpochFilter::new();
        assert!(f.accept(K, Some(1)));
        assert!(f.accept(K, Some(2)));
        assert!(!f.accept(K, Some(1))); // the fenced holder, late
        assert!(f.accept(K, Some(2)));
        assert_eq!(f.highest(K), Some(2));
    }

    #[test]
    fn no_epoch_is_accepted_and_keeps_the_highest() {
        let mut f = EpochFilter::new();
        assert!(f.accept(K, None));
        assert_eq!(f.highest(K), None);
        assert!(f.accept(K, Some(6)));
        assert!(f.accept(K, None));
        assert!(!f.accept(K, Some(0)));
        assert_eq!(f.highest(K), Some(6));
    }

    #[test]
    fn streams_are_fenced_each_on_its_own() {
        let mut f = EpochFilter::new();
        assert!(f.accept(K, Some(9)));
        assert!(f.accept("fleet/car-1/radar/tracks", Some(1)));
        assert!(f.accept("fleet/car-1/@vehicle/tracks", Some(1)));
    }

    #[test]
    fn memory_is_bounded() {
        let mut f = EpochFilter::new();
        for i in 0..MAX_EPOCH_KEYS {
            assert!(f.accept(&i.to_string(), Some(5)));
        }
        assert!(f.accept("one more", Some(5))); // the others are forgotten
        assert_eq!(f.highest("0"), None);
        assert!(f.accept("0", Some(1)));
    }
}
