//! The few system calls the wait strategies need, over libc: the monotonic clock, waiting for
//! file descriptors with a deadline, an absolute-time timer, and the thread's timer slack and
//! time slice.

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

pub use crate::clock::monotonic_ns;

fn timespec(ns: u64) -> libc::timespec {
    libc::timespec {
        tv_sec: (ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (ns % 1_000_000_000) as libc::c_long,
    }
}

/// What woke [`wait_readable`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ready {
    /// The first descriptor (the cycle event) is readable.
    Event,
    /// Only the second descriptor (the timer) is readable.
    Timer,
    /// `until_ns` passed.
    TimedOut,
    /// A signal handler ran.
    Interrupted,
}

/// Sleeps until `event` (or `timer`, if given) is readable or CLOCK_MONOTONIC reaches
/// `until_ns`. One `ppoll`; errors are the errno.
pub fn wait_readable(event: i32, timer: Option<i32>, until_ns: u64) -> Result<Ready, i32> {
    let now = monotonic_ns();
    if until_ns <= now {
        return Ok(Ready::TimedOut);
    }
    let ts = timespec(until_ns - now);
    let mut fds = [
        libc::pollfd {
            fd: event,
            events: libc::POLLIN,
            revents: 0,
        },
        libc::pollfd {
            fd: timer.unwrap_or(-1),
            events: libc::POLLIN,
            revents: 0,
        },
    ];
    let n: libc::nfds_t = if timer.is_some() { 2 } else { 1 };
    // SAFETY: `fds` holds `n` valid pollfd entries and outlives the call; `ts` is a valid
    // relative timeout; a null signal mask keeps the thread's mask.
    let rc = unsafe { libc::ppoll(fds.as_mut_ptr(), n, &ts, std::ptr::null()) };
    if rc < 0 {
        let errno = io::Error::last_os_error().raw_os_error().unwrap_or(0);
        return if errno == libc::EINTR {
            Ok(Ready::Interrupted)
        } else {
            Err(errno)
        };
    }
    if rc == 0 {
        return Ok(Ready::TimedOut);
    }
    if fds[0].revents != 0 {
        Ok(Ready::Event)
    } else {
        Ok(Ready::Timer)
    }
}

/// A CLOCK_MONOTONIC timerfd armed at absolute times.
#[derive(Debug)]
pub struct TimerFd(OwnedFd);

impl TimerFd {
    pub fn new() -> io::Result<Self> {
        // SAFETY: plain syscall; the returned descriptor is checked and then owned.
        let fd = unsafe {
            libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_NONBLOCK | libc::TFD_CLOEXEC,
            )
        };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` is a fresh descriptor owned by nobody else.
        Ok(Self(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    pub fn fd(&self) -> i32 {
        self.0.as_raw_fd()
    }

    /// Arms the timer to expire once at CLOCK_MONOTONIC `t_ns` (absolute). Re-arming clears a
    /// previous expiry that was not read.
    pub fn arm_at(&self, t_ns: u64) -> Result<(), i32> {
        let spec = libc::itimerspec {
            it_interval: timespec(0),
            it_value: timespec(t_ns.max(1)),
        };
        // SAFETY: valid descriptor and itimerspec; the old value is not requested.
        let rc = unsafe {
            libc::timerfd_settime(
                self.fd(),
                libc::TFD_TIMER_ABSTIME,
                &spec,
                std::ptr::null_mut(),
            )
        };
        if rc < 0 {
            return Err(io::Error::last_os_error().raw_os_error().unwrap_or(0));
        }
        Ok(())
    }
}

/// Sets the calling thread's timer slack to 1 ns, so timers (the predictive wake-up) are not
/// deferred by the default 50 µs.
pub fn minimise_timer_slack() -> io::Result<()> {
    // SAFETY: PR_SET_TIMERSLACK takes one unsigned long argument; the others are ignored.
    let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    if rc < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// The time slice an event or predictive subscriber's thread asks for: the shortest the
/// kernel accepts (it clamps a requested slice to 0.1-100 ms).
pub const SHORT_SLICE_NS: u64 = 100_000;

/// The calling thread's scheduling attributes (`sched_getattr`, the first, 48-byte version of
/// the structure).
fn thread_sched_attr() -> io::Result<libc::sched_attr> {
    // SAFETY: sched_attr is plain data; all-zero is a valid value.
    let mut attr: libc::sched_attr = unsafe { std::mem::zeroed() };
    let size = std::mem::size_of::<libc::sched_attr>() as libc::c_uint;
    // SAFETY: pid 0 is the calling thread; the kernel writes at most `size` bytes into `attr`.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_sched_getattr,
            0,
            &mut attr as *mut libc::sched_attr,
            size,
            0,
        )
    };
    if rc < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(attr)
}

/// The calling thread's time slice as the kernel reports it (ns): the slice it asked for, 0 when
/// it never asked, or a kernel older than 6.12 (whose fair scheduler has no per-task slice).
#[cfg(test)]
fn thread_slice_ns() -> io::Result<u64> {
    thread_sched_attr().map(|a| a.sched_runtime)
}

/// Asks the kernel for a short time slice ([`SHORT_SLICE_NS`]) for the calling thread, when it
/// runs under the normal policy (`SCHED_OTHER`); its nice value is kept, and a thread under
/// another policy (a real-time one, batch or idle) is left as it is (`Ok(false)`).
///
/// What it changes: since Linux 6.12 the fair scheduler (EEVDF) takes a normal task's
/// `sched_runtime` as its slice, and a task woken with a shorter slice than the running one's
/// preempts it at once instead of waiting for that task to sleep or use up its own slice.
/// A subscriber woken by the service on the service's CPU then takes its sample while the
/// service finishes its cycle, rather than after. Its share of the CPU does not change (that is
/// the weight, from the nice value), and no privilege is needed. Threads the caller starts
/// afterwards inherit it (as they inherit its nice value). Older kernels accept and ignore it.
pub fn request_short_slice() -> io::Result<bool> {
    let mut attr = thread_sched_attr()?;
    if attr.sched_policy != libc::SCHED_OTHER as u32 {
        return Ok(false);
    }
    attr.size = std::mem::size_of::<libc::sched_attr>() as u32;
    attr.sched_runtime = SHORT_SLICE_NS;
    // Only the flag a normal thread may carry in this version of the structure (utilisation
    // clamps would need the longer one).
    attr.sched_flags &= libc::SCHED_FLAG_RESET_ON_FORK as u64;
    // SAFETY: pid 0 is the calling thread; `attr` is a complete structure of `attr.size` bytes.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_sched_setattr,
            0,
            &attr as *const libc::sched_attr,
            0,
        )
    };
    if rc < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timer_wakes_a_poll_at_its_absolute_time() {
        let t = TimerFd::new().unwrap();
        // A descriptor that never becomes readable stands in for the event.
        let (r, _w) = std::os::unix::net::UnixDatagram::pair().unwrap();
        let start = monotonic_ns();
        t.arm_at(start + 2_000_000).unwrap();
        let got = wait_readable(r.as_raw_fd(), Some(t.fd()), start + 1_000_000_000).unwrap();
        assert_eq!(got, Ready::Timer);
        assert!(monotonic_ns() >= start + 2_000_000, "not before its time");
        // Re-arming clears the expiry: the next wait times out instead.
        t.arm_at(monotonic_ns() + 1_000_000_000).unwrap();
        let got = wait_readable(r.as_raw_fd(), Some(t.fd()), monotonic_ns() + 1_000_000).unwrap();
        assert_eq!(got, Ready::TimedOut);
    }

    #[test]
    fn event_wins_over_a_later_timer() {
        let t = TimerFd::new().unwrap();
        let (r, w) = std::os::unix::net::UnixDatagram::pair().unwrap();
        w.send(b"x").unwrap();
        t.arm_at(monotonic_ns() + 1_000_000_000).unwrap();
        let got = wait_readable(r.as_raw_fd(), Some(t.fd()), monotonic_ns() + 1_000_000_000);
        assert_eq!(got, Ok(Ready::Event));
    }

    #[test]
    fn a_normal_thread_gets_the_short_slice_and_keeps_its_nice_value() {
        // A thread of its own: the attributes are per thread, and this test must not leave
        // the test harness's threads changed.
        std::thread::spawn(|| {
            // SAFETY: setpriority on the calling thread (who = 0 is the caller's tid for
            // PRIO_PROCESS on Linux); raising the nice value needs no privilege.
            let rc = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, 3) };
            assert_eq!(rc, 0, "{}", io::Error::last_os_error());
            assert!(
                request_short_slice().unwrap(),
                "a SCHED_OTHER thread is changed"
            );
            let attr = thread_sched_attr().unwrap();
            assert_eq!(attr.sched_policy, libc::SCHED_OTHER as u32);
            assert_eq!(attr.sched_nice, 3, "the nice value is kept");
            let slice = thread_slice_ns().unwrap();
            // 6.12 and later report the slice asked for; older kernels have none to report.
            assert!(
                slice == SHORT_SLICE_NS || slice == 0,
                "slice {slice} ns, asked {SHORT_SLICE_NS}"
            );
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_thread_under_another_policy_is_left_as_it_is() {
        std::thread::spawn(|| {
            // SCHED_BATCH needs no privilege.
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: pid 0 is the calling thread; `param` is valid for SCHED_BATCH.
            let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_BATCH, &param) };
            assert_eq!(rc, 0, "{}", io::Error::last_os_error());
            let before = thread_slice_ns().unwrap();
            assert!(!request_short_slice().unwrap());
            assert_eq!(
                thread_sched_attr().unwrap().sched_policy,
                libc::SCHED_BATCH as u32
            );
            assert_eq!(thread_slice_ns().unwrap(), before);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn timer_slack_is_set_to_one_ns() {
        minimise_timer_slack().unwrap();
        // SAFETY: PR_GET_TIMERSLACK takes no argument and returns the slack.
        let slack = unsafe { libc::prctl(libc::PR_GET_TIMERSLACK, 0, 0, 0, 0) };
        assert_eq!(slack, 1);
    }
}
