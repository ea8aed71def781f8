"""iceoryx2 plumbing: domains, the project's QoS, readers of one topic and the three ways to wait.

Every process opens (or creates) the services with the same QoS as dvrk_ipc::qos in Rust and
DVRK_IPC_QOS_* in C, because whichever process creates a service first fixes its QoS.
"""

import collections
import ctypes
import errno
import math
import os
import pwd
import select
import stat
import time

import iceoryx2 as iox2

from . import msg

# QoS: the same values as dvrk_ipc::qos (Rust) and DVRK_IPC_QOS_* (C).
QOS_MAX_PUBLISHERS = 1
QOS_MAX_SUBSCRIBERS = 32
QOS_SUBSCRIBER_MAX_BUFFER_SIZE = 256
QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES = 2
QOS_HISTORY_SIZE = 1
QOS_ENABLE_SAFE_OVERFLOW = True
QOS_MAX_NODES = QOS_MAX_SUBSCRIBERS + 4
QOS_EVENT_MAX_NOTIFIERS = 1
QOS_EVENT_MAX_LISTENERS = QOS_MAX_SUBSCRIBERS

NOMINAL_PERIOD_NS = 666_667
"""The sidecar's nominal cycle period (1500 Hz)."""

WAIT_STRATEGIES = ("event", "spin", "predictive")

# The same limits as dvrk_ipc::MAX_DOMAIN_PREFIX_LEN / MAX_ROOT_PATH_LEN: the event socket
# `<root><prefix><id>.event` must fit a 108-byte unix socket path.
MAX_DOMAIN_PREFIX_LEN = 24
MAX_ROOT_PATH_LEN = 48

# Longest single sleep, so that Ctrl-C (handled by Python between calls) is never held up.
_MAX_SLEEP_NS = 100_000_000


class DvrkSidecarError(Exception):
    """Base class of this package's errors."""


class ConfigError(DvrkSidecarError, ValueError):
    """A bad argument: names the argument and the value."""


class OpenError(DvrkSidecarError):
    """A service could not be opened or created; the message names it and iceoryx2's reason."""


def _hint(reason: str) -> str:
    if "IncompatibleTypes" in reason:
        return (
            ": the publisher uses another message type or version; run the dvrk-sidecar and the "
            "dvrk_sidecar package of the same release"
        )
    if "Permission" in reason or "InsufficientPermissions" in reason:
        return ": permission denied on the shared memory (is your user in the sidecar's group?)"
    if "DoesNotSupport" in reason or "Exceeds" in reason:
        return ": the service was created with another QoS, or is full"
    return ""


class NoSample(DvrkSidecarError, TimeoutError):
    """No fresh sample arrived in time; the message says whether a publisher is connected."""


IPC_ROOT_ENV = "DVRK_SIDECAR_IPC_ROOT"
"""The environment variable that moves the default root path, as dvrk_ipc::IPC_ROOT_ENV."""


def _check_root(root, what="root"):
    if not isinstance(root, str) or not root.startswith("/") or len(root.encode()) > MAX_ROOT_PATH_LEN:
        raise ConfigError(f"{what} {root!r}: must be an absolute path of at most {MAX_ROOT_PATH_LEN} bytes")
    return root if root.endswith("/") else root + "/"


def default_root() -> str:
    """The root path of the project's default domain, as dvrk_ipc::default_root_path:
    $DVRK_SIDECAR_IPC_ROOT when set, else /tmp/dvrk-sidecar-<euid>/ (one directory per account,
    the same for every process of it, whatever its environment)."""
    env = os.environ.get(IPC_ROOT_ENV)
    if env is None:
        return f"/tmp/dvrk-sidecar-{os.geteuid()}/"
    return _check_root(env, IPC_ROOT_ENV)


def default_domain_prefix() -> str:
    """The file-name prefix of the project's default domain, as
    dvrk_ipc::default_domain_prefix: dvrk_<euid>_."""
    return f"dvrk_{os.geteuid()}_"


def _resolve(domain, root):
    """The (prefix, root path) of a domain: the project's defaults for None."""
    if domain is None:
        domain = default_domain_prefix()
    ok = isinstance(domain, str) and all(c.isascii() and (c.isalnum() or c in "_-.") for c in domain)
    if not domain or len(domain) > MAX_DOMAIN_PREFIX_LEN or not ok:
        raise ConfigError(
            f"domain {domain!r}: must be 1 to {MAX_DOMAIN_PREFIX_LEN} ASCII letters, digits, "
            "'_', '-' or '.'"
        )
    return domain, (default_root() if root is None else _check_root(root))


def domain_config(domain=None, root=None):
    """iceoryx2's built-in defaults (no config file lookup, like dvrk_ipc::create_node) in the
    domain `domain` (the file-name prefix of its shared memory and its own service namespace)
    under the root path `root`. None: the project's defaults (dvrk_<euid>_ under
    /tmp/dvrk-sidecar-<euid>/ or $DVRK_SIDECAR_IPC_ROOT), where `dvrk-sidecar serve`
    publishes."""
    domain, root = _resolve(domain, root)
    cfg = iox2.config.default()
    cfg.global_cfg.prefix = iox2.FileName.new(domain)
    cfg.global_cfg.root_path = iox2.Path.new(root)
    _leave_dead_nodes_to_the_sidecar(cfg)
    return cfg


def _user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return f"uid {uid}"


def other_accounts_roots(parent: str = "/tmp") -> list:
    """The default domain roots of other accounts (`/tmp/dvrk-sidecar-<uid>/` with another uid
    than this process's), sorted by uid, as (path, uid, owner) - as
    dvrk_ipc::access::other_accounts_roots."""
    me = os.geteuid()
    found = []
    try:
        names = os.listdir(parent)
    except OSError:
        return found
    for name in names:
        rest = name[len("dvrk-sidecar-"):] if name.startswith("dvrk-sidecar-") else ""
        if not rest.isdigit() or int(rest) == me:
            continue
        path = os.path.join(parent, name)
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if stat.S_ISDIR(st.st_mode):
            found.append((path + "/", int(rest), _user_name(st.st_uid)))
    return sorted(found, key=lambda r: r[1])


def no_publisher_hint(root: str, prefix: str, others=None) -> str:
    """Why no publisher may be found, when the service may run under another account: the
    other accounts' default roots that exist and what to do; "" when there are none (as
    dvrk_ipc::access::no_publisher_hint)."""
    others = other_accounts_roots() if others is None else others
    if not others:
        return ""
    listed = ", ".join(f"{path} (owner {owner})" for path, _, owner in others)
    me = _user_name(os.geteuid())
    return (
        f"; this process ({me}) looks in {root} with the prefix {prefix}; the dVRK sidecar's "
        f"shared memory of other accounts exists: {listed}. A service running as another "
        f"account is reachable only from that account: run this program as it (e.g. sudo -u "
        f"{others[0][2]} ...). {IPC_ROOT_ENV} cannot point at another account's directory (it "
        f"must be this account's own, and the prefix dvrk_<euid>_ differs as well)"
    )


def ensure_private_root(root: str) -> None:
    """Makes the root directory `root` private to this account or refuses it, as
    dvrk_ipc::access::ensure_private_root (same checks, same words): created 0700 if missing
    (mkdir, then lstat: a symbolic link is never followed); OpenError when it is a symbolic
    link, not a directory, another account's or writable by group or others, or when its parent
    lets another account replace it (writable by a user other than root and this one, without
    the sticky bit of /tmp)."""
    me = os.geteuid()
    path = root.rstrip("/") or "/"
    parent = os.path.dirname(path)

    def refuse(where, problem, st):
        owner, me_name = _user_name(st.st_uid), _user_name(me)
        if problem == "symlink":
            what = "is a symbolic link"
            fix = (
                "iceoryx2 would follow it wherever it points, and whoever made it chooses where. "
                f"Remove it when no program using iceoryx2 runs (sudo rm {where}), or set "
                f"{IPC_ROOT_ENV} to a directory of this account's own"
            )
        elif problem == "not-a-directory":
            what = "is not a directory"
            fix = (
                f"Remove it when no program using iceoryx2 runs (sudo rm {where}), or set "
                f"{IPC_ROOT_ENV} to a directory of this account's own"
            )
        elif problem == "other-owner":
            what = "belongs to another account"
            fix = (
                "The service and its consumers keep their iceoryx2 state where only their account "
                f"can write. If {owner} runs the dVRK sidecar, run this program as {owner} "
                f"(sudo -u {owner} ...); otherwise {owner} created it first and could hide the "
                "service from its consumers: remove it when no program using iceoryx2 runs "
                f"(sudo rm -rf {where}), or set {IPC_ROOT_ENV} to a directory of this account's own"
            )
        elif problem == "writable-by-others":
            what = "is writable by group or others"
            fix = (
                "Another user could replace the service's discovery files and event sockets "
                f"there: chmod 700 {where}"
            )
        else:
            what = (
                f"is the parent of {path}, and another account than root and {me_name} may write "
                "it without the sticky bit, so it could replace that directory"
            )
            fix = f"Set {IPC_ROOT_ENV} to a path in /tmp, /run or a directory of this account's own"
        return OpenError(
            f"refusing the dVRK sidecar's shared-memory directory {where}: it {what} (owner "
            f"{owner}, mode {stat.S_IMODE(st.st_mode):04o}; this process runs as {me_name}). {fix}"
        )

    if parent != path:
        try:
            st = os.stat(parent)
        except OSError:
            st = None
        if st is not None:
            others_may_write = st.st_mode & 0o022 and not st.st_mode & stat.S_ISVTX
            if st.st_uid not in (0, me) or others_may_write:
                raise refuse(parent, "unsafe-parent", st)
    try:
        try:
            os.mkdir(path, 0o700)
        except FileExistsError:
            pass
        st = os.lstat(path)
    except OSError as e:
        raise OpenError(
            f"creating the dVRK sidecar's shared-memory directory {path} failed: "
            f"{os.strerror(e.errno or errno.EIO)} (os error {e.errno}). Set {IPC_ROOT_ENV} to a "
            f"directory this account may create (an absolute path of at most {MAX_ROOT_PATH_LEN} bytes)"
        ) from None
    if stat.S_ISLNK(st.st_mode):
        raise refuse(path, "symlink", st)
    if not stat.S_ISDIR(st.st_mode):
        raise refuse(path, "not-a-directory", st)
    if st.st_uid != me:
        raise refuse(path, "other-owner", st)
    if st.st_mode & 0o022:
        raise refuse(path, "writable-by-others", st)


def _leave_dead_nodes_to_the_sidecar(cfg) -> None:
    """Turns off iceoryx2's automatic removal of dead nodes (on node creation and destruction,
    and on opening a service), as dvrk_sidecar._native does for its nodes.

    iceoryx2 tells a dead node by its monitor lock (fcntl F_GETLK) unless the node carries the
    process id of the asking copy of iceoryx2. This process may hold two copies: the iceoryx2
    package and the native module's. Each one's nodes carry another id, and F_GETLK never
    reports a lock of the asking process, so each copy saw the other's nodes as dead and removed
    their services while they were in use. The sidecar removes the nodes of dead processes every
    few seconds; `Reader.publishers` still reaps a dead publisher of another process."""
    cfg.global_cfg.node.cleanup_dead_nodes_on_creation = False
    cfg.global_cfg.node.cleanup_dead_nodes_on_destruction = False
    cfg.global_cfg.service.cleanup_dead_nodes_on_open = False


def reap_dead_nodes(config) -> int:
    """Removes the resources of the dead nodes of other processes in the domain of `config`;
    returns how many. A node of this process is never dead, whatever its monitor lock says
    (see `_leave_dead_nodes_to_the_sidecar`)."""
    me = os.getpid()
    reaped = 0
    for state in iox2.Node.list(iox2.ServiceType.Ipc, config):
        if isinstance(state, iox2.NodeState.Dead):
            view = state[0]
            if view.id.pid(iox2.ServiceType.Ipc) != me and view.try_remove_stale_resources():
                reaped += 1
    return reaped


def create_node(name, domain=None, root=None):
    """An iceoryx2 node with signal handling left to Python. iceoryx2's own log level is Fatal
    unless IOX2_LOG_LEVEL says otherwise (its failures come back here as exceptions)."""
    iox2.set_log_level_from_env_or(iox2.LogLevel.Fatal)
    config = domain_config(domain, root)
    _, root_path = _resolve(domain, root)
    if root_path == default_root():
        try:
            ensure_private_root(root_path)
        except OpenError as e:
            where = f"domain {domain!r}" if domain else "the default domain"
            raise OpenError(f"creating an iceoryx2 node in {where}: {e}") from None
    try:
        return (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(name))
            .config(config)
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
    except Exception as e:
        where = f"domain {domain!r}" if domain else "the default domain"
        reason = str(e)
        hint = _hint(reason) or (
            ": often a permission problem on the shared memory or on the domain's root path"
            if "InternalError" in reason
            else ""
        )
        raise OpenError(f"creating an iceoryx2 node in {where}: {reason}{hint}") from e


def check_prefix(prefix: str) -> str:
    """The service prefix (the arm's name), checked like dvrk_ipc::ServiceNames::new."""
    if not isinstance(prefix, str) or not prefix or len(prefix) > 200:
        raise ConfigError(f"arm name {prefix!r}: must be 1 to 200 bytes")
    if prefix.startswith("/") or prefix.endswith("/") or "//" in prefix:
        raise ConfigError(f"arm name {prefix!r}: no leading, trailing or double '/'")
    return prefix


def open_topic(node, prefix: str, topic: str):
    """Opens or creates `<prefix>/<topic>` with the project's QoS."""
    if topic not in msg.TOPICS:
        raise ConfigError(f"topic {topic!r}: expected one of {', '.join(msg.TOPICS)}")
    try:
        return _open_topic(node, prefix, topic)
    except Exception as e:
        name = f"{prefix}/{topic}"
        reason = str(e)
        raise OpenError(
            f"opening {name} as {msg.TOPICS[topic].type_name()}: {reason}{_hint(reason)}"
        ) from e


def _open_topic(node, prefix, topic):
    return (
        node.service_builder(iox2.ServiceName.new(f"{prefix}/{topic}"))
        .publish_subscribe(msg.TOPICS[topic])
        .max_publishers(QOS_MAX_PUBLISHERS)
        .max_subscribers(QOS_MAX_SUBSCRIBERS)
        .max_nodes(QOS_MAX_NODES)
        .subscriber_max_buffer_size(QOS_SUBSCRIBER_MAX_BUFFER_SIZE)
        .subscriber_max_borrowed_samples(QOS_SUBSCRIBER_MAX_BORROWED_SAMPLES)
        .history_size(QOS_HISTORY_SIZE)
        .enable_safe_overflow(QOS_ENABLE_SAFE_OVERFLOW)
        .open_or_create()
    )


def open_cycle_event(node, prefix: str, event: str = msg.CYCLE_EVENT):
    """Opens or creates the event `<prefix>/cycle` (or `event`, e.g. `msg.CYCLE_FIRST_EVENT`)
    with the project's QoS."""
    try:
        return (
            node.service_builder(iox2.ServiceName.new(f"{prefix}/{event}"))
            .event()
            .max_notifiers(QOS_EVENT_MAX_NOTIFIERS)
            .max_listeners(QOS_EVENT_MAX_LISTENERS)
            .max_nodes(QOS_MAX_NODES)
            .open_or_create()
        )
    except Exception as e:
        reason = str(e)
        raise OpenError(f"opening the event {prefix}/{event}: {reason}{_hint(reason)}") from e


class Reader:
    """A subscriber of one topic that copies samples out of shared memory at once.

    It buffers `buffer` samples and remembers as many of the last it took: 4 for the Arm (the
    newest, plus the few before it to find one cycle's messages), 256 for `echo`, which prints
    every sample of the last 170 ms."""

    def __init__(self, node, prefix: str, topic: str, buffer: int = 4):
        self.node = node
        self.service_name = f"{prefix}/{topic}"
        self.topic = topic
        self.payload = msg.TOPICS[topic]
        self.service = open_topic(node, prefix, topic)
        self.subscriber = self.service.subscriber_builder().buffer_size(buffer).create()
        self.recent = collections.deque(maxlen=min(buffer, 4))
        """The last samples taken (ctypes copies), oldest first."""

    @property
    def last(self):
        """The newest sample taken so far, or None."""
        return self.recent[-1] if self.recent else None

    def take(self):
        """The oldest buffered sample as a copy, or None; releases its shared-memory slot now."""
        sample = self.subscriber.receive()
        if sample is None:
            return None
        value = self.payload.from_buffer_copy(sample.payload().contents)
        sample.delete()
        self.recent.append(value)
        return value

    def find(self, seq: int):
        """The remembered sample of cycle `seq`, or None."""
        for value in self.recent:
            if value.header.seq == seq:
                return value
        return None

    def take_newest(self):
        """Drains the buffer; returns the newest sample received by this call, or None."""
        newest = None
        while True:
            value = self.take()
            if value is None:
                return newest
            newest = value

    def publishers(self) -> int:
        """Connected publishers, after reaping those whose process died."""
        reap_dead_nodes(self.node.config)
        return self.service.dynamic_config.number_of_publishers

    def no_sample(self, waited_s: float) -> NoSample:
        """The error for a wait that ended without a sample."""
        if self.publishers() == 0:
            g = self.node.config.global_cfg
            why = "no publisher is connected (is `dvrk-sidecar serve` running with this prefix and domain?)"
            why += no_publisher_hint(g.root_path.to_string(), g.prefix.to_string())
        else:
            why = "a publisher is connected but sent nothing"
        return NoSample(f"no sample on {self.service_name} within {waited_s:g} s: {why}")

    def close(self):
        self.subscriber.delete()


def _socket_fds() -> set:
    fds = set()
    for name in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{name}").startswith("socket:"):
                fds.add(int(name))
        except OSError:
            pass
    return fds


def _event_socket_fds(fds) -> set:
    """Those of `fds` that are unix sockets bound to an iceoryx2 event path (`*.event`): a
    listener's. A notifier's sockets (e.g. of a publisher in this process) are not bound."""
    inodes = {}
    for fd in fds:
        try:
            link = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        inodes[link[len("socket:["):-1]] = fd
    found = set()
    try:
        with open("/proc/net/unix") as table:
            for line in table:
                parts = line.split()
                if len(parts) >= 8 and parts[6] in inodes and parts[7].endswith(".event"):
                    found.add(inodes[parts[6]])
    except OSError:
        pass
    return found


def _minimise_timer_slack() -> None:
    """PR_SET_TIMERSLACK = 1 ns for this thread, so a timed sleep is not deferred by 50 us."""
    libc = ctypes.CDLL(None, use_errno=True)
    pr_set_timerslack = 29
    if libc.prctl(pr_set_timerslack, ctypes.c_ulong(1), 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_TIMERSLACK)")


class _SchedAttr(ctypes.Structure):
    """struct sched_attr, its first (48-byte) version."""

    _fields_ = [
        ("size", ctypes.c_uint32),
        ("sched_policy", ctypes.c_uint32),
        ("sched_flags", ctypes.c_uint64),
        ("sched_nice", ctypes.c_int32),
        ("sched_priority", ctypes.c_uint32),
        ("sched_runtime", ctypes.c_uint64),
        ("sched_deadline", ctypes.c_uint64),
        ("sched_period", ctypes.c_uint64),
    ]


# sched_setattr and sched_getattr system call numbers, per machine (on others no slice is asked).
_SCHED_SYSCALLS = {"x86_64": (314, 315), "aarch64": (274, 275)}
SHORT_SLICE_NS = 100_000
"""The time slice an event or predictive waiter's thread asks for (dvrk_ipc::sys)."""


SHORT_SLICE_ENV = "DVRK_SIDECAR_SHORT_SLICE"
"""`0` turns the short time slice off, `1` (or unset) on (dvrk_ipc::SHORT_SLICE_ENV)."""


def short_slice_wanted() -> bool:
    """Whether event and predictive waiters ask for the short slice, from $DVRK_SIDECAR_SHORT_SLICE
    (ConfigError for a value other than 0 or 1, with the same words as dvrk_ipc)."""
    value = os.environ.get(SHORT_SLICE_ENV)
    if value is None or value == "1":
        return True
    if value == "0":
        return False
    raise ConfigError(f'{SHORT_SLICE_ENV}="{value}": expected 0 (no short time slice) or 1 (the default)')


def request_short_slice() -> bool:
    """Asks for a 0.1 ms time slice for this thread, as dvrk_ipc's event and predictive waits
    do: since Linux 6.12 a task woken with a shorter slice than the running one's preempts it,
    so a waiter woken on the service's CPU takes its sample while the service finishes its
    cycle. Only under the normal policy (SCHED_OTHER); the nice value is kept. True when set;
    False for another policy, another machine, or a refusal (it is a hint: the wait works
    without it)."""
    return _set_thread_slice(SHORT_SLICE_NS)


def _set_thread_slice(ns: int) -> bool:
    """sched_setattr of this thread's slice to `ns` (0: the kernel's default), keeping its
    policy and nice value; only under SCHED_OTHER. True when set."""
    calls = _SCHED_SYSCALLS.get(os.uname().machine)
    if calls is None:
        return False
    setattr_nr, getattr_nr = calls
    libc = ctypes.CDLL(None, use_errno=True)
    attr = _SchedAttr()
    size = ctypes.sizeof(_SchedAttr)
    if libc.syscall(getattr_nr, 0, ctypes.byref(attr), size, 0) != 0:
        return False
    if attr.sched_policy != 0:  # SCHED_OTHER
        return False
    attr.size = size
    attr.sched_runtime = ns
    attr.sched_flags &= 0x01  # SCHED_FLAG_RESET_ON_FORK only (no utilisation clamps here)
    return libc.syscall(setattr_nr, 0, ctypes.byref(attr), 0) == 0


class Predictor:
    """The publisher's cycle: a period and a phase learnt from the samples' `publish_t_ns`, and
    two adaptive margins around the predicted arrival (the model of dvrk_ipc's predictive wait:
    period smoothed over consecutive cycles, phase a low quantile of recent arrivals, a guard
    that grows on a late wake-up and shrinks on an on-time one)."""

    LEARN = 16
    WINDOW = 16
    PHASE_QUANTILE = 0.1
    PERIOD_ALPHA = 1.0 / 64.0

    def __init__(self, nominal_period_ns: int = NOMINAL_PERIOD_NS):
        self.nominal = float(nominal_period_ns)
        self.period = self.nominal
        self.recent = collections.deque(maxlen=self.WINDOW)
        self.observed = 0
        # Python wakes up later than Rust: wider starting margins than dvrk_ipc's.
        self.guard = min(100_000.0, self.nominal / 4)
        self.spin_after = min(50_000.0, self.nominal / 4)

    def ready(self) -> bool:
        return self.observed >= self.LEARN

    def observe(self, seq: int, t_ns: int) -> None:
        """Sample `seq` was published at `t_ns` (CLOCK_MONOTONIC)."""
        if self.recent:
            last_seq, last_t = self.recent[-1]
            if seq <= last_seq or t_ns <= last_t:
                if seq == last_seq:
                    return  # the same cycle read through another topic
                self.recent.clear()  # a new publisher, or a clock oddity: learn afresh
                self.observed = 0
                self.period = self.nominal
            else:
                per_cycle = (t_ns - last_t) / (seq - last_seq)
                # A stall restarts the publisher's grid: leave those gaps out.
                if 0.5 * self.period < per_cycle < 1.5 * self.period:
                    alpha = 1.0 / (self.observed + 1) if not self.ready() else self.PERIOD_ALPHA
                    self.period += alpha * (per_cycle - self.period)
        self.recent.append((seq, t_ns))
        self.observed += 1

    def next_arrival_ns(self, now_ns: int) -> int:
        """The predicted publish time of the next cycle not yet due `spin_after` before now."""
        newest_seq = self.recent[-1][0]
        projected = sorted(t + (newest_seq - s) * self.period for s, t in self.recent)
        base = projected[int(self.PHASE_QUANTILE * (len(projected) - 1))]
        k = max(1, math.ceil((now_ns - self.spin_after - base) / self.period))
        return int(base + k * self.period)

    def graded(self, on_time: bool) -> None:
        """The last predictive wake-up came before the sample (True) or after it."""
        cap = self.period / 4
        if on_time:
            self.guard = max(10_000.0, self.guard - 1_000.0)
        else:
            self.guard = min(cap, self.guard + 30_000.0)

    def missed(self) -> None:
        """Polling ended `spin_after` past the prediction without the sample."""
        self.spin_after = min(self.period / 4, self.spin_after + 30_000.0)

    def caught(self) -> None:
        self.spin_after = max(20_000.0, self.spin_after - 1_000.0)


class Waiter:
    """Waits for a sample as the consumer chooses (dvrk_ipc::WaitStrategy):

    - `event`: sleep on the `<prefix>/cycle` event, notified once per cycle after all nine
      messages; costs nothing while waiting;
    - `spin`: poll without sleeping (a whole core; opens no listener, so it costs the publisher
      nothing);
    - `predictive`: learn the publisher's period and phase from `publish_t_ns`, sleep on the
      event's socket until shortly before the next sample is due, then poll; never later than
      the event. Sets this thread's timer slack to 1 ns.

    `event` and `predictive` ask for a 0.1 ms time slice for this thread
    (`request_short_slice`; `short_slice` says whether it was set), as the native client does,
    unless $DVRK_SIDECAR_SHORT_SLICE is 0.
    """

    def __init__(self, node, prefix: str, strategy: str = "event", nominal_period_ns: int = NOMINAL_PERIOD_NS):
        if strategy not in WAIT_STRATEGIES:
            raise ConfigError(f"wait {strategy!r}: expected one of {', '.join(WAIT_STRATEGIES)}")
        self.strategy = strategy
        self.listener = None
        self.fd = None
        self.predictor = None
        self.short_slice = False
        if strategy == "spin":
            return
        want_slice = short_slice_wanted()  # before anything is opened: a bad value leaks nothing
        self.event = open_cycle_event(node, prefix)
        before = _socket_fds()
        self.listener = self.event.listener_builder().create()
        self.short_slice = want_slice and request_short_slice()
        if strategy == "predictive":
            # iceoryx2's Python API does not expose the listener's descriptor; it is the unix
            # socket that creating the listener opened and bound to the event's path.
            new = _event_socket_fds(_socket_fds() - before)
            if len(new) != 1:
                self.listener.delete()
                raise DvrkSidecarError(
                    f"wait 'predictive': cannot find the socket of {prefix}/cycle "
                    f"({len(new)} new event sockets); use wait='event'"
                )
            self.fd = new.pop()
            _minimise_timer_slack()
            self.predictor = Predictor(nominal_period_ns)

    def observe(self, header) -> None:
        if self.predictor is not None and header.publish_t_ns:
            self.predictor.observe(header.seq, header.publish_t_ns)

    def _readable(self, until_ns: int) -> bool:
        """Sleeps until the event's socket is readable (True) or until_ns (False)."""
        timeout = max(0, min(until_ns - time.monotonic_ns(), _MAX_SLEEP_NS)) / 1e9
        try:
            readable, _, _ = select.select([self.fd], [], [], timeout)
        except InterruptedError:
            return False
        return bool(readable)

    def wait_for(self, poll, until_ns: int):
        """Calls `poll()` until it returns a message (returned) or until_ns passes (None).

        `poll` takes what was received since its last call and returns the newest message or
        None; the predictor learns from what it returns."""
        value = self._wait_for(poll, until_ns)
        if value is not None:
            self.observe(value.header)
        return value

    def _wait_for(self, poll, until_ns: int):
        if self.strategy == "spin":
            while True:
                value = poll()
                if value is not None or time.monotonic_ns() >= until_ns:
                    return value
        if self.strategy == "event":
            while True:
                value = poll()
                if value is not None:
                    return value
                now = time.monotonic_ns()
                if now >= until_ns:
                    return None
                # Consumes the notifications too: after it, a pending sample is polled first.
                self.listener.timed_wait(iox2.Duration.from_nanos(min(until_ns - now, _MAX_SLEEP_NS)))
        # predictive
        value = poll()
        if value is not None:
            return value
        self.listener.try_wait()  # old notifications: their samples are polled next
        p = self.predictor
        while True:
            value = poll()
            if value is not None:
                return value
            now = time.monotonic_ns()
            if now >= until_ns:
                return None
            if not p.ready():
                if self._readable(until_ns):
                    self.listener.try_wait()
                continue
            arrival = p.next_arrival_ns(now)
            woke_on_event = self._readable(min(until_ns, arrival - int(p.guard)))
            if woke_on_event:
                self.listener.try_wait()
                value = poll()
                if value is None:
                    # The notification of a cycle whose sample was already taken by polling
                    # (the publisher notifies after its last message): back to sleep until the
                    # next predicted arrival, not into polling for a whole period.
                    continue
                p.graded(False)
                p.caught()
                return value
            started = time.monotonic_ns()
            spin_until = min(until_ns, max(started, arrival + int(p.spin_after)))
            first = True
            while True:
                value = poll()
                if value is not None:
                    late = woke_on_event or first or value.header.publish_t_ns < started
                    p.graded(not late)
                    p.caught()
                    return value
                first = False
                if time.monotonic_ns() >= spin_until:
                    break
            if spin_until < until_ns:
                p.missed()

    def close(self):
        if self.listener is not None:
            self.listener.delete()
            self.listener = None
