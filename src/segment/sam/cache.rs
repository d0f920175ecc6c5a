//! The encoder's outputs of recent frames. The encoder is the costly half of a SAM-family model
//! and depends on the frame alone, while segment-and-solve draws the same frames again in every
//! round and a bump check draws its recorded views again at every check: keeping what the
//! encoder made for them leaves those only the decoder to run.

use std::collections::VecDeque;
use std::hash::{Hash, Hasher};

use easyhec_drivers::Frame;

/// A frame's key: a 64-bit hash of its size and pixels. Two different frames share one by
/// chance about once in 2^64 lookups; making them collide on purpose needs control of the
/// camera's frames, which already decides the masks.
pub(super) fn frame_key(frame: &Frame) -> u64 {
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    (frame.width, frame.height, &frame.rgb).hash(&mut hasher);
    hasher.finish()
}

/// At most `capacity` values by key, the least recently used dropped first.
pub(super) struct RecentlyUsed<V> {
    capacity: usize,
    /// Least recently used first.
    entries: VecDeque<(u64, V)>,
}

impl<V: Clone> RecentlyUsed<V> {
    pub(super) fn new(capacity: usize) -> Self {
        RecentlyUsed {
            capacity: capacity.max(1),
            entries: VecDeque::new(),
        }
    }

    /// The value kept for `key`, now the most recently used.
    pub(super) fn get(&mut self, key: u64) -> Option<V> {
        let at = self.entries.iter().position(|(k, _)| *k == key)?;
        let entry = self.entries.remove(at)?;
        let value = entry.1.clone();
        self.entries.push_back(entry);
        Some(value)
    }

    /// Keeps `value` for `key`, dropping the least recently used past the capacity.
    pub(super) fn insert(&mut self, key: u64, value: V) {
        self.entries.retain(|(k, _)| *k != key);
        while self.entries.len() >= self.capacity {
            self.entries.pop_front();
        }
        self.entries.push_back((key, value));
    }

    #[cfg(test)]
    fn keys(&self) -> Vec<u64> {
        self.entries.iter().map(|(k, _)| *k).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_hit_is_kept_longest_and_the_least_recently_used_goes_first() {
        let mut cache = RecentlyUsed::new(3);
        for k in 1..=3 {
            cache.insert(k, k * 10);
        }
        assert_eq!(cache.get(1), Some(10));
        cache.insert(4, 40);
        // 2 was the least recently used; 1 was used after 3 was kept.
        assert_eq!(cache.keys(), vec![3, 1, 4]);
        assert_eq!(cache.get(2), None);
        cache.insert(3, 31);
        assert_eq!(cache.keys(), vec![1, 4, 3]);
        assert_eq!(cache.get(3), Some(31));
    }

    #[test]
    fn frames_differing_in_one_pixel_or_in_shape_have_different_keys() {
        let frame = |w: u32, h: u32, last: u8| {
            let mut rgb = vec![7u8; (w * h * 3) as usize];
            if let Some(p) = rgb.last_mut() {
                *p = last;
            }
            Frame {
                width: w,
                height: h,
                rgb,
                captured_at: std::time::SystemTime::UNIX_EPOCH,
                sequence: 0,
            }
        };
        let a = frame(4, 6, 7);
        assert_eq!(frame_key(&a), frame_key(&frame(4, 6, 7)));
        assert_ne!(frame_key(&a), frame_key(&frame(4, 6, 8)));
        assert_ne!(frame_key(&a), frame_key(&frame(6, 4, 7)));
    }
}
