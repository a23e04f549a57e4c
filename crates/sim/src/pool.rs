//! A small persistent thread pool for the CPU renderer: a render call hands
//! one job to the pool's workers and waits for all of them (one submission
//! and one synchronisation per call), the calling thread working too.
//! Threads are started once, not per call.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;

/// The job of one call, stored: run with the worker's index (0 is the caller).
type Job = dyn Fn(usize) + Sync + 'static;

/// A borrowed job made storable; only dereferenced while [`Pool::run`], which
/// owns the borrow, waits for every worker to finish with it.
#[derive(Clone, Copy)]
struct JobPtr(*const Job);

// SAFETY: the pointee is `Sync` and outlives every use (see `Pool::run`).
unsafe impl Send for JobPtr {}

struct State {
    generation: u64,
    job: Option<JobPtr>,
    pending: usize,
    panic: Option<Box<dyn std::any::Any + Send>>,
    quit: bool,
}

struct Shared {
    state: Mutex<State>,
    work: Condvar,
    done: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// `threads - 1` workers plus the calling thread.
pub(crate) struct Pool {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for Pool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pool").field("threads", &self.threads()).finish()
    }
}

impl Pool {
    /// A pool running jobs on `threads` threads (the caller and `threads - 1`
    /// workers); an error when a worker cannot be started.
    pub(crate) fn new(threads: usize) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                generation: 0,
                job: None,
                pending: 0,
                panic: None,
                quit: false,
            }),
            work: Condvar::new(),
            done: Condvar::new(),
        });
        let mut workers = Vec::new();
        for index in 1..threads.max(1) {
            let sh = shared.clone();
            let spawned = std::thread::Builder::new()
                .name(format!("render-{index}"))
                .spawn(move || worker(&sh, index));
            match spawned {
                Ok(h) => workers.push(h),
                Err(e) => {
                    // Dropping the pool stops the workers already started.
                    drop(Self { shared, workers });
                    return Err(e);
                }
            }
        }
        Ok(Self { shared, workers })
    }

    /// Threads that run a job, the caller included.
    pub(crate) fn threads(&self) -> usize {
        self.workers.len() + 1
    }

    /// Runs `job(i)` once on each thread `i` (0 is the caller) and returns
    /// when all are done. A panic in any of them is resumed here.
    pub(crate) fn run(&self, job: &(dyn Fn(usize) + Sync + '_)) {
        if self.workers.is_empty() {
            job(0);
            return;
        }
        {
            let mut st = self.shared.lock();
            // SAFETY: the lifetime is erased only for storage; the pointer is
            // cleared below before this function returns, and every worker has
            // finished with it by then (`pending` reached zero).
            let ptr: *const (dyn Fn(usize) + Sync + '_) = job;
            st.job = Some(JobPtr(unsafe {
                std::mem::transmute::<*const (dyn Fn(usize) + Sync + '_), *const Job>(ptr)
            }));
            st.pending = self.workers.len();
            st.generation += 1;
        }
        self.shared.work.notify_all();
        let mine = catch_unwind(AssertUnwindSafe(|| job(0)));
        let mut st = self.shared.lock();
        while st.pending > 0 {
            st = self.shared.done.wait(st).unwrap_or_else(PoisonError::into_inner);
        }
        st.job = None;
        let theirs = st.panic.take();
        drop(st);
        if let Err(p) = mine {
            resume_unwind(p);
        }
        if let Some(p) = theirs {
            resume_unwind(p);
        }
    }
}

fn worker(shared: &Shared, index: usize) {
    let mut seen = 0;
    loop {
        let job = {
            let mut st = shared.lock();
            while st.generation == seen && !st.quit {
                st = shared.work.wait(st).unwrap_or_else(PoisonError::into_inner);
            }
            if st.quit {
                return;
            }
            seen = st.generation;
            st.job
        };
        let result = match job {
            // SAFETY: `Pool::run` keeps the job alive until `pending` is zero.
            Some(JobPtr(f)) => catch_unwind(AssertUnwindSafe(|| unsafe { (*f)(index) })),
            None => Ok(()),
        };
        let mut st = shared.lock();
        if let Err(p) = result {
            st.panic.get_or_insert(p);
        }
        st.pending -= 1;
        if st.pending == 0 {
            shared.done.notify_one();
        }
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.shared.lock().quit = true;
        self.shared.work.notify_all();
        for h in self.workers.drain(..) {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
