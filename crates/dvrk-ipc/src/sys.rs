//! The few system calls the wait strategies need, over libc: the monotonic clock, waiting for
//! file descriptors with a deadline, an absolute-time timer, and the thread's timer slack.

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
    fn timer_slack_is_set_to_one_ns() {
        minimise_timer_slack().unwrap();
        // SAFETY: PR_GET_TIMERSLACK takes no argument and returns the slack.
        let slack = unsafe { libc::prctl(libc::PR_GET_TIMERSLACK, 0, 0, 0, 0) };
        assert_eq!(slack, 1);
    }
}
