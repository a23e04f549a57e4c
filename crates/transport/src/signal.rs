//! What a signal does to a rotorhive process: SIGINT, SIGTERM and SIGHUP
//! ask every loop to stop; a child dies with the process that started it.

use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

/// Asks every loop of this process to stop (as SIGTERM would).
pub fn request_stop() {
    STOP.store(true, Ordering::SeqCst);
}

/// True once [`request_stop`] was called or a handled signal arrived
/// (SIGHUP after [`handle_hangup`]; SIGINT and SIGTERM are seen through a
/// hub's [`Hub::shutdown_requested`]).
pub fn stop_requested() -> bool {
    STOP.load(Ordering::SeqCst)
}

extern "C" fn on_hangup(_: libc::c_int) {
    // Only an atomic store: async-signal-safe.
    STOP.store(true, Ordering::SeqCst);
}

/// Makes SIGHUP (a closed terminal, a dropped SSH session) a request to stop
/// cleanly, like SIGINT and SIGTERM, instead of killing the process with its
/// shared memory left behind.
pub fn handle_hangup() {
    // SAFETY: installs a handler that only stores to an atomic; the
    // sigaction struct is fully initialised (zeroed, then the handler set).
    unsafe {
        let mut sa: libc::sigaction = std::mem::zeroed();
        sa.sa_sigaction = on_hangup as *const () as libc::sighandler_t;
        libc::sigemptyset(&mut sa.sa_mask);
        libc::sigaction(libc::SIGHUP, &sa, std::ptr::null_mut());
    }
}

/// Makes a child process about to be started by `cmd` receive `signal` when
/// this process's spawning thread ends, however it ends (SIGKILL, the OOM
/// killer): `PR_SET_PDEATHSIG`, set in the child before it runs, and the
/// signal sent at once if this process died before that took effect. The
/// supervisor ties its roles to itself (SIGTERM); `hive bench seeds` and
/// `bench table` tie their runs (SIGINT, which ends a run as Ctrl-C does).
pub fn dies_with_this_process(cmd: &mut std::process::Command, signal: rustix::process::Signal) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id();
    // SAFETY: a pre_exec hook runs in the forked child before exec and may
    // only make async-signal-safe calls: these are plain system calls
    // through rustix (prctl(2), getppid(2), getpid(2), kill(2)), which
    // allocate nothing and take no lock.
    unsafe {
        cmd.pre_exec(move || {
            use rustix::process::{getpid, getppid, kill_process};
            rustix::process::set_parent_process_death_signal(Some(signal))?;
            // The parent may have died before the prctl took effect.
            if getppid().map(|p| p.as_raw_pid() as u32) != Some(parent) {
                kill_process(getpid(), signal)?;
            }
            Ok(())
        });
    }
}
