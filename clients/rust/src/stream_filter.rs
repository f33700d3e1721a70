//! `StreamFilter`: which tracks messages a subscriber delivers, per stream (a tracks key: one
//! sensor's, or one fused vehicle's `@vehicle`). Not a message of a fenced holder, whose
//! custody `epoch` is below the highest the stream has shown (`EpochFilter`); not an exact
//! repeat of a recent (`seq`, `stamp_ns`); and, after custody moved, not the new holder's
//! replay up to the last message (by stamp, then seq) delivered from the holder before it
//! (schemas/README.md, "Custody epoch (fencing)"). The rule of the Python clients'
//! `StreamFilter`, verdict for verdict; `TrackSubscriber` and `VehicleTrackSubscriber` both
//! use it.

use std::collections::{HashMap, VecDeque};

use crate::epoch_filter::EpochFilter;

/// Per key: a repeat comes within a takeover, a few frames at most.
pub const RECENT_FRAMES: usize = 16;
/// Streams remembered at most; past it the filter starts afresh.
pub const MAX_STREAM_KEYS: usize = 100_000;

/// What `StreamFilter::admit` decides about one message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Verdict {
    Deliver,
    /// (`seq`, `stamp_ns`) delivered on this stream within the window, or a new holder's
    /// replay of what the holder before it delivered.
    Repeat,
    /// An epoch below the stream's highest: sent by a fenced holder.
    Stale,
}

#[derive(Default)]
struct Stream {
    /// (stamp_ns, seq) delivered, the last one last.
    recent: VecDeque<(u64, u64)>,
    /// After the epoch rose: the last message delivered from the holder before. The new
    /// holder's messages at or before it are repeats (it replays from the last frame it
    /// heard, which after a partition is more frames back than the window holds). By
    /// (stamp, seq): a fused vehicle's lidar and camera frames can share a stamp, each its
    /// own message. None: caught up.
    handover: Option<(u64, u64)>,
}

/// Per stream key: its highest epoch, its last `recent_frames` deliveries, and where a new
/// holder has to get past. Not synchronised: a subscriber keeps it under its lock (samples
/// of two links come on two threads, and each verdict and what it records are one step).
/// Bounded: past `max_keys` streams it starts afresh (a stream forgotten so takes its next
/// epoch as its highest).
pub struct StreamFilter {
    epochs: EpochFilter,
    streams: HashMap<String, Stream>,
    recent_frames: usize,
    max_keys: usize,
}

impl Default for StreamFilter {
    fn default() -> Self {
        Self::new(RECENT_FRAMES, MAX_STREAM_KEYS)
    }
}

impl StreamFilter {
    /// A window of `recent_frames` per stream (at least 1), `max_keys` streams (at least 1).
    pub fn new(recent_frames: usize, max_keys: usize) -> Self {
        Self {
            epochs: EpochFilter::new(),
            streams: HashMap::new(),
            recent_frames: recent_frames.max(1),
            max_keys: max_keys.max(1),
        }
    }

    /// The verdict on a message of stream `key`; a delivered one is remembered. A message
    /// without an epoch (a service of before epochs) is judged as a repeat or not only, and
    /// leaves the stream's highest epoch as it was. A new holder's epoch is its stream's
    /// highest from its first message on, even when that message is a repeat.
    pub fn admit(&mut self, key: &str, seq: u64, stamp_ns: u64, epoch: Option<u64>) -> Verdict {
        if !self.streams.contains_key(key) && self.streams.len() >= self.max_keys {
            self.streams.clear();
            self.epochs = EpochFilter::new();
        }
        let before = self.epochs.highest(key);
        if !self.epochs.accept(key, epoch) {
            return Verdict::Stale;
        }
        let stream = self.streams.entry(key.to_owned()).or_default();
        if let (Some(now), Some(before)) = (epoch, before) {
            if now > before {
                stream.handover = stream.recent.back().copied();
            }
        }
        let caught_up = stream.handover.is_none_or(|h| (stamp_ns, seq) > h);
        if stream.recent.contains(&(stamp_ns, seq)) || (epoch.is_some() && !caught_up) {
            return Verdict::Repeat;
        }
        stream.handover = None;
        if stream.recent.len() >= self.recent_frames {
            stream.recent.pop_front();
        }
        stream.recent.push_back((stamp_ns, seq));
        Verdict::Deliver
    }

    /// The highest epoch stream `key` has shown; None when none (or forgotten).
    pub fn highest_epoch(&self, key: &str) -> Option<u64> {
        self.epochs.highest(key)
    }
}

#[cfg(test)]
mod tests {
    //! The cases of the Python `StreamFilter`'s tests (tests/client/test_epoch_fencing.py).
    use super::Verdict::{Deliver, Repeat, Stale};
    use super::*;

    const K: &str = "fleet/car-1/lidar/tracks";

    #[test]
    fn an_exact_repeat_is_caught_per_key_and_a_new_stamp_is_not() {
        let mut f = StreamFilter::default();
        assert_eq!(f.admit(K, 3, 100, None), Deliver);
        assert_eq!(f.admit(K, 3, 100, None), Repeat);
        assert_eq!(f.admit(K, 3, 200, None), Deliver); // a restarted publisher's seq 3
        assert_eq!(f.admit("fleet/car-1/radar/tracks", 3, 100, None), Deliver);
    }

    #[test]
    fn the_window_is_the_last_recent_frames() {
        let mut f = StreamFilter::default();
        for seq in 0..=RECENT_FRAMES as u64 {
            assert_eq!(f.admit("k", seq, seq, None), Deliver);
        }
        assert_eq!(f.admit("k", 0, 0, None), Deliver); // pushed out by the newer ones
        let last = RECENT_FRAMES as u64;
        assert_eq!(f.admit("k", last, last, None), Repeat);
    }

    #[test]
    fn a_lower_epoch_is_stale_an_equal_one_follows_the_repeat_rule() {
        let mut f = StreamFilter::default();
        assert_eq!(f.admit(K, 0, 100, Some(1)), Deliver);
        assert_eq!(f.admit(K, 1, 200, Some(2)), Deliver);
        assert_eq!(f.admit(K, 2, 300, Some(1)), Stale); // a fenced holder, whatever its seq
        assert_eq!(f.admit(K, 1, 200, Some(2)), Repeat); // same epoch, same (seq, stamp)
        assert_eq!(f.admit(K, 1, 250, Some(2)), Deliver); // same epoch, a new stamp
        assert_eq!(f.admit(K, 0, 900, Some(2)), Deliver); // a rebooted vehicle's seq 0 again
        assert_eq!(f.highest_epoch(K), Some(2));
    }

    #[test]
    fn a_new_holders_repeat_is_a_repeat_and_raises_the_epoch() {
        let mut f = StreamFilter::default();
        assert_eq!(f.admit(K, 7, 700, Some(3)), Deliver);
        // The new holder sends again the frame the old one had sent: not delivered twice...
        assert_eq!(f.admit(K, 7, 700, Some(4)), Repeat);
        // ...but it holds the stream now: the old holder's next message is stale.
        assert_eq!(f.admit(K, 8, 800, Some(3)), Stale);
        assert_eq!(f.highest_epoch(K), Some(4));
    }

    #[test]
    fn a_new_holders_replay_after_a_partition_is_delivered_once() {
        let mut f = StreamFilter::new(4, MAX_STREAM_KEYS);
        assert!((0..40).all(|q| f.admit(K, q, q * 100, Some(1)) == Deliver)); // the old holder
        let replay: Vec<Verdict> = (10..45).map(|q| f.admit(K, q, q * 100, Some(2))).collect();
        let mut want = vec![Repeat; 30];
        want.extend([Deliver; 5]);
        assert_eq!(replay, want);
        assert_eq!(f.admit(K, 45, 4500, Some(1)), Stale); // the old holder, still on its side
                                                          // Caught up: a stamp going back (a rebooted vehicle) is a new frame again.
        assert_eq!(f.admit(K, 0, 50, Some(2)), Deliver);
    }

    #[test]
    fn a_new_holders_message_sharing_the_last_stamp_is_delivered() {
        // A fused vehicle's lidar and camera frames can share a stamp, two messages.
        let v = "fleet/veh00/@vehicle/tracks";
        let mut f = StreamFilter::default();
        assert_eq!(f.admit(v, 74, 2900, Some(1)), Deliver);
        assert_eq!(f.admit(v, 75, 3000, Some(1)), Deliver);
        assert_eq!(f.admit(v, 75, 3000, Some(2)), Repeat);
        assert_eq!(f.admit(v, 76, 3000, Some(2)), Deliver);
        assert_eq!(f.admit(v, 77, 3067, Some(2)), Deliver);
        let mut g = StreamFilter::new(1, MAX_STREAM_KEYS); // out of the window: by (stamp, seq)
        assert_eq!(g.admit(v, 75, 3000, Some(1)), Deliver);
        assert_eq!(g.admit(v, 76, 3000, Some(1)), Deliver);
        assert_eq!(g.admit(v, 75, 3000, Some(2)), Repeat);
        assert_eq!(g.admit(v, 76, 3000, Some(2)), Repeat);
    }

    #[test]
    fn no_epoch_is_judged_by_the_repeat_rule_only_and_keeps_the_highest() {
        let mut f = StreamFilter::default();
        let k = "fleet/car-1/@vehicle/tracks";
        assert_eq!(f.admit(k, 0, 100, None), Deliver);
        assert_eq!(f.highest_epoch(k), None);
        assert_eq!(f.admit(k, 1, 200, Some(6)), Deliver);
        assert_eq!(f.admit(k, 2, 300, None), Deliver);
        assert_eq!(f.admit(k, 2, 300, None), Repeat);
        assert_eq!(f.highest_epoch(k), Some(6));
        assert_eq!(f.admit(k, 3, 400, Some(0)), Stale); // epoch 0 is an epoch, lower than 6
    }

    #[test]
    fn streams_are_fenced_each_on_their_own() {
        let mut f = StreamFilter::default();
        assert_eq!(f.admit(K, 0, 100, Some(9)), Deliver);
        assert_eq!(
            f.admit("fleet/car-1/radar/tracks", 0, 100, Some(1)),
            Deliver
        );
        assert_eq!(
            f.admit("fleet/car-2/lidar/tracks", 0, 100, Some(1)),
            Deliver
        );
        assert_eq!(
            f.admit("fleet/car-1/@vehicle/tracks", 0, 100, Some(1)),
            Deliver
        );
    }

    #[test]
    fn memory_is_bounded_forgetting_every_stream_at_once() {
        let mut f = StreamFilter::new(2, 2);
        assert_eq!(f.admit("a", 0, 0, Some(5)), Deliver);
        assert_eq!(f.admit("b", 0, 0, Some(5)), Deliver);
        assert_eq!(f.admit("c", 0, 0, Some(5)), Deliver); // a third: the first two forgotten
        assert_eq!(f.highest_epoch("a"), None);
        assert_eq!(f.admit("a", 1, 1, Some(1)), Deliver); // forgotten: its next is its highest
        for seq in [1, 2] {
            assert_eq!(f.admit("c", seq, seq, Some(5)), Deliver);
        }
        assert_eq!(f.admit("c", 0, 0, Some(5)), Deliver); // out of the window of the 2 newest
    }
}
