//! The `hive` processes a benchmark starts (the runs of `bench seeds` and
//! `bench table`), tied to the benchmark's life.

/// Makes a `hive` process a benchmark starts (a run of `bench seeds` or
/// `bench table`) stop when the benchmark does, however it ends (a
/// scheduler's SIGTERM, SIGKILL): the kernel sends it SIGINT, which ends
/// its run as Ctrl-C in a terminal would. Without it a killed harness left
/// its current run training on. (The signal follows the thread that spawned
/// the child: the harnesses spawn from their main thread.)
pub(crate) fn stops_with_this_process(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    let harness = std::process::id();
    // SAFETY: a pre_exec hook runs in the forked child before exec and may
    // only make async-signal-safe calls: these are plain system calls
    // through rustix (prctl(2), getppid(2), getpid(2), kill(2)), which
    // allocate nothing and take no lock.
    unsafe {
        cmd.pre_exec(move || {
            use rustix::process::{Signal, getpid, getppid, kill_process};
            rustix::process::set_parent_process_death_signal(Some(Signal::INT))?;
            // The harness may have died before the prctl took effect.
            if getppid().map(|p| p.as_raw_pid() as u32) != Some(harness) {
                kill_process(getpid(), Signal::INT)?;
            }
            Ok(())
        });
    }
}
