"""Python subscribers of the latency harness (benches/latency/main.rs runs one process each).

    python3 python_sub.py shm native|pure WAIT PREFIX TOPIC SECONDS
    python3 python_sub.py json SECONDS          # prints "PORT n" first

Every mode prints one JSON line at the end, as the Rust subscribers do: {"all": [latency ns of
every sample, from header.sample_t_ns to the moment Python holds it], "publisher": [...],
"lost": sequence gaps after the first sample, "cpu_percent": CPU of this process while it
measured, "on_time": [predicted on time, predictive waits] or null}.

- `shm native`: dvrk_sidecar._native.Subscription (compiled wait, GIL released) - the sample
  is in Python's hands as a numpy array when `wait()` returns.
- `shm pure`: the pure-Python client's Reader and Waiter (what `Arm(backend="pure")` uses).
- `json`: a sawSocketStreamer consumer as a Python lab program writes it today: a UDP socket,
  `json.loads`, the pose out of the dict.
"""

import json
import socket
import struct
import sys
import time

mono = time.monotonic_ns
cpu = time.process_time_ns


class Window:
    """CPU use from the first sample to the end."""

    def __init__(self):
        self.t0 = None
        self.c0 = None

    def mark(self, now):
        if self.t0 is None:
            self.t0, self.c0 = now, cpu()

    def elapsed_s(self, now):
        return 0.0 if self.t0 is None else (now - self.t0) * 1e-9

    def percent(self, now):
        if self.t0 is None or now <= self.t0:
            return 0.0
        return 100.0 * (cpu() - self.c0) / (now - self.t0)


def report(lat, publisher, lost, window, on_time=None, cpu_percent=None):
    """`cpu_percent`: as measured when the loop ended (the window up to now if not given)."""
    if cpu_percent is None:
        cpu_percent = window.percent(mono())
    print(json.dumps({"all": lat, "publisher": publisher, "lost": lost,
                      "cpu_percent": cpu_percent, "on_time": on_time}), flush=True)


def header_stamps(dtype):
    """A struct reading (sample_t_ns, publish_t_ns) out of one sample of `dtype`, at the
    offsets the dtype gives."""
    header, base = dtype.fields["header"]
    offsets = sorted((header.fields[k][1] + base, k) for k in ("sample_t_ns", "publish_t_ns"))
    if [k for _, k in offsets] != ["sample_t_ns", "publish_t_ns"]:
        raise SystemExit("sample_t_ns is expected before publish_t_ns in the header")
    (a, _), (b, _) = offsets
    return struct.Struct(f"<{a}xQ{b - a - 8}xQ")


def shm_native(wait, prefix, topic, seconds):
    from dvrk_sidecar import _native, native

    node = _native.Node("latency-py-sub")
    dtype = native.DTYPES[topic]
    sub = _native.Subscription(node, prefix, topic, dtype, wait=wait)
    # The loop does the least a consumer can between two waits: the moment the sample is in
    # Python's hands and its two stamps, read in one call (a struct over the array's buffer),
    # kept for after the run. With 16 subscribers on 2 cores every microsecond a consumer
    # spends between two waits delays the others' hand-off; field indexing (`a["header"]...`)
    # and the latency arithmetic would cost 1.8 against 0.5 µs (warm). Kept as ints, which the
    # garbage collector does not track: a tuple kept per sample made it run every 700 samples,
    # and traverse all of them in its older generations.
    stamps = header_stamps(dtype).unpack_from
    next_sample, window = sub.wait, Window()
    nows, sampled, published = [], [], []
    first_gaps, end = None, None
    while True:
        a = next_sample(0.5)
        now = mono()
        if a is not None:
            t, pub = stamps(a)
            nows.append(now)
            sampled.append(t)
            published.append(pub)
            if end is None:
                window.mark(now)
                end = now + int(seconds * 1e9)
                first_gaps = sub.stats()["seq_gaps_total"]
            elif now > end:
                break
        elif end is not None and sub.terminated:
            break
        elif end is not None and mono() > end:
            break
    cpu_percent = window.percent(mono())
    st = sub.stats()
    lat = [now - t for now, t in zip(nows, sampled)]
    publisher = [pub - t for t, pub in zip(sampled, published)]
    on_time = None
    if wait == "predictive":
        total = (st["predicted_on_time_total"] + st["predicted_late_total"] + st["predicted_missed_total"]
                 + st["predicted_skipped_total"])
        on_time = [st["predicted_on_time_total"], total]
    report(lat, publisher, st["seq_gaps_total"] - (first_gaps or 0), window, on_time, cpu_percent)


def shm_pure(wait, prefix, topic, seconds):
    from dvrk_sidecar import ipc

    node = ipc.create_node("latency-py-pure")
    reader = ipc.Reader(node, prefix, topic, buffer=16)
    waiter = ipc.Waiter(node, prefix, wait)
    lat, publisher, window = [], [], Window()
    state = {"last": None, "lost": 0}

    def poll():
        # Every sample drained counts (as the Rust subscriber's `each`); the newest is returned.
        newest = None
        while True:
            v = reader.take()
            if v is None:
                return newest
            now = mono()
            h = v.header
            if state["last"] is not None and h.seq > state["last"] + 1:
                state["lost"] += h.seq - state["last"] - 1
            state["last"] = h.seq
            window.mark(now)
            lat.append(now - h.sample_t_ns)
            publisher.append(h.publish_t_ns - h.sample_t_ns)
            newest = v

    while window.elapsed_s(mono()) <= seconds:
        v = waiter.wait_for(poll, mono() + 500_000_000)
        if v is None and window.t0 is not None and reader.publishers() == 0:
            break
    report(lat, publisher, state["lost"], window)


def json_udp(seconds):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    print(f"PORT {sock.getsockname()[1]}", flush=True)
    sock.settimeout(0.2)
    lat, window = [], Window()
    last, lost, idle = None, 0, 0
    while True:
        try:
            data = sock.recv(2048)
        except socket.timeout:
            idle += 1
            if window.t0 is not None and idle > 5:
                break
            continue
        idle = 0
        now = mono()
        window.mark(now)
        v = json.loads(data)
        cp = v["measured_cp"]
        lat.append(now - int(cp["Timestamp"] * 1e9))
        _ = cp["Position"]["Translation"], cp["Position"]["Rotation"]
        seq = v["seq"]
        if last is not None and seq > last + 1:
            lost += seq - last - 1
        last = seq
        if window.elapsed_s(now) > seconds:
            break
    report(lat, [], lost, window)


def main(argv):
    if argv[0] == "shm":
        backend, wait, prefix, topic, seconds = argv[1], argv[2], argv[3], argv[4], float(argv[5])
        (shm_native if backend == "native" else shm_pure)(wait, prefix, topic, seconds)
    elif argv[0] == "json":
        json_udp(float(argv[1]))
    else:
        raise SystemExit(f"unknown mode {argv[0]!r}")


if __name__ == "__main__":
    main(sys.argv[1:])
