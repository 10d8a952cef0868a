//! A race-free latest-value slot: one writer publishes, readers take the newest value.
//!
//! The servo thread hands the device pose to the physics thread through one slot, and the
//! physics thread hands the local model back through another (DESIGN §7). Neither side may
//! wait for the other, so the hand-off is neither a lock nor a queue: it is a small array of
//! value slots, each with a count of the readers copying out of it, and an atomic index of
//! the slot that holds the newest value (a triple buffer generalised to several readers).
//!
//! * [`Publisher::publish`] writes into a slot that is neither current nor being read, then
//!   makes it current. With `max_readers` reader handles there are `max_readers + 2` slots:
//!   at most one is pinned per reader plus the current one, so a free slot always exists and
//!   the writer never waits.
//! * [`Reader::read`] pins the current slot (increments its reader count), checks that it is
//!   still current, copies the value out and unpins it. If the writer made another slot
//!   current in between, it unpins and retries: it never waits for the writer to finish
//!   anything, because the slot it retries on was complete before it became current.
//! * Nothing allocates after construction; values are `Copy`.
//!
//! Every value carries the sequence number it was published with (the initial value has 0),
//! so a reader can tell a new value from one it has already seen; the sequence a reader sees
//! never goes backwards.
//!
//! Unlike a seqlock, no read ever overlaps a write of the same bytes, so the scheme is sound
//! under the Rust (C++20) memory model without volatile tricks; the argument is written at
//! the two `unsafe` blocks.

use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicUsize, Ordering::SeqCst};
use std::sync::Arc;

/// One value buffer and the number of readers currently copying out of it.
struct Slot<T> {
    readers: AtomicUsize,
    value: UnsafeCell<(T, u64)>,
}

/// The shared part of a latest-value slot. Create one with [`LatestValue::channel`]; write
/// through the single [`Publisher`], read through [`Reader`] handles.
pub struct LatestValue<T> {
    slots: Box<[Slot<T>]>,
    /// Index of the slot holding the newest complete value.
    current: AtomicUsize,
    /// Reader handles alive.
    handles: AtomicUsize,
    /// The most reader handles that may exist at once.
    max_readers: usize,
}

// SAFETY: the values are only ever moved between threads by copy (`T: Copy + Send`), and
// every access to a slot's `UnsafeCell` follows the protocol argued in `publish` and `read`,
// which never lets a write overlap another access to the same slot.
unsafe impl<T: Copy + Send> Sync for LatestValue<T> {}

/// The single writer of a [`LatestValue`]. Not `Clone`: one writer is what makes the writer's
/// choice of a free slot race-free.
pub struct Publisher<T> {
    shared: Arc<LatestValue<T>>,
    sequence: u64,
}

/// A reader handle of a [`LatestValue`]. `read` takes `&mut self`, so one handle pins at most
/// one slot at a time; the number of handles is bounded at construction.
pub struct Reader<T: Copy + Default + Send> {
    shared: Arc<LatestValue<T>>,
    last_sequence: u64,
}

impl<T: Copy + Default + Send> LatestValue<T> {
    /// A slot holding `T::default()` with sequence 0, its publisher and one reader handle;
    /// up to `max_readers` (at least 1) reader handles may exist at once.
    pub fn channel(max_readers: usize) -> (Publisher<T>, Reader<T>) {
        Self::channel_with(T::default(), max_readers)
    }

    /// As [`LatestValue::channel`], starting from `initial` (sequence 0).
    pub fn channel_with(initial: T, max_readers: usize) -> (Publisher<T>, Reader<T>) {
        let max_readers = max_readers.max(1);
        let slots = (0..max_readers + 2)
            .map(|_| Slot {
                readers: AtomicUsize::new(0),
                value: UnsafeCell::new((initial, 0)),
            })
            .collect();
        let shared = Arc::new(LatestValue {
            slots,
            current: AtomicUsize::new(0),
            handles: AtomicUsize::new(1),
            max_readers,
        });
        let reader = Reader {
            shared: Arc::clone(&shared),
            last_sequence: 0,
        };
        (
            Publisher {
                shared,
                sequence: 0,
            },
            reader,
        )
    }

    /// A new reader handle, or `None` when `max_readers` handles already exist.
    fn new_reader(self: &Arc<Self>) -> Option<Reader<T>> {
        let mut n = self.handles.load(SeqCst);
        loop {
            if n >= self.max_readers {
                return None;
            }
            match self.handles.compare_exchange(n, n + 1, SeqCst, SeqCst) {
                Ok(_) => {
                    return Some(Reader {
                        shared: Arc::clone(self),
                        last_sequence: 0,
                    })
                }
                Err(actual) => n = actual,
            }
        }
    }
}

impl<T: Copy + Default + Send> Publisher<T> {
    /// Publish `value` as the newest; returns its sequence number (1, 2, …). Never waits,
    /// never allocates.
    pub fn publish(&mut self, value: T) -> u64 {
        let shared = &*self.shared;
        self.sequence += 1;
        // Only this publisher stores `current`, so this load sees our own last store.
        let current = shared.current.load(SeqCst);
        loop {
            for (index, slot) in shared.slots.iter().enumerate() {
                if index == current || slot.readers.load(SeqCst) != 0 {
                    continue;
                }
                // SAFETY: no reader copies out of this slot now or until it becomes current.
                // A reader reads a slot only after (a) pinning it and (b) seeing `current`
                // equal its index. If its pin came after our check above in the SeqCst order,
                // (b) can only observe the store below, which is ordered after this write.
                // If its pin came before the check, the check saw it (or saw the unpin, an
                // RMW with release semantics, so that reader's copy happened-before this
                // write). Only this publisher writes slots, so no two writes overlap.
                unsafe { *slot.value.get() = (value, self.sequence) };
                shared.current.store(index, SeqCst);
                return self.sequence;
            }
            // Unreachable while the handle bound holds (max_readers + 2 slots, at most one
            // pinned per handle plus the current one); kept as a bounded-by-readers retry.
            std::hint::spin_loop();
        }
    }

    /// The sequence number of the last published value (0 before the first publish).
    pub fn sequence(&self) -> u64 {
        self.sequence
    }

    /// A new reader handle, or `None` when the slot's `max_readers` handles exist.
    pub fn reader(&self) -> Option<Reader<T>> {
        self.shared.new_reader()
    }
}

impl<T: Copy + Default + Send> Reader<T> {
    /// The newest value and its sequence number (0 = the initial value). Never waits for the
    /// writer (it retries only when the writer made a newer value current meanwhile), never
    /// allocates, never returns a torn value.
    pub fn read(&mut self) -> (T, u64) {
        let shared = &*self.shared;
        loop {
            let index = shared.current.load(SeqCst);
            let slot = &shared.slots[index];
            slot.readers.fetch_add(1, SeqCst);
            if shared.current.load(SeqCst) == index {
                // SAFETY: the slot is pinned and was current after the pin. The publisher
                // writes only slots that are not current and whose reader count it read as 0.
                // Any write it starts after our pin sees the pin and skips this slot; a write
                // whose check preceded our pin belongs to a slot that was not current at the
                // check, and `current` can equal `index` again (as we just saw) only through
                // the publisher's store after that write completed; the SeqCst load
                // synchronises with that store, so the write happened-before this copy.
                let (value, sequence) = unsafe { *slot.value.get() };
                slot.readers.fetch_sub(1, SeqCst);
                self.last_sequence = self.last_sequence.max(sequence);
                return (value, sequence);
            }
            slot.readers.fetch_sub(1, SeqCst);
            std::hint::spin_loop();
        }
    }

    /// The newest value if it was published after the last value this handle returned.
    pub fn read_new(&mut self) -> Option<(T, u64)> {
        let seen = self.last_sequence;
        let (value, sequence) = self.read();
        (sequence > seen).then_some((value, sequence))
    }

    /// Another reader handle of the same slot, or `None` when `max_readers` handles exist.
    pub fn try_clone(&self) -> Option<Reader<T>> {
        self.shared.new_reader()
    }
}

impl<T: Copy + Default + Send> Drop for Reader<T> {
    fn drop(&mut self) {
        self.shared.handles.fetch_sub(1, SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_and_value() {
        let (mut p, mut r) = LatestValue::<u64>::channel(2);
        assert_eq!(r.read(), (0, 0));
        assert_eq!(p.publish(7), 1);
        assert_eq!(r.read(), (7, 1));
        assert_eq!(r.read_new(), None);
        p.publish(9);
        assert_eq!(r.read_new(), Some((9, 2)));
    }

    #[test]
    fn reader_handles_are_bounded() {
        let (p, r) = LatestValue::<u32>::channel(2);
        let r2 = r.try_clone().expect("second handle");
        assert!(p.reader().is_none());
        drop(r2);
        assert!(p.reader().is_some());
    }
}
