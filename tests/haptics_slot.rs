//! The latest-value slot under contention: a writer publishes structs whose fields all equal
//! a counter as fast as it can; readers check that every value they read is whole (no torn
//! struct), that it carries its own sequence number, and that sequences never go back.

use palpate::haptics::slot::LatestValue;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

/// 16 words: a torn copy would mix counters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Wide {
    words: [u64; 16],
}

const READERS: usize = 3;
/// The writer keeps publishing until the readers have together seen this many new values,
/// or for 3 s on a machine too busy to get there; at least [`MIN_NEW_VALUES`] must have been
/// seen for the test to count (reads and writes overlapped).
const TARGET_NEW_VALUES: u64 = 30_000;
const MIN_NEW_VALUES: u64 = 1_000;

#[test]
fn readers_never_see_torn_or_older_values() {
    let (mut publisher, first) = LatestValue::<Wide>::channel(READERS);
    let mut readers = vec![first];
    for _ in 1..READERS {
        readers.push(publisher.reader().expect("a reader handle"));
    }
    assert!(publisher.reader().is_none(), "the handle bound holds");
    let seen = Arc::new(AtomicU64::new(0));
    let final_sequence = Arc::new(AtomicU64::new(u64::MAX));

    let handles: Vec<_> = readers
        .into_iter()
        .map(|mut reader| {
            let seen = Arc::clone(&seen);
            let final_sequence = Arc::clone(&final_sequence);
            thread::spawn(move || {
                let mut last = 0u64;
                let (mut n, mut distinct) = (0u64, 0u64);
                while last != final_sequence.load(Ordering::Acquire) {
                    let (value, sequence) = reader.read();
                    n += 1;
                    let w = value.words[0];
                    assert!(
                        value.words.iter().all(|&x| x == w),
                        "torn value {:?}",
                        value.words
                    );
                    assert_eq!(w, sequence, "value and sequence travel together");
                    assert!(sequence >= last, "sequence went back: {sequence} < {last}");
                    if sequence > last {
                        distinct += 1;
                        seen.fetch_add(1, Ordering::Relaxed);
                    }
                    last = sequence;
                    // Four threads share two cores on CI: give the writer its turn now and then.
                    if n % 64 == 0 {
                        thread::yield_now();
                    }
                }
                (n, distinct)
            })
        })
        .collect();

    let give_up = Instant::now() + Duration::from_secs(3);
    let mut k = 0u64;
    while seen.load(Ordering::Relaxed) < TARGET_NEW_VALUES && Instant::now() < give_up {
        k += 1;
        assert_eq!(publisher.publish(Wide { words: [k; 16] }), k);
        // About a microsecond between publishes: a thousand times the physics thread's rate,
        // and room for a read to complete (a writer publishing back to back only makes
        // readers retry).
        for _ in 0..300 {
            std::hint::spin_loop();
        }
    }
    k += 1;
    publisher.publish(Wide { words: [k; 16] });
    final_sequence.store(k, Ordering::Release);
    let mut total_distinct = 0;
    for h in handles {
        let (n, distinct) = h.join().expect("reader thread");
        println!("reader: {n} reads, {distinct} distinct values (of {k} published)");
        total_distinct += distinct;
    }
    assert!(
        total_distinct >= MIN_NEW_VALUES,
        "reads and writes overlapped too little: {total_distinct} new values seen"
    );
}

#[test]
fn read_new_reports_only_new_values() {
    let (mut p, mut r) = LatestValue::<u32>::channel(1);
    assert_eq!(r.read_new(), None, "the initial value is not new");
    p.publish(3);
    p.publish(4);
    assert_eq!(
        r.read_new(),
        Some((4, 2)),
        "the newest, skipping older ones"
    );
    assert_eq!(r.read_new(), None);
}
