//! A frame's work shared by the calling thread and a few helper threads.
//!
//! The camera conversions (src/capture/pixel_format.rs, src/capture/response.rs) and the
//! decomposition's resampling of a fisheye frame (src/decompose/working_map.rs) cut a frame into
//! fixed chunks (bands of rows) whose results do not depend on which thread computes them. Here
//! the calling thread (capture, decompose) takes chunks itself, one at a time from a shared
//! counter, and a pool's threads help it, instead of handing the whole job to the pool and
//! waiting for it (rayon's `install`). Waking an idle thread costs: on a VM a halted virtual CPU
//! waits for the host (docs/performance.md, "What waking an idle CPU costs on this VM"), on bare
//! metal a deep C-state tens of µs. A helper that starts late just takes fewer chunks; the
//! calling thread, having taken the last chunk, still waits for every helper to have started
//! and found nothing left (the chunks borrow the frame).
//!
//! So a stage of N threads is the calling thread and a pool of N − 1 helpers: [`helper_pool`].

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};

/// The machine's cores (1 if unknown), counted once per process: `available_parallelism`
/// reads the cgroup's files, which cost 10–25% of a fisheye frame's decomposition when it was
/// called every frame (docs/performance.md, "A camera's frames"); the ASG fit asks every frame.
pub fn cores() -> usize {
    static CORES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *CORES.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
}

/// The helpers of a stage of `threads` threads, the calling one included: a pool of
/// min(`threads`, [`cores`]) − 1 threads named `{name}-0`, `{name}-1`, …, or `None` where that
/// is 0 (the calling thread works alone).
pub fn helper_pool(threads: usize, name: &str) -> std::io::Result<Option<rayon::ThreadPool>> {
    let helpers = threads.min(cores()).saturating_sub(1);
    if helpers == 0 {
        return Ok(None);
    }
    let name = name.to_string();
    rayon::ThreadPoolBuilder::new()
        .num_threads(helpers)
        .thread_name(move |i| format!("{name}-{i}"))
        .build()
        .map(Some)
        .map_err(std::io::Error::other)
}

/// Calls `f(i, chunk)` for every chunk `i` of `items` (`chunk_len` items each, the last may be
/// shorter): in order on the calling thread without a pool, else on the calling thread and
/// `pool`'s threads together, each taking the next chunk not yet taken. `chunk_len` 0 counts
/// as 1.
pub fn for_each_chunk_mut<T: Send>(
    pool: Option<&rayon::ThreadPool>,
    items: &mut [T],
    chunk_len: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let chunk_len = chunk_len.max(1);
    let Some(pool) = pool else {
        for (i, chunk) in items.chunks_mut(chunk_len).enumerate() {
            f(i, chunk);
        }
        return;
    };
    // One lock per chunk: each chunk is taken once, so none is ever contended.
    let chunks: Vec<Mutex<&mut [T]>> = items.chunks_mut(chunk_len).map(Mutex::new).collect();
    let next = AtomicUsize::new(0);
    let work = || loop {
        let i = next.fetch_add(1, Ordering::Relaxed);
        let Some(chunk) = chunks.get(i) else {
            break;
        };
        let mut chunk = chunk.lock().unwrap_or_else(PoisonError::into_inner);
        f(i, &mut chunk);
    };
    pool.in_place_scope(|scope| {
        for _ in 0..pool.current_num_threads() {
            scope.spawn(|_| work());
        }
        work();
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every chunk is visited exactly once, with its own index, with or without helpers, and
    /// with chunk lengths that do and do not divide the items.
    #[test]
    fn every_chunk_is_visited_once_with_its_index() {
        let pool = helper_pool(3, "test-helper").unwrap();
        for (chunk_len, n) in [(1, 0), (1, 7), (4, 16), (5, 23), (64, 10), (0, 3)] {
            for pool in [None, pool.as_ref()] {
                let mut items = vec![0usize; n];
                for_each_chunk_mut(pool, &mut items, chunk_len, |i, chunk| {
                    for v in chunk.iter_mut() {
                        *v += i + 1;
                    }
                });
                let expected: Vec<usize> = (0..n).map(|k| k / chunk_len.max(1) + 1).collect();
                assert_eq!(items, expected, "chunk length {chunk_len}, {n} items");
            }
        }
    }

    #[test]
    fn one_thread_needs_no_pool() {
        assert!(helper_pool(1, "test-helper").unwrap().is_none());
        assert!(helper_pool(0, "test-helper").unwrap().is_none());
        if cores() > 1 {
            let pool = helper_pool(2, "test-helper").unwrap().unwrap();
            assert_eq!(pool.current_num_threads(), 1);
        }
    }
}
