//! A bounded, closable hand-off from Zenoh's callback threads to consumers that block or poll.
//! Keeps the newest `capacity` items; older ones are dropped (and counted) when full. Closing
//! wakes every consumer at once.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

struct Inner<T> {
    items: VecDeque<T>,
    closed: bool,
    put_count: u64,
    dropped: u64,
}

pub(crate) struct Mailbox<T> {
    inner: Mutex<Inner<T>>,
    ready: Condvar,
    capacity: usize,
}

impl<T> Mailbox<T> {
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            inner: Mutex::new(Inner {
                items: VecDeque::new(),
                closed: false,
                put_count: 0,
                dropped: 0,
            }),
            ready: Condvar::new(),
            capacity,
        }
    }

    // A consumer that panicked while holding the lock leaves plain data behind: keep going.
    fn lock(&self) -> MutexGuard<'_, Inner<T>> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// From any thread; never blocks.
    pub fn put(&self, item: T) {
        let mut g = self.lock();
        if g.closed {
            return;
        }
        if g.items.len() == self.capacity {
            g.items.pop_front();
            g.dropped += 1;
        }
        g.items.push_back(item);
        g.put_count += 1;
        drop(g);
        self.ready.notify_one();
    }

    pub fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// The oldest item, waiting up to `timeout` (None: until one comes or the mailbox is
    /// closed). None on timeout, or once closed and drained.
    pub fn get(&self, timeout: Option<Duration>) -> Option<T> {
        let deadline = timeout.map(|t| Instant::now() + t);
        let mut g = self.lock();
        loop {
            if let Some(item) = g.items.pop_front() {
                return Some(item);
            }
            if g.closed {
                return None;
            }
            g = match deadline {
                None => self.ready.wait(g).unwrap_or_else(|e| e.into_inner()),
                Some(d) => {
                    let now = Instant::now();
                    if now >= d {
                        return None;
                    }
                    self.ready
                        .wait_timeout(g, d - now)
                        .unwrap_or_else(|e| e.into_inner())
                        .0
                }
            };
        }
    }

    pub fn try_get(&self) -> Option<T> {
        self.lock().items.pop_front()
    }

    pub fn put_count(&self) -> u64 {
        self.lock().put_count
    }

    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn keeps_the_newest_and_counts_the_dropped() {
        let m = Mailbox::new(2);
        (0..5).for_each(|i| m.put(i));
        assert_eq!((m.put_count(), m.dropped()), (5, 3));
        assert_eq!(m.try_get(), Some(3));
        assert_eq!(m.try_get(), Some(4));
        assert_eq!(m.get(Some(Duration::from_millis(10))), None);
    }

    #[test]
    fn close_wakes_a_blocked_consumer_after_the_buffered_items() {
        let m = Arc::new(Mailbox::new(4));
        m.put(1);
        let c = Arc::clone(&m);
        let consumer = std::thread::spawn(move || (c.get(None), c.get(None)));
        std::thread::sleep(Duration::from_millis(50));
        m.close();
        m.put(2); // after close: ignored
        assert_eq!(consumer.join().unwrap(), (Some(1), None));
    }
}
