//! The CPU renderer's threads (the physics shares them): a render call
//! hands one job to every thread and waits for all of them, the calling
//! thread working too. The threads are a rayon pool of `threads - 1`,
//! started once, not per call.

use std::sync::{Mutex, PoisonError};

use rayon::ThreadPool;

/// `threads - 1` rayon workers plus the calling thread.
pub(crate) struct Pool {
    workers: Option<ThreadPool>,
    threads: usize,
}

impl std::fmt::Debug for Pool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pool").field("threads", &self.threads()).finish()
    }
}

impl Pool {
    /// A pool running jobs on `threads` threads (the caller and `threads - 1`
    /// workers); an error when the workers cannot be started.
    pub(crate) fn new(threads: usize) -> std::io::Result<Self> {
        let threads = threads.max(1);
        let workers = if threads > 1 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads - 1)
                .thread_name(|i| format!("render-{}", i + 1))
                .build()
                .map_err(std::io::Error::other)?;
            Some(pool)
        } else {
            None
        };
        Ok(Self { workers, threads })
    }

    /// Threads that run a job, the caller included.
    pub(crate) fn threads(&self) -> usize {
        self.threads
    }

    /// Runs `job(i)` once for each thread index `i` (0 on the caller) and
    /// returns when all are done. A panic in any of them is resumed here.
    pub(crate) fn run(&self, job: &(dyn Fn(usize) + Sync + '_)) {
        let Some(workers) = &self.workers else {
            job(0);
            return;
        };
        workers.in_place_scope(|s| {
            for i in 1..self.threads {
                s.spawn(move |_| job(i));
            }
            job(0);
        });
    }

    /// Runs `work` on every item of `pieces`, handed out to the threads as
    /// they come free (one lock per piece), and returns when all are done.
    pub(crate) fn share<I>(&self, pieces: I, work: impl Fn(I::Item) + Sync)
    where
        I: Iterator + Send,
    {
        let queue = Mutex::new(pieces);
        self.run(&|_| {
            loop {
                let next = queue.lock().unwrap_or_else(PoisonError::into_inner).next();
                let Some(piece) = next else { break };
                work(piece);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::panic::{AssertUnwindSafe, catch_unwind};
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn every_thread_runs_each_job_once_and_the_borrow_ends_with_the_call() {
        let pool = Pool::new(3).unwrap();
        assert_eq!(pool.threads(), 3);
        for round in 0..200 {
            let hits: Vec<AtomicUsize> = (0..3).map(|_| AtomicUsize::new(0)).collect();
            pool.run(&|i| {
                hits[i].fetch_add(round + 1, Ordering::Relaxed);
            });
            assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == round + 1));
        }
    }

    #[test]
    fn a_panicking_worker_is_reported_to_the_caller_and_the_pool_goes_on() {
        let pool = Pool::new(2).unwrap();
        let r =
            catch_unwind(AssertUnwindSafe(|| pool.run(&|i| assert!(i != 1, "worker one fails"))));
        assert!(r.is_err());
        let n = AtomicUsize::new(0);
        pool.run(&|_| {
            n.fetch_add(1, Ordering::Relaxed);
        });
        assert_eq!(n.load(Ordering::Relaxed), 2);
    }
}
