"""A publisher written in Python (the iceoryx2 package and this package's ctypes messages), in
a process of its own as the sidecar is: the nine topics of an arm in the sidecar's order, the
`cycle/first` event after the first message and the `cycle` event after the last, every 2 ms.

    python3 py_publisher.py ARM DOMAIN ROOT

Prints "ready" once its ports exist, then publishes cycles seq 1, 2, ... until SIGTERM (then
it removes its ports and exits 0) or 60 s. Every message has `valid` set; every pose is the
identity rotation at x = seq for `compensated/local/measured_cp` and x = -1 for the others.
"""

import signal
import sys
import time

from dvrk_sidecar import ipc, msg


def main():
    arm, domain, root = sys.argv[1:4]
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    node = ipc.create_node("py-publisher", domain, root)
    pubs = {t: ipc.open_topic(node, arm, t).publisher_builder().create() for t in msg.PUBLISH_ORDER}
    first = ipc.open_cycle_event(node, arm, msg.CYCLE_FIRST_EVENT).notifier_builder().create()
    last = ipc.open_cycle_event(node, arm).notifier_builder().create()
    print("ready", flush=True)
    seq = 0
    end = time.monotonic() + 60
    while not stop and time.monotonic() < end:
        seq += 1
        for i, topic in enumerate(msg.PUBLISH_ORDER):
            t = msg.TOPICS[topic]
            m = t()
            m.header.seq = seq
            m.header.sample_t_ns = m.header.publish_t_ns = time.monotonic_ns()
            m.header.sample_realtime_ns = time.time_ns()
            m.header.valid = 1
            if t is msg.PoseV2:
                m.rotation[0] = m.rotation[4] = m.rotation[8] = 1.0
                m.position_m[0] = seq if topic == "compensated/local/measured_cp" else -1.0
            pubs[topic].send_copy(m)
            if i == 0:
                first.notify()
        last.notify()
        time.sleep(0.002)
    for p in pubs.values():
        p.delete()
    first.delete()
    last.delete()
    return 0


if __name__ == "__main__":
    sys.exit(main())
