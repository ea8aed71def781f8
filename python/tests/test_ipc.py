"""dvrk_sidecar's iceoryx2 side in an isolated domain of its own (real shared memory, removed
afterwards): a service of another type is refused with a readable error, a silent arm raises
NoSample, echo exits 2 on silence, and a publisher's samples reach the Arm."""

import ctypes
import os
import subprocess
import sys
import threading
import time
import unittest

import iceoryx2 as iox2

import dvrk_sidecar
from dvrk_sidecar import Arm, NoSample, OpenError, ipc, msg

ROOT = "/tmp/iox2t/"


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

    def test_a_service_of_another_type_is_refused_by_name(self):
        node = ipc.create_node("other", self.domain, ROOT)
        # The port factory keeps the service alive.
        service = (
            node.service_builder(iox2.ServiceName.new("PSM1/measured_js"))
            .publish_subscribe(ctypes.c_uint64)
            .open_or_create()
        )
        self.addCleanup(lambda: service)
        with self.assertRaises(OpenError) as cm:
            Arm("PSM1", domain=self.domain, root=ROOT)
        text = str(cm.exception)
        self.assertIn("PSM1/measured_js", text)
        self.assertIn("dvrk::JointStateV2", text)
        self.assertIn("IncompatibleTypes", text)

    def test_a_silent_arm_raises_no_sample_for_each_strategy(self):
        for wait in dvrk_sidecar.WAIT_STRATEGIES:
            with Arm("PSM1", wait=wait, domain=self.domain, root=ROOT) as arm:
                with self.assertRaisesRegex(NoSample, "no publisher is connected"):
                    arm.compensated.local.measured_cp(wait=0.05)
                self.assertIsNone(arm.wait_for_cycle(timeout=0.05))
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

    def test_samples_of_a_publisher_reach_the_arm(self):
        stop = threading.Event()
        ready = threading.Event()

        def publish():
            # iceoryx2 ports stay in the thread that made them.
            node = ipc.create_node("pub", self.domain, ROOT)
            pubs = {t: ipc.open_topic(node, "PSM1", t).publisher_builder().create() for t in msg.TOPICS}
            notifier = ipc.open_cycle_event(node, "PSM1").notifier_builder().create()
            ready.set()
            seq = 0
            while not stop.is_set() and seq < 20_000:
                seq += 1
                for topic, t in msg.TOPICS.items():
                    m = t()
                    m.header.seq = seq
                    m.header.sample_t_ns = m.header.publish_t_ns = time.monotonic_ns()
                    m.header.valid = 1
                    if t is msg.PoseV2:
                        m.rotation[0] = m.rotation[4] = m.rotation[8] = 1.0
                        m.position_m[0] = seq if topic == "compensated/local/measured_cp" else -1.0
                    pubs[topic].send_copy(m)
                notifier.notify()
                time.sleep(0.002)

        thread = threading.Thread(target=publish)
        thread.start()
        self.addCleanup(thread.join)
        self.addCleanup(stop.set)
        self.assertTrue(ready.wait(30))
        for wait in dvrk_sidecar.WAIT_STRATEGIES:
            with Arm("PSM1", domain=self.domain, root=ROOT, wait=wait, timeout=5.0) as arm:
                last = 0
                for _ in range(30):
                    header = arm.wait_for_cycle()
                    self.assertIsNotNone(header, wait)
                    self.assertGreater(header.seq, last, wait)
                    last = header.seq
                    tip, h = arm.compensated.local.measured_cp(extra=True)
                    # The newest pose: this cycle's, or a later one published meanwhile.
                    self.assertGreaterEqual(h.seq, header.seq, wait)
                    self.assertEqual(tip[0, 3], float(h.seq), wait)
                    self.assertEqual(tip.shape, (4, 4))
                # The other getters: numpy arrays of the joints, the status as a dict.
                self.assertEqual(arm.measured_jp().shape, (6,))
                self.assertEqual(arm.compensated.measured_jf().shape, (6,))
                self.assertEqual(arm.jaw.measured_jv().shape, (1,))
                jaw, header = arm.compensated.jaw.measured_jp(extra=True)
                self.assertEqual((jaw.shape, header.valid), ((1,), True))
                status = arm.compensated.status()
                self.assertNotIn("_reserved", status)
                self.assertEqual(status["tau_ext_nm"].shape, (2,))
                base = arm.measured_cp()
                self.assertEqual(base[0, 3], -1.0)  # not the compensated local pose
                # One cycle's nine messages, all of the same seq.
                for _ in range(10):
                    cycle = arm.read_cycle()
                    self.assertIsNotNone(cycle, wait)
                    seqs = {
                        cycle.measured_js(extra=True)[-1].seq,
                        cycle.jaw.measured_js(extra=True)[-1].seq,
                        cycle.local.measured_cp(extra=True)[-1].seq,
                        cycle.compensated.measured_js(extra=True)[-1].seq,
                        cycle.compensated.jaw.measured_jp(extra=True)[-1].seq,
                        cycle.compensated.measured_cp(extra=True)[-1].seq,
                        cycle.compensated.status(extra=True)[-1].seq,
                    }
                    self.assertEqual(seqs, {cycle.seq}, wait)
                    self.assertEqual(cycle.compensated.local.measured_cp()[0, 3], float(cycle.seq))


if __name__ == "__main__":
    unittest.main()
