//! Frames prepared ahead of tracking: loading and keypoint detection for frames `t + 1, …`
//! run on worker threads while frame `t` is tracked, and reach tracking in frame order.
//!
//! Each worker runs its frame on a rayon pool of its own (the machine's threads shared out
//! among the workers), so two workers on two cores each run a whole network pass on one
//! core instead of splitting every layer of one pass in two: no core waits at a layer's end
//! for the other, which the mapping and correction threads keep busy at times. What a frame
//! gives does not depend on which worker prepared it.

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::mpsc::channel;
use std::sync::{Condvar, Mutex};

/// Where the workers stand: the next index to hand out, how many items were consumed, and
/// whether the consumer is done (stopped early, finished or panicking).
struct State {
    next: usize,
    consumed: usize,
    done: bool,
}

struct Shared {
    state: Mutex<State>,
    changed: Condvar,
}

impl Shared {
    fn update(&self, f: impl FnOnce(&mut State)) {
        f(&mut self.state.lock().unwrap_or_else(|e| e.into_inner()));
        self.changed.notify_all();
    }
}

/// Tells the workers to stop when the consumer leaves, whichever way it leaves.
struct Finish<'a>(&'a Shared);

impl Drop for Finish<'_> {
    fn drop(&mut self) {
        self.0.update(|s| s.done = true);
    }
}

/// `produce(i)` for `i` in `0..n` on `workers` threads (at most `2·workers` items ahead of
/// the consumer), `consume(i, item)` on the calling thread in order of `i` until it returns
/// `false`. A panic in `produce` resumes on the calling thread once the items before it
/// are consumed.
pub(crate) fn ordered_map<T: Send>(
    n: usize,
    workers: usize,
    produce: impl Fn(usize) -> T + Sync,
    mut consume: impl FnMut(usize, T) -> bool,
) {
    let workers = workers.clamp(1, n.max(1));
    let ahead = 2 * workers;
    let per_worker = (rayon::current_num_threads() / workers).max(1);
    let shared = Shared {
        state: Mutex::new(State {
            next: 0,
            consumed: 0,
            done: false,
        }),
        changed: Condvar::new(),
    };
    let (shared, produce) = (&shared, &produce);
    std::thread::scope(|s| {
        // Before the workers start: whichever way this thread leaves (a worker that could
        // not be spawned included), the others are told to stop.
        let _finish = Finish(shared);
        let (tx, rx) = channel::<(usize, std::thread::Result<T>)>();
        for _ in 0..workers {
            let tx = tx.clone();
            s.spawn(move || {
                // Without a pool of its own (the system refused threads) a worker uses the
                // global one: the same results, only slower.
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(per_worker)
                    .build()
                    .ok();
                loop {
                    let i = {
                        let mut st = shared.state.lock().unwrap_or_else(|e| e.into_inner());
                        while !st.done && st.next < n && st.next >= st.consumed + ahead {
                            st = shared.changed.wait(st).unwrap_or_else(|e| e.into_inner());
                        }
                        if st.done || st.next >= n {
                            break;
                        }
                        st.next += 1;
                        st.next - 1
                    };
                    let run = || catch_unwind(AssertUnwindSafe(|| produce(i)));
                    let item = match &pool {
                        Some(p) => p.install(run),
                        None => run(),
                    };
                    if tx.send((i, item)).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        let mut pending = BTreeMap::new();
        let mut want = 0;
        for (i, item) in rx {
            pending.insert(i, item);
            while let Some(item) = pending.remove(&want) {
                let item = item.unwrap_or_else(|panic| resume_unwind(panic));
                if !consume(want, item) {
                    return;
                }
                want += 1;
                shared.update(|s| s.consumed = want);
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn items_arrive_in_order_whatever_the_workers_take() {
        for workers in [1, 2, 3, 8] {
            let mut seen = Vec::new();
            ordered_map(
                25,
                workers,
                |i| {
                    // Uneven work: later items often finish first.
                    std::thread::sleep(std::time::Duration::from_micros(
                        ((i * 7) % 5) as u64 * 300,
                    ));
                    i * i
                },
                |i, v| {
                    seen.push((i, v));
                    true
                },
            );
            let want: Vec<_> = (0..25).map(|i| (i, i * i)).collect();
            assert_eq!(seen, want, "{workers} workers");
        }
        let mut none = 0;
        ordered_map(
            0,
            2,
            |i| i,
            |_, _| {
                none += 1;
                true
            },
        );
        assert_eq!(none, 0);
    }

    #[test]
    fn stopping_early_stops_the_workers_within_the_look_ahead() {
        let produced = AtomicUsize::new(0);
        let mut consumed = 0;
        ordered_map(
            1000,
            2,
            |i| {
                produced.fetch_add(1, Ordering::SeqCst);
                i
            },
            |i, _| {
                consumed += 1;
                i < 4
            },
        );
        assert_eq!(consumed, 5);
        // Items 0..=4 consumed, at most 2·workers more prepared ahead.
        assert!(produced.load(Ordering::SeqCst) <= 4 + 4 + 1);
    }

    #[test]
    fn a_panicking_item_panics_the_caller_after_the_items_before_it() {
        let mut consumed = Vec::new();
        let result = catch_unwind(AssertUnwindSafe(|| {
            ordered_map(
                10,
                2,
                |i| {
                    assert!(i != 6, "item six");
                    i
                },
                |i, _| {
                    consumed.push(i);
                    true
                },
            )
        }));
        assert!(result.is_err());
        assert_eq!(consumed, (0..6).collect::<Vec<_>>());
    }
}
