//! A bounded ring the ingest thread appends to without ever waiting: it tries the lock and,
//! if an HTTP reader holds it, keeps the items for its next attempt.

use std::collections::VecDeque;
use std::sync::Mutex;

pub struct Ring<T> {
    items: Mutex<VecDeque<T>>,
    capacity: usize,
}

impl<T: Clone> Ring<T> {
    pub fn new(capacity: usize) -> Self {
        Self {
            items: Mutex::new(VecDeque::with_capacity(capacity.min(1 << 16))),
            capacity,
        }
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Moves `pending` into the ring if the lock is free now (dropping the oldest items beyond
    /// the capacity); otherwise leaves them in `pending`, trimmed to the capacity.
    pub fn try_append(&self, pending: &mut Vec<T>) {
        if pending.is_empty() {
            return;
        }
        match self.items.try_lock() {
            Ok(mut items) => {
                for item in pending.drain(..) {
                    if items.len() == self.capacity {
                        items.pop_front();
                    }
                    items.push_back(item);
                }
            }
            Err(_) => {
                let excess = pending.len().saturating_sub(self.capacity);
                pending.drain(..excess);
            }
        }
    }

    /// Copies the items that pass `keep`, oldest first.
    pub fn collect(&self, keep: impl Fn(&T) -> bool) -> Vec<T> {
        let items = self
            .items
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        items.iter().filter(|item| keep(item)).cloned().collect()
    }

    /// The items of the last `seconds` before the newest one (by `time_s`) that pass `keep`,
    /// oldest first.
    pub fn recent(
        &self,
        seconds: f64,
        time_s: impl Fn(&T) -> f64,
        keep: impl Fn(&T) -> bool,
    ) -> Vec<T> {
        let items = self
            .items
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let newest = items.back().map_or(0.0, &time_s);
        items
            .iter()
            .filter(|item| time_s(item) >= newest - seconds && keep(item))
            .cloned()
            .collect()
    }

    /// The newest item.
    pub fn last(&self) -> Option<T> {
        let items = self
            .items
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        items.back().cloned()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_newest_items_up_to_capacity() {
        let ring = Ring::new(3);
        let mut pending = vec![1, 2, 3, 4, 5];
        ring.try_append(&mut pending);
        assert!(pending.is_empty());
        assert_eq!(ring.collect(|_| true), vec![3, 4, 5]);
        assert_eq!(ring.collect(|&x| x > 3), vec![4, 5]);
        assert_eq!(ring.last(), Some(5));
        assert_eq!(ring.recent(1.0, |&x| x as f64, |_| true), vec![4, 5]);
        assert_eq!(ring.recent(9.0, |&x| x as f64, |&x| x != 4), vec![3, 5]);
    }

    #[test]
    fn a_held_lock_defers_and_trims_instead_of_waiting() {
        let ring = Ring::new(2);
        let guard = ring.items.lock().unwrap();
        let mut pending = vec![1, 2, 3];
        ring.try_append(&mut pending);
        assert_eq!(pending, vec![2, 3]);
        drop(guard);
        ring.try_append(&mut pending);
        assert_eq!(ring.collect(|_| true), vec![2, 3]);
    }
}
