"""dvrk_sidecar's iceoryx2 side in an isolated domain of its own (real shared memory, removed
afterwards), with each client (`backend="native"` when the native module is built, and
`"pure"`): a service of another type is refused with a readable error, a silent arm raises
NoSample, echo exits 2 on silence, a Python publisher's samples reach the Arm, each native
wait hands out an array of its own, the two copies of iceoryx2 in one process leave each
other's nodes alone, and event and predictive waits give their thread the short time slice."""

import ctypes
import os
import subprocess
import sys
import time
import unittest

import iceoryx2 as iox2
import numpy

import dvrk_sidecar
from dvrk_sidecar import Arm, NoSample, OpenError, ipc, msg

ROOT = "/tmp/iox2t/"
HERE = os.path.dirname(os.path.abspath(__file__))

BACKENDS = ("native", "pure") if dvrk_sidecar.NATIVE_IMPORT_ERROR is None else ("pure",)
"""The clients these tests run against: both, unless the native module is not built."""


def _remove_domain(domain):
    for base in ("/dev/shm", ROOT):
        for dirpath, _, files in os.walk(base):
            for f in files:
                if f.startswith(domain):
                    try:
                        os.remove(os.path.join(dirpath, f))
                    except OSError:
                        pass


class IsolatedDomain(unittest.TestCase):
    def setUp(self):
        self.domain = f"py{os.getpid()}_{self._testMethodName[-6:]}_"
        self.addCleanup(_remove_domain, self.domain)

    def test_ci_tests_both_clients(self):
        # .ci/python-deps builds the native module: under CI these tests must not quietly run
        # on the pure client alone.
        if os.environ.get("CI"):
            self.assertEqual(BACKENDS, ("native", "pure"), dvrk_sidecar.NATIVE_IMPORT_ERROR)
        self.assertIn("pure", BACKENDS)

    def test_a_service_of_another_type_is_refused_by_name(self):
        node = ipc.create_node("other", self.domain, ROOT)
        # The port factory keeps the service alive.
        service = (
            node.service_builder(iox2.ServiceName.new("PSM1/measured_js"))
            .publish_subscribe(ctypes.c_uint64)
            .open_or_create()
        )
        self.addCleanup(lambda: service)
        for backend in BACKENDS:
            with self.subTest(backend=backend):
                with self.assertRaises(OpenError) as cm:
                    Arm("PSM1", domain=self.domain, root=ROOT, backend=backend)
                text = str(cm.exception)
                self.assertIn("opening PSM1/measured_js as dvrk::JointStateV2: ", text)
                self.assertIn("IncompatibleTypes", text)
                self.assertIn("another message type or version", text)  # the hint

    def test_a_silent_arm_raises_no_sample_for_each_strategy(self):
        for backend in BACKENDS:
            for wait in dvrk_sidecar.WAIT_STRATEGIES:
                with self.subTest(backend=backend, wait=wait):
                    with Arm("PSM1", wait=wait, domain=self.domain, root=ROOT, backend=backend) as arm:
                        self.assertEqual(arm.backend, backend)
                        with self.assertRaisesRegex(NoSample, "no publisher is connected"):
                            arm.compensated.local.measured_cp(wait=0.05)
                        self.assertIsNone(arm.wait_for_cycle(timeout=0.05))
                        # dVRK 2.4 convention: no exception, zeros and a zero timestamp.
                        p, v, e, t = arm.measured_js(wait=0.05, stamped=True)
                        self.assertEqual((t, p.shape, float(abs(p).sum())), (0.0, (6,), 0.0))
                    with self.assertRaisesRegex(dvrk_sidecar.DvrkSidecarError, "closed"):
                        arm.measured_js()

    def test_echo_exits_2_on_silence(self):
        started = time.monotonic()
        out = subprocess.run(
            [sys.executable, "-m", "dvrk_sidecar", "echo", "/PSM1/jaw/measured_js", "--domain", self.domain,
             "--root", ROOT, "--timeout-s", "0.3"],
            capture_output=True, text=True, timeout=60,
        )
        self.assertEqual(out.returncode, 2, out.stderr)
        self.assertIn("no sample on PSM1/jaw/measured_js", out.stderr)
        self.assertLess(time.monotonic() - started, 30)

    def _publisher(self):
        """py_publisher.py in a process of its own, once its ports exist."""
        proc = subprocess.Popen(
            [sys.executable, os.path.join(HERE, "py_publisher.py"), "PSM1", self.domain, ROOT],
            stdout=subprocess.PIPE, text=True,
        )

        def stop():
            proc.terminate()
            self.assertEqual(proc.wait(timeout=60), 0)  # SIGTERM: ports removed, exit 0
            proc.stdout.close()

        self.addCleanup(stop)
        self.assertEqual(proc.stdout.readline().strip(), "ready")
        return proc

    def test_samples_of_a_python_publisher_reach_the_arm(self):
        self._publisher()
        for backend in BACKENDS:
            for wait in dvrk_sidecar.WAIT_STRATEGIES:
                with self.subTest(backend=backend, wait=wait):
                    self._read_cycles(backend, wait)

    def _read_cycles(self, backend, wait):
        with Arm("PSM1", domain=self.domain, root=ROOT, wait=wait, timeout=5.0, backend=backend) as arm:
            last = 0
            for _ in range(30):
                header = arm.wait_for_cycle()
                self.assertIsNotNone(header)
                self.assertGreater(header.seq, last)
                last = header.seq
                tip, h = arm.compensated.local.measured_cp(extra=True)
                # The newest pose: this cycle's, or a later one published meanwhile.
                self.assertGreaterEqual(h.seq, header.seq)
                self.assertEqual(tip[0, 3], float(h.seq))
                self.assertEqual(tip.shape, (4, 4))
            # The other getters: numpy arrays of the joints, the status as a dict.
            self.assertEqual(arm.measured_jp().shape, (6,))
            self.assertEqual(arm.compensated.measured_jf().shape, (6,))
            self.assertEqual(arm.jaw.measured_jv().shape, (1,))
            jaw, header = arm.compensated.jaw.measured_jp(extra=True)
            self.assertEqual((jaw.shape, header.valid), ((1,), True))
            # dVRK 2.4 convention: data and the sample's timestamp (s, ROS time), not zero.
            p, v, e, t = arm.measured_js(stamped=True)
            self.assertEqual(p.shape, (6,))
            self.assertLess(abs(t - time.time()), 60.0)
            status = arm.compensated.status()
            self.assertNotIn("_reserved", status)
            self.assertEqual(status["tau_ext_nm"].shape, (2,))
            base = arm.measured_cp()
            self.assertEqual(base[0, 3], -1.0)  # not the compensated local pose
            # One cycle's nine messages, all of the same seq.
            for _ in range(10):
                cycle = arm.read_cycle()
                self.assertIsNotNone(cycle)
                seqs = {
                    cycle.measured_js(extra=True)[-1].seq,
                    cycle.jaw.measured_js(extra=True)[-1].seq,
                    cycle.local.measured_cp(extra=True)[-1].seq,
                    cycle.compensated.measured_js(extra=True)[-1].seq,
                    cycle.compensated.jaw.measured_jp(extra=True)[-1].seq,
                    cycle.compensated.measured_cp(extra=True)[-1].seq,
                    cycle.compensated.status(extra=True)[-1].seq,
                }
                self.assertEqual(seqs, {cycle.seq})
                self.assertEqual(cycle.compensated.local.measured_cp()[0, 3], float(cycle.seq))

    @unittest.skipIf("native" not in BACKENDS, dvrk_sidecar.NATIVE_IMPORT_ERROR)
    def test_each_native_wait_hands_out_an_array_of_its_own(self):
        # The native wait copies a sample into an array it made before waiting: every sample
        # must still get its own array, which later waits leave as it was, and a wait that
        # timed out keeps its array for the next sample.
        from dvrk_sidecar import _native, native

        topic = "compensated/local/measured_cp"
        node = _native.Node("own", self.domain, ROOT)
        subs = {}
        for wait in dvrk_sidecar.WAIT_STRATEGIES:
            subs[wait] = _native.Subscription(node, "PSM1", topic, native.DTYPES[topic], wait=wait)
            self.addCleanup(subs[wait].close)
            self.assertIsNone(subs[wait].wait(0.05))  # no publisher yet
        self._publisher()
        for wait, sub in subs.items():
            with self.subTest(wait=wait):
                got = []
                while len(got) < 12:
                    a = sub.wait(5.0)
                    self.assertIsNotNone(a, f"no sample within 5 s after {len(got)}")
                    got.append(a)
                seqs = [int(a["header"]["seq"][0]) for a in got]
                self.assertEqual(seqs, sorted(set(seqs)))
                # The publisher writes x = seq into this topic's pose.
                self.assertEqual([float(a["position_m"][0][0]) for a in got], [float(q) for q in seqs])
                for i, a in enumerate(got[1:], 1):
                    self.assertFalse(numpy.shares_memory(a, got[i - 1]))

    @unittest.skipIf("native" not in BACKENDS, dvrk_sidecar.NATIVE_IMPORT_ERROR)
    def test_the_native_predictive_late_share_is_checked(self):
        # 1-50 % of the predicted waits may wake after the sample; anything else is refused,
        # naming the keyword and the value.
        from dvrk_sidecar import _native, native

        topic = "compensated/local/measured_cp"
        node = _native.Node("late", self.domain, ROOT)
        for bad in (0, 51, -1, 300):
            with self.subTest(bad=bad):
                with self.assertRaisesRegex(ValueError, f"predictive_late_percent {bad}: must be within 1..=50"):
                    _native.Subscription(
                        node, "PSM1", topic, native.DTYPES[topic], wait="predictive", predictive_late_percent=bad
                    )
        for good in (1, 10, 50):
            sub = _native.Subscription(
                node, "PSM1", topic, native.DTYPES[topic], wait="predictive", predictive_late_percent=good
            )
            sub.close()

    @unittest.skipIf("native" not in BACKENDS, dvrk_sidecar.NATIVE_IMPORT_ERROR)
    def test_the_two_iceoryx2_copies_in_one_process_leave_each_others_nodes_alone(self):
        # The iceoryx2 package's nodes and the native module's each look dead to the other copy
        # (another process id, a monitor lock held by this very process): neither may remove
        # the other's services when it creates a node, opens a service or drops a node.
        from dvrk_sidecar import _native, native

        node = ipc.create_node("pub", self.domain, ROOT)
        service = ipc.open_topic(node, "PSM1", "compensated/status")
        publisher = service.publisher_builder().create()
        self.addCleanup(publisher.delete)
        Arm("PSM1", domain=self.domain, root=ROOT, backend="native").close()
        self.assertEqual(service.dynamic_config.number_of_publishers, 1)
        native_node = _native.Node("probe", self.domain, ROOT)
        sub = _native.Subscription(
            native_node, "PSM1", "compensated/status", native.DTYPES["compensated/status"], wait="spin"
        )
        self.addCleanup(sub.close)
        # The iceoryx2 package's node creation and opening, after the native module's.
        Arm("PSM1", domain=self.domain, root=ROOT, backend="pure").close()
        self.assertEqual(service.dynamic_config.number_of_subscribers, 1)
        self.assertEqual(sub.publishers(), 1)
        m = msg.CompensationStatusV4()
        m.header.seq = 7
        publisher.send_copy(m)  # connects the subscriber and delivers to it
        a = sub.take()
        self.assertIsNotNone(a)
        self.assertEqual(int(a["header"]["seq"][0]), 7)

    def test_event_and_predictive_waits_give_their_thread_a_short_slice(self):
        # The slice is per thread: each case opens its waiter on a thread of its own and reads
        # the kernel's own account of that thread's slice.
        import threading

        release = tuple(int(x) for x in os.uname().release.split("-")[0].split(".")[:2])
        if release < (6, 12):
            self.skipTest(f"kernel {os.uname().release} has no per-task slice (6.12+)")

        def slice_ns():
            with open("/proc/thread-self/sched") as f:
                line = next(l for l in f if l.strip().startswith("se.slice"))
            value = line.split(":")[1].strip()
            ms, _, frac = value.partition(".")
            return int(ms) * 1_000_000 + int(frac) if frac else int(value)

        topic = "compensated/local/measured_cp"

        def open_native(wait):
            from dvrk_sidecar import _native, native

            node = _native.Node("slice", self.domain, ROOT)
            return _native.Subscription(node, "PSM1", topic, native.DTYPES[topic], wait=wait).close

        def open_pure(wait):
            waiter = ipc.Waiter(ipc.create_node("slice", self.domain, ROOT), "PSM1", wait)
            self.assertEqual(waiter.short_slice, wait != "spin" and ipc.short_slice_wanted())
            return waiter.close

        cases = [(b, w, None) for b in BACKENDS for w in dvrk_sidecar.WAIT_STRATEGIES]
        # $DVRK_SIDECAR_SHORT_SLICE=0 turns it off for both clients.
        cases += [(b, w, "0") for b in BACKENDS for w in ("event", "predictive")]
        for backend, wait, env in cases:
            with self.subTest(backend=backend, wait=wait, env=env):
                seen = {}

                def subscribe():
                    # A thread inherits its creator's slice, and earlier tests opened
                    # waiters on the main thread: back to the kernel's default first.
                    self.assertTrue(ipc._set_thread_slice(0))
                    seen["before"] = slice_ns()
                    close = (open_native if backend == "native" else open_pure)(wait)
                    seen["after"] = slice_ns()
                    close()

                if env is None:
                    os.environ.pop(ipc.SHORT_SLICE_ENV, None)
                else:
                    os.environ[ipc.SHORT_SLICE_ENV] = env
                try:
                    t = threading.Thread(target=subscribe)
                    t.start()
                    t.join()
                finally:
                    os.environ.pop(ipc.SHORT_SLICE_ENV, None)
                if wait == "spin" or env == "0":
                    self.assertEqual(seen["after"], seen["before"])
                else:
                    self.assertNotEqual(seen["before"], 100_000)
                    self.assertEqual(seen["after"], 100_000)

    def test_a_bad_short_slice_setting_is_refused_with_its_name_and_value(self):
        os.environ[ipc.SHORT_SLICE_ENV] = "off"
        try:
            for backend in BACKENDS:
                with self.subTest(backend=backend):
                    with self.assertRaises(dvrk_sidecar.DvrkSidecarError) as cm:
                        Arm("PSM1", wait="event", domain=self.domain, root=ROOT, backend=backend).measured_js(wait=0.01)
                    self.assertIn(
                        'DVRK_SIDECAR_SHORT_SLICE="off": expected 0 (no short time slice) or 1 (the default)',
                        str(cm.exception),
                    )
        finally:
            os.environ.pop(ipc.SHORT_SLICE_ENV, None)

if __name__ == "__main__":
    unittest.main()
