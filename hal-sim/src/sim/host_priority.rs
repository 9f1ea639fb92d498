//! The host scheduling of the real-time line's threads ([`super::ethercat_line`], "Real time").
//!
//! A master on a real machine runs its cycle thread at a real-time priority (SCHED_FIFO), and so must the
//! simulator that stands for the slaves when both share a loaded 2-core host: at the normal policy, the frame
//! path waits behind whatever else runs and answers milliseconds late. The priority is given from outside
//! (`chrt -f P drive-sim ...`, inherited by every thread); the drive workers then step down below the frame
//! path, so that a frame preempts the stepping at once rather than waiting for a worker to reach its next
//! turn (two workers at the frame path's own priority hold both cores while they are behind the wall clock).
//! Lowering a real-time priority needs no privilege (sched(7), RLIMIT_RTPRIO), so this works in the
//! unprivileged network namespace the tests run in.

/// The calling thread's scheduling: the policy's name and its real-time priority (0 for the normal policy).
#[must_use]
pub fn current() -> (&'static str, i32) {
    let (policy, priority) = sys::current();
    let name = match policy {
        libc::SCHED_FIFO => "SCHED_FIFO",
        libc::SCHED_RR => "SCHED_RR",
        libc::SCHED_OTHER => "SCHED_OTHER",
        _ => "other",
    };
    (name, priority)
}

/// Steps the calling thread one real-time priority below the one it inherited (or to the normal policy from
/// priority 1); nothing at the normal policy. Returns the thread's priority after the call (0: normal).
pub fn step_below_inherited() -> i32 {
    let (policy, priority) = sys::current();
    if policy != libc::SCHED_FIFO && policy != libc::SCHED_RR {
        return 0;
    }
    let lower = priority.saturating_sub(1);
    let applied = if lower >= 1 { sys::set(policy, lower) } else { sys::set(libc::SCHED_OTHER, 0) };
    if applied.is_ok() {
        lower.max(0)
    } else {
        priority
    }
}

/// The scheduling FFI. Each call passes the calling thread (id 0) and a pointer to a live local, and its result
/// is checked.
#[allow(unsafe_code)]
mod sys {
    use std::io;

    /// `sched_getscheduler(0)` and `sched_getparam(0)`: the calling thread's policy and priority.
    pub fn current() -> (i32, i32) {
        // SAFETY: no pointer; 0 names the calling thread.
        let policy = unsafe { libc::sched_getscheduler(0) };
        let mut param = libc::sched_param { sched_priority: 0 };
        // SAFETY: `param` is a live local of the type the call writes.
        let got = unsafe { libc::sched_getparam(0, &raw mut param) };
        (policy, if got == 0 { param.sched_priority } else { 0 })
    }

    /// `sched_setscheduler(0, policy, {priority})` for the calling thread (Linux applies it to the thread).
    pub fn set(policy: i32, priority: i32) -> io::Result<()> {
        let param = libc::sched_param { sched_priority: priority };
        // SAFETY: `param` is a live local the call only reads.
        if unsafe { libc::sched_setscheduler(0, policy, &raw const param) } == 0 {
            Ok(())
        } else {
            Err(io::Error::last_os_error())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At the normal policy (how the tests run) a worker stays where it is: 0, the normal policy, unchanged.
    #[test]
    fn a_thread_at_the_normal_policy_stays_there() {
        let before = current();
        if before.0 != "SCHED_OTHER" {
            return;
        }
        assert_eq!(std::thread::spawn(step_below_inherited).join().ok(), Some(0));
        assert_eq!(current(), before);
    }

    /// From a real-time priority a worker steps one below it, and from priority 1 to the normal policy, on its
    /// own thread only. Needs the privilege to raise a thread first (root or CAP_SYS_NICE); without it there is
    /// nothing to step down from and the case proves nothing, so it returns.
    #[test]
    fn a_real_time_thread_steps_one_priority_below_and_from_1_to_the_normal_policy() {
        let steps = std::thread::spawn(|| {
            sys::set(libc::SCHED_FIFO, 2).ok()?;
            let first = (step_below_inherited(), current());
            let second = (step_below_inherited(), current());
            Some((first, second))
        })
        .join()
        .ok()
        .flatten();
        let Some((first, second)) = steps else { return };
        assert_eq!(first, (1, ("SCHED_FIFO", 1)));
        assert_eq!(second, (0, ("SCHED_OTHER", 0)));
        assert_eq!(current().0, "SCHED_OTHER", "the test's own thread is untouched");
    }
}
