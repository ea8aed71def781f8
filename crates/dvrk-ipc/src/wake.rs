//! The cycle's wake-up: one futex word per cycle event, in a small file of the domain's root
//! directory, that the publisher bumps once per cycle and wakes its sleepers with: one at a
//! time while they are few, all in one system call when many.
//!
//! Why not iceoryx2's event alone: in 0.10 an `ipc::Service` event wakes each listener with a
//! unix datagram of its own, so the publisher pays one `sendto` per sleeping subscriber per
//! cycle (about 1.5 µs each on the development VM, 25 µs with 16), every subscriber a
//! `recvfrom` to consume it, and the sixteenth subscriber is woken after fifteen sends. The
//! lower layer's other event concepts (`iceoryx2_cal::event::SemaphoreShmCountingBitSet`, a
//! process-shared semaphore per listener) would need a service type of our own (possible: the
//! trait is public, not sealed) that every process must use, the pure-Python client, the C and
//! C++ consumers and the `iox2` tools included, which all speak `ipc::Service`; they still post
//! once per listener, and their listeners have no file descriptor, so a WaitSet cannot watch
//! them. benches/README.md, "Latency by wait strategy", has the measurement.
//!
//! The iceoryx2 events are still notified every cycle (other consumers wait on them), and every
//! event and predictive [`crate::Subscription`] still holds a listener (so it counts as one, is
//! reaped as one, and an application can watch it in a WaitSet of its own); it just does not
//! sleep on it, and never drains it. iceoryx2 sends a listener no datagram while its last one is
//! unconsumed, so such a listener costs the publisher a few atomic operations per cycle.
//!
//! The word lives in `<root><prefix><event name, escaped>.wake` (64 bytes, mode 0600), beside
//! iceoryx2's discovery files and event sockets: the root of the project's default domain is
//! this account's alone ([`crate::access::ensure_private_root`]), and a file found there that
//! is not this account's, or that others may write, or a symbolic link, is refused. Whoever
//! comes first (publisher or subscriber) creates it; it is never removed (as iceoryx2's
//! `global_mgmt`), so a restarted publisher wakes the subscribers that are still waiting.
//!
//! Per cycle: [`WakeWord::bump`] is one atomic add, one atomic load and, only while someone
//! sleeps, one `FUTEX_WAKE` for all, or one per sleeper up to [`WAKE_ONE_BY_ONE_MAX`] of them;
//! [`WakeWord::wait`] one `FUTEX_WAIT_BITSET` with an absolute CLOCK_MONOTONIC deadline (so the
//! predictive wait needs no timer descriptor). No allocation.

use std::ffi::CString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

use iceoryx2::config::Config;

/// Up to this many sleepers the publisher wakes one at a time, one `FUTEX_WAKE` of 1 each; more
/// all at once. Woken all at once, four or eight subscribers on two cores queue behind each
/// other for the CPUs (event path p50 31-37 µs at 4, 39-44 µs at 8, on the development VM); one
/// at a time, the first runs while the next is woken (21-24 µs, 31-32 µs). At 16 the sixteen
/// system calls cost more than the queue (54 µs all at once, 60-63 µs one at a time).
/// benches/README.md, "Latency by wait strategy".
pub const WAKE_ONE_BY_ONE_MAX: u32 = 8;
/// Size of the file (one cache line; the two words at its start).
const FILE_SIZE: usize = 64;
/// Suffix of the files.
pub const WAKE_SUFFIX: &str = ".wake";

/// The two words at the start of the file.
#[repr(C)]
struct Shared {
    /// Bumped once per cycle after the event's messages are sent: the futex word.
    seq: AtomicU32,
    /// Threads about to sleep on, or sleeping on, `seq`: the publisher calls `FUTEX_WAKE` only
    /// while this is not 0. A subscriber killed while asleep leaves it 1 too high, which costs
    /// the publisher one needless (and cheap) system call per cycle until the file is replaced.
    sleepers: AtomicU32,
    /// Process id of the publisher that bumps the word, 0 when none does: a subscription sleeps
    /// on the word only while this is set, else on its iceoryx2 listener (publishers other than
    /// [`crate::ArmPublisher`], e.g. a Python one, notify only the iceoryx2 event).
    publisher: AtomicU32,
}

/// What ended [`WakeWord::wait`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Woken {
    /// The word moved (a cycle was published, or moved before the sleep began).
    Bumped,
    /// The deadline passed.
    TimedOut,
    /// A signal handler ran.
    Interrupted,
}

/// A mapped wake-up word (see the module's documentation).
#[derive(Debug)]
pub struct WakeWord {
    shared: *const Shared,
    path: PathBuf,
    /// Device and inode of the mapped file, to notice it was replaced.
    id: (u64, u64),
    _fd: OwnedFd,
}

// The word is only touched through atomics and futex calls.
// SAFETY: the mapping stays valid for the life of the value and is only accessed atomically.
unsafe impl Send for WakeWord {}
// SAFETY: as above.
unsafe impl Sync for WakeWord {}

impl Drop for WakeWord {
    fn drop(&mut self) {
        // SAFETY: `shared` is the start of a FILE_SIZE mapping made in `open`, unmapped once.
        unsafe { libc::munmap(self.shared as *mut libc::c_void, FILE_SIZE) };
    }
}

/// The file of the event `event_name` in the domain `config`.
pub fn wake_path(config: &Config, event_name: &str) -> PathBuf {
    let mut name = config.global.prefix.to_string();
    for b in event_name.bytes() {
        if b.is_ascii_alphanumeric() || b == b'-' || b == b'.' {
            name.push(b as char);
        } else {
            // '/' (and anything else) as `_xx`, '_' itself included: one name per event.
            name.push_str(&format!("_{b:02x}"));
        }
    }
    name.push_str(WAKE_SUFFIX);
    PathBuf::from(config.global.root_path().to_string()).join(name)
}

/// [`WakeWord::open`] for the event service `name`, with the path in the error.
pub(crate) fn open_event_word(
    config: &Config,
    name: &iceoryx2::service::service_name::ServiceName,
) -> Result<WakeWord, crate::IpcError> {
    WakeWord::open(config, name.as_str()).map_err(|source| crate::IpcError::Wake {
        path: wake_path(config, name.as_str()),
        source,
    })
}

fn futex(
    word: *const AtomicU32,
    op: libc::c_int,
    val: u32,
    ts: *const libc::timespec,
    bitset: u32,
) -> libc::c_long {
    // SAFETY: `word` points into a live shared mapping; the other arguments are as the futex
    // operation expects (uaddr2 unused).
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word,
            op,
            val,
            ts,
            std::ptr::null::<u32>(),
            bitset,
        )
    }
}

impl WakeWord {
    /// Opens the wake-up word of the event `event_name` in the domain `config`, creating it
    /// (0600) if missing. Refuses a symbolic link, a file of another account and a file that
    /// others may write ([`io::ErrorKind::PermissionDenied`], with the reason).
    pub fn open(config: &Config, event_name: &str) -> io::Result<Self> {
        Self::open_path(wake_path(config, event_name))
    }

    /// The file at this word's path, opened again (after [`WakeWord::replaced`]).
    pub fn reopen(&self) -> io::Result<Self> {
        Self::open_path(self.path.clone())
    }

    fn open_path(path: PathBuf) -> io::Result<Self> {
        let fd = open_private(&path)?;
        // SAFETY: a fresh shared mapping of a file of at least FILE_SIZE bytes; checked below.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                FILE_SIZE,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                fd.as_raw_fd(),
                0,
            )
        };
        if p == libc::MAP_FAILED {
            return Err(io::Error::last_os_error());
        }
        let id = file_id(&fd)?;
        Ok(Self {
            shared: p as *const Shared,
            path,
            id,
            _fd: fd,
        })
    }

    fn shared(&self) -> &Shared {
        // SAFETY: mapped for the life of `self`, page-aligned, zero-initialised or written only
        // through these atomics.
        unsafe { &*self.shared }
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The current value; a [`WakeWord::wait`] with it returns at the next bump.
    #[inline]
    pub fn load(&self) -> u32 {
        self.shared().seq.load(Ordering::SeqCst)
    }

    /// Publisher: the event's messages are sent; wake everyone sleeping on the word.
    #[inline]
    pub fn bump(&self) {
        let s = self.shared();
        s.seq.fetch_add(1, Ordering::SeqCst);
        // A sleeper registers before it compares the word in the kernel: either it sees the new
        // value there, or this sees it registered (both sides sequentially consistent).
        let sleepers = s.sleepers.load(Ordering::SeqCst);
        if sleepers == 0 {
            return;
        }
        if sleepers <= WAKE_ONE_BY_ONE_MAX {
            // One at a time: the first woken is running before the next is woken. A wake that
            // finds no one left ends it (a counted sleeper not yet in the kernel compares the
            // word there and returns at once).
            for _ in 0..sleepers {
                if futex(&s.seq, libc::FUTEX_WAKE, 1, std::ptr::null(), 0) <= 0 {
                    break;
                }
            }
        } else {
            futex(
                &s.seq,
                libc::FUTEX_WAKE,
                i32::MAX as u32,
                std::ptr::null(),
                0,
            );
        }
    }

    /// Sleeps until the word differs from `seen`, CLOCK_MONOTONIC reaches `until_ns`, or a
    /// signal handler runs. Returns at once when the word already differs.
    pub fn wait(&self, seen: u32, until_ns: u64) -> Result<Woken, i32> {
        let s = self.shared();
        let ts = libc::timespec {
            tv_sec: (until_ns / 1_000_000_000) as libc::time_t,
            tv_nsec: (until_ns % 1_000_000_000) as libc::c_long,
        };
        s.sleepers.fetch_add(1, Ordering::SeqCst);
        // FUTEX_WAIT_BITSET takes an absolute CLOCK_MONOTONIC time (FUTEX_WAIT a relative one).
        let rc = futex(
            &s.seq,
            libc::FUTEX_WAIT_BITSET,
            seen,
            &ts,
            libc::FUTEX_BITSET_MATCH_ANY as u32,
        );
        let errno = if rc < 0 {
            io::Error::last_os_error().raw_os_error().unwrap_or(0)
        } else {
            0
        };
        s.sleepers.fetch_sub(1, Ordering::SeqCst);
        match errno {
            0 | libc::EAGAIN => Ok(Woken::Bumped),
            libc::ETIMEDOUT => Ok(Woken::TimedOut),
            libc::EINTR => Ok(Woken::Interrupted),
            e => Err(e),
        }
    }

    /// Publisher: this process bumps the word from now on (until [`WakeWord::unclaim`]).
    pub fn claim(&self) {
        self.shared()
            .publisher
            .store(std::process::id(), Ordering::SeqCst);
    }

    /// Publisher: this process stops bumping the word.
    pub fn unclaim(&self) {
        let me = std::process::id();
        let _ = self
            .shared()
            .publisher
            .compare_exchange(me, 0, Ordering::SeqCst, Ordering::SeqCst);
    }

    /// Whether a publisher bumps the word (one atomic load).
    #[inline]
    pub fn has_publisher(&self) -> bool {
        self.shared().publisher.load(Ordering::SeqCst) != 0
    }

    /// Clears the publisher's claim when its process no longer exists (it died without
    /// [`WakeWord::unclaim`]). Setup path: one `kill(pid, 0)`.
    pub fn forget_dead_publisher(&self) {
        let pid = self.shared().publisher.load(Ordering::SeqCst);
        if pid == 0 {
            return;
        }
        // SAFETY: signal 0 only checks that the process exists.
        let gone = unsafe { libc::kill(pid as libc::pid_t, 0) } != 0
            && io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
        if gone {
            let _ = self.shared().publisher.compare_exchange(
                pid,
                0,
                Ordering::SeqCst,
                Ordering::SeqCst,
            );
        }
    }

    /// Whether the file at [`WakeWord::path`] is no longer the one mapped (removed, or removed
    /// and created again, e.g. by a cleanup of the root directory). Setup path: one `stat`.
    pub fn replaced(&self) -> bool {
        match std::fs::symlink_metadata(&self.path) {
            Ok(m) => {
                use std::os::unix::fs::MetadataExt;
                (m.dev(), m.ino()) != self.id
            }
            Err(_) => true,
        }
    }
}

fn file_id(fd: &OwnedFd) -> io::Result<(u64, u64)> {
    // SAFETY: fstat fills the zeroed struct for a valid descriptor.
    let st = unsafe {
        let mut st: libc::stat = std::mem::zeroed();
        if libc::fstat(fd.as_raw_fd(), &mut st) != 0 {
            return Err(io::Error::last_os_error());
        }
        st
    };
    Ok((st.st_dev, st.st_ino))
}

/// Opens (creating 0600 if missing) a regular file of this account's that nobody else may
/// write, without following a symbolic link, and makes it FILE_SIZE bytes long.
fn open_private(path: &Path) -> io::Result<OwnedFd> {
    let c = CString::new(path.as_os_str().as_bytes())
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "NUL in the path"))?;
    // SAFETY: valid NUL-terminated path; the descriptor is checked and then owned.
    let raw = unsafe {
        libc::open(
            c.as_ptr(),
            libc::O_RDWR | libc::O_CREAT | libc::O_NOFOLLOW | libc::O_CLOEXEC,
            0o600 as libc::c_uint,
        )
    };
    if raw < 0 {
        let e = io::Error::last_os_error();
        if e.raw_os_error() == Some(libc::ELOOP) {
            return Err(io::Error::new(
                io::ErrorKind::PermissionDenied,
                format!("{} is a symbolic link", path.display()),
            ));
        }
        return Err(e);
    }
    // SAFETY: fresh descriptor owned by nobody else.
    let fd = unsafe { OwnedFd::from_raw_fd(raw) };
    // SAFETY: fstat fills the zeroed struct for a valid descriptor.
    let st = unsafe {
        let mut st: libc::stat = std::mem::zeroed();
        if libc::fstat(fd.as_raw_fd(), &mut st) != 0 {
            return Err(io::Error::last_os_error());
        }
        st
    };
    let me = crate::services::euid();
    let refuse = |why: &str| {
        Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            format!(
                "{} {why} (owner uid {}, mode {:04o}; this process runs as uid {me}): remove \
                 it when no dvrk-sidecar and no consumer runs",
                path.display(),
                st.st_uid,
                st.st_mode & 0o7777
            ),
        ))
    };
    if st.st_mode & libc::S_IFMT != libc::S_IFREG {
        return refuse("is not a regular file");
    }
    if st.st_uid != me {
        return refuse("belongs to another account");
    }
    if st.st_mode & 0o022 != 0 {
        return refuse("is writable by group or others");
    }
    if (st.st_size as usize) < FILE_SIZE {
        // SAFETY: valid descriptor; growing a file zero-fills it (idempotent between racers).
        if unsafe { libc::ftruncate(fd.as_raw_fd(), FILE_SIZE as libc::off_t) } != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    Ok(fd)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    fn config(case: &str) -> Config {
        let prefix = format!("w{}{case}_", std::process::id());
        crate::domain_config(&prefix, Some("/tmp/iox2t/")).unwrap()
    }

    fn setup(case: &str) -> (Config, PathBuf) {
        std::fs::create_dir_all("/tmp/iox2t/").unwrap();
        let cfg = config(case);
        let path = wake_path(&cfg, "arm/cycle_first");
        let _ = std::fs::remove_file(&path);
        (cfg, path)
    }

    #[test]
    fn the_file_name_escapes_the_service_name() {
        let cfg = crate::domain_config("p_", Some("/tmp/x/")).unwrap();
        assert_eq!(
            wake_path(&cfg, "PSM1/cycle/first"),
            PathBuf::from("/tmp/x/p_PSM1_2fcycle_2ffirst.wake")
        );
        // '_' is escaped too, so "a_2f" and "a/" stay apart.
        assert_ne!(wake_path(&cfg, "a_2f"), wake_path(&cfg, "a/"));
    }

    #[test]
    fn a_bump_wakes_a_sleeper_in_another_mapping() {
        let (cfg, path) = setup("bump");
        let publisher = WakeWord::open(&cfg, "arm/cycle_first").unwrap();
        let subscriber = WakeWord::open(&cfg, "arm/cycle_first").unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o7777;
        assert_eq!(mode, 0o600);
        let seen = subscriber.load();
        let far = crate::monotonic_ns() + 60_000_000_000;
        std::thread::scope(|s| {
            let t = s.spawn(|| subscriber.wait(seen, far));
            // Bump until the sleeper is back (it may not be asleep yet at the first bump; a
            // later one wakes it, or its compare sees the new value).
            while !t.is_finished() {
                publisher.bump();
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            assert_eq!(t.join().unwrap(), Ok(Woken::Bumped));
        });
        assert_ne!(subscriber.load(), seen);
        // A stale value returns at once; a current one times out at its deadline.
        assert_eq!(subscriber.wait(seen, far), Ok(Woken::Bumped));
        let soon = crate::monotonic_ns() + 2_000_000;
        assert_eq!(
            subscriber.wait(subscriber.load(), soon),
            Ok(Woken::TimedOut)
        );
        assert!(crate::monotonic_ns() >= soon);
        assert_eq!(subscriber.shared().sleepers.load(Ordering::SeqCst), 0);
        assert!(!subscriber.has_publisher());
        publisher.claim();
        assert!(subscriber.has_publisher());
        subscriber.forget_dead_publisher();
        assert!(subscriber.has_publisher(), "this process is alive");
        publisher.unclaim();
        assert!(!subscriber.has_publisher());
        assert!(!subscriber.replaced());
        std::fs::remove_file(&path).unwrap();
        assert!(subscriber.replaced());
    }

    /// Every sleeper wakes from one bump, whether few (woken one at a time) or many (all at
    /// once), and none is left counted as asleep.
    #[test]
    fn one_bump_wakes_every_sleeper_few_or_many() {
        let (cfg, path) = setup("many");
        let publisher = WakeWord::open(&cfg, "arm/cycle_first").unwrap();
        for n in [
            3,
            WAKE_ONE_BY_ONE_MAX as usize,
            WAKE_ONE_BY_ONE_MAX as usize + 3,
        ] {
            let subscribers: Vec<WakeWord> = (0..n)
                .map(|_| WakeWord::open(&cfg, "arm/cycle_first").unwrap())
                .collect();
            let seen = publisher.load();
            // A sleeper the bump missed times out here.
            let far = crate::monotonic_ns() + 5_000_000_000;
            std::thread::scope(|s| {
                let threads: Vec<_> = subscribers
                    .iter()
                    .map(|w| s.spawn(move || w.wait(seen, far)))
                    .collect();
                // All registered (and so asleep or about to compare the word) before the bump.
                while publisher.shared().sleepers.load(Ordering::SeqCst) < n as u32 {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
                std::thread::sleep(std::time::Duration::from_millis(20));
                publisher.bump();
                for t in threads {
                    assert_eq!(t.join().unwrap(), Ok(Woken::Bumped), "{n} sleepers");
                }
            });
            assert_eq!(publisher.shared().sleepers.load(Ordering::SeqCst), 0);
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_file_others_may_write_or_a_link_is_refused() {
        let (cfg, path) = setup("refuse");
        std::fs::write(&path, [0u8; FILE_SIZE]).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o666)).unwrap();
        let e = WakeWord::open(&cfg, "arm/cycle_first").unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
        assert!(e.to_string().contains("writable by group or others"), "{e}");
        std::fs::remove_file(&path).unwrap();
        let target = PathBuf::from(format!("{}.target", path.display()));
        std::fs::write(&target, [0u8; FILE_SIZE]).unwrap();
        std::os::unix::fs::symlink(&target, &path).unwrap();
        let e = WakeWord::open(&cfg, "arm/cycle_first").unwrap_err();
        assert!(e.to_string().contains("symbolic link"), "{e}");
        std::fs::remove_file(&path).unwrap();
        std::fs::remove_file(&target).unwrap();
    }
}
