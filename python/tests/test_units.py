"""Unit tests of the pure parts of dvrk_sidecar (no shared memory): layouts, the JSON shape,
service names, argument checks and the predictor. Run: python3 -m unittest discover python/tests
(tests/python_client.rs runs them against the installed package)."""

import ctypes
import json
import math
import os
import subprocess
import sys
import unittest
import unittest.mock

import numpy

import dvrk_sidecar
from dvrk_sidecar import arm, ipc, msg


class Layouts(unittest.TestCase):
    def test_sizes_and_offsets_follow_the_spec(self):
        self.assertEqual(ctypes.sizeof(msg.HeaderV2), 48)
        self.assertEqual(msg.HeaderV2.sample_realtime_ns.offset, 16)
        self.assertEqual(msg.HeaderV2.flags.offset, 44)
        self.assertEqual(msg.JointStateV2.effort.offset, 144)
        self.assertEqual(msg.JawStateV1.effort.offset, 64)
        self.assertEqual(msg.PoseV2.rotation.offset, 104)
        self.assertEqual(msg.CompensationStatusV4.consecutive_read_failures.offset, 128)
        self.assertEqual(msg.CompensationStatusV4.implausible_total.offset, 168)

    def test_layouts_have_no_holes(self):
        for lay in msg.layouts():
            end = 0
            for f in lay["fields"]:
                self.assertEqual(f["offset"], end, (lay["type_name"], f["name"]))
                end += f["size"]
            self.assertEqual(end, lay["size"], lay["type_name"])

    def test_layout_type_names(self):
        names = [lay["type_name"] for lay in msg.layouts()]
        self.assertEqual(
            names,
            ["dvrk::HeaderV2", "dvrk::JointStateV2", "dvrk::JawStateV1", "dvrk::PoseV2", "dvrk::CompensationStatusV4"],
        )
        pose = msg.layout(msg.PoseV2)
        self.assertEqual(pose["fields"][0]["type"], "dvrk::HeaderV2")
        self.assertEqual(pose["fields"][3]["type"], "[f64; 9]")


def _header(**kw):
    h = msg.HeaderV2(seq=7, sample_t_ns=11, sample_realtime_ns=1_700_000_000_123_456_789, board_timestamp=5, publish_t_ns=13, valid=1)
    for k, v in kw.items():
        setattr(h, k, v)
    return h


class JsonShape(unittest.TestCase):
    def test_joint_state(self):
        m = msg.JointStateV2(header=_header(flags=(1 << 9) | (1 << 7)))
        m.position[2] = 0.1
        m.effort[5] = float("nan")
        j = msg.to_json("PSM1/measured_js", m)
        self.assertEqual(j["topic"], "PSM1/measured_js")
        self.assertEqual(j["name"], list(msg.JOINT_NAMES))
        self.assertEqual(j["position"][2], 0.1)
        self.assertIsNone(j["effort"][5])  # serde_json writes a non-finite f64 as null
        self.assertEqual(j["header"]["flags"], ["CORRECTION_ACTIVE_J1", "SIMULATED"])
        self.assertIs(j["header"]["valid"], True)
        self.assertEqual(j["header"]["sample_realtime_ns"], 1_700_000_000_123_456_789)
        json.dumps(j, allow_nan=False)

    def test_jaw_is_lists_of_one(self):
        m = msg.JawStateV1(header=_header(valid=0), position=0.5, velocity=-1.0, effort=0.25)
        j = msg.to_json("PSM1/jaw/measured_js", m)
        self.assertEqual((j["name"], j["position"], j["velocity"], j["effort"]), (["jaw"], [0.5], [-1.0], [0.25]))
        self.assertIs(j["header"]["valid"], False)

    def test_pose_rotation_is_rows(self):
        m = msg.PoseV2(header=_header())
        for i in range(9):
            m.rotation[i] = float(i)
        j = msg.to_json("PSM1/local/measured_cp", m)
        self.assertEqual(j["rotation"], [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [6.0, 7.0, 8.0]])
        self.assertEqual(set(j), {"topic", "header", "position_m", "orientation_xyzw", "rotation"})

    def test_status_has_its_field_names_without_reserved(self):
        j = msg.to_json("PSM1/compensated/status", msg.CompensationStatusV4(header=_header(), cycles_total=3))
        self.assertNotIn("_reserved", j)
        self.assertEqual(j["cycles_total"], 3)
        # topic and header, every field but the header and _reserved, and `source` spelled out
        self.assertEqual(len(j), 2 + len(msg.CompensationStatusV4._fields_) - 2 + 1)
        self.assertEqual(j["source"]["console_state"], "UNKNOWN")

    def test_reserved_flag_bits_are_skipped_as_in_rust(self):
        self.assertEqual(msg.flag_names((1 << 0) | (1 << 31) | (1 << 13)), ["BOARD_TIMEOUT", "HELD"])

    def test_source_state_is_spelled_out(self):
        v = 2 | (1 << 4) | (1 << 5) | (2 << 8) | ((3 + 1) << 16)
        s = msg.source_state_dict(v)
        self.assertEqual(s["console_state"], "ENABLED")
        self.assertTrue(s["homed"] and s["console_heard"])
        self.assertEqual(s["parameter_set"], 2)
        self.assertEqual(s["instrument"], msg.INSTRUMENTS[1])
        self.assertEqual(msg.source_state_dict(1 << 16)["instrument"], "removed")


class Names(unittest.TestCase):
    def test_split_service_takes_the_longest_topic(self):
        self.assertEqual(msg.split_service("PSM1/measured_cp"), ("PSM1", "measured_cp"))
        self.assertEqual(msg.split_service("PSM1/local/measured_cp"), ("PSM1", "local/measured_cp"))
        self.assertEqual(
            msg.split_service("test/p1/x/compensated/jaw/measured_js"), ("test/p1/x", "compensated/jaw/measured_js")
        )

    def test_split_service_names_what_is_wrong(self):
        with self.assertRaisesRegex(ValueError, '"PSM1/measured_xx" is not a dvrk-sidecar service'):
            msg.split_service("PSM1/measured_xx")
        with self.assertRaises(ValueError):
            msg.split_service("PSM1")

    def test_split_service_reads_ros_names_and_bare_topics(self):
        self.assertEqual(msg.split_service("/PSM2/jaw/measured_js"), ("PSM2", "jaw/measured_js"))
        self.assertEqual(msg.split_service("local/measured_cp"), ("PSM1", "local/measured_cp"))
        self.assertEqual(msg.split_service("measured_js", "PSM3"), ("PSM3", "measured_js"))

    def test_bad_domain_and_prefix_are_named(self):
        with self.assertRaisesRegex(ipc.ConfigError, "domain 'a/b'"):
            ipc.domain_config("a/b")
        with self.assertRaisesRegex(ipc.ConfigError, "root 'tmp'"):
            ipc.domain_config("ok_", "tmp")
        with self.assertRaisesRegex(ipc.ConfigError, "arm name '/PSM1'"):
            ipc.check_prefix("/PSM1")


class Domain(unittest.TestCase):
    """The project's default domain, computed as dvrk_ipc computes it, and its root directory
    checked as dvrk_ipc::access::ensure_private_root checks it (a scratch directory, no shared
    memory)."""

    def setUp(self):
        self.scratch = f"/tmp/dvrk-py-priv-{os.getpid()}-{self._testMethodName[-8:]}"
        self.addCleanup(subprocess.run, ["rm", "-rf", self.scratch], check=False)

    def test_default_domain_is_the_accounts_own(self):
        uid = os.geteuid()
        with unittest.mock.patch.dict(os.environ):
            os.environ.pop(ipc.IPC_ROOT_ENV, None)
            self.assertEqual(ipc.default_root(), f"/tmp/dvrk-sidecar-{uid}/")
            self.assertEqual(ipc.default_domain_prefix(), f"dvrk_{uid}_")
            cfg = ipc.domain_config()
            self.assertEqual(cfg.global_cfg.prefix.to_string(), f"dvrk_{uid}_")
            self.assertEqual(cfg.global_cfg.root_path.to_string(), f"/tmp/dvrk-sidecar-{uid}/")
        with unittest.mock.patch.dict(os.environ, {ipc.IPC_ROOT_ENV: "/run/dvrk-sidecar"}):
            self.assertEqual(ipc.default_root(), "/run/dvrk-sidecar/")
        for bad in ("", "run/x", "/tmp/a-very-long-root-path-that-breaks-unix-socket-names/"):
            with unittest.mock.patch.dict(os.environ, {ipc.IPC_ROOT_ENV: bad}):
                with self.assertRaisesRegex(ipc.ConfigError, ipc.IPC_ROOT_ENV):
                    ipc.default_root()

    def test_a_missing_root_is_created_owner_only(self):
        ipc.ensure_private_root(self.scratch + "/")
        st = os.lstat(self.scratch)
        self.assertEqual(st.st_mode & 0o7777, 0o700)
        self.assertEqual(st.st_uid, os.geteuid())
        ipc.ensure_private_root(self.scratch)  # again: accepted as it is

    def test_a_root_writable_by_others_is_refused(self):
        os.mkdir(self.scratch)
        os.chmod(self.scratch, 0o777)
        with self.assertRaisesRegex(ipc.OpenError, "writable by group or others.*mode 0777.*chmod 700"):
            ipc.ensure_private_root(self.scratch)

    def test_a_symbolic_link_is_refused_not_followed(self):
        os.mkdir(self.scratch)
        link = self.scratch + "/link"
        os.symlink(self.scratch + "/target", link)
        with self.assertRaisesRegex(ipc.OpenError, "is a symbolic link"):
            ipc.ensure_private_root(link + "/")
        self.assertFalse(os.path.exists(self.scratch + "/target"))

    def test_a_root_another_account_owns_is_refused(self):
        if os.geteuid() != 0:
            self.skipTest("needs root to give a directory to uid 65534 (chown)")
        os.mkdir(self.scratch, 0o700)
        os.chown(self.scratch, 65534, 65534)
        owner = ipc._user_name(65534)
        with self.assertRaises(ipc.OpenError) as e:
            ipc.ensure_private_root(self.scratch)
        for needle in (
            f"refusing the dVRK sidecar's shared-memory directory {self.scratch}",
            f"belongs to another account (owner {owner}, mode 0700; this process runs as root)",
            f"sudo -u {owner}",
            ipc.IPC_ROOT_ENV,
        ):
            self.assertIn(needle, str(e.exception))


class OtherAccounts(unittest.TestCase):
    """No publisher found: the other accounts' default roots are named (a scratch parent
    stands in for /tmp)."""

    def setUp(self):
        self.scratch = f"/tmp/dvrk-py-others-{os.getpid()}"
        self.addCleanup(subprocess.run, ["rm", "-rf", self.scratch], check=False)

    def test_the_hint_names_other_accounts_roots_not_ours(self):
        me = os.geteuid()
        for name in (f"dvrk-sidecar-{me}", "dvrk-sidecar-4242", "dvrk-sidecar-17", "dvrk-sidecar-x"):
            os.makedirs(os.path.join(self.scratch, name))
        open(os.path.join(self.scratch, "dvrk-sidecar-99"), "w").close()  # not a directory
        found = ipc.other_accounts_roots(self.scratch)
        self.assertEqual([uid for _, uid, _ in found], [u for u in (17, 4242) if u != me])
        hint = ipc.no_publisher_hint("/tmp/dvrk-sidecar-0/", "dvrk_0_", found)
        for needle in (
            f"{self.scratch}/dvrk-sidecar-4242/",
            "looks in /tmp/dvrk-sidecar-0/ with the prefix dvrk_0_",
            "sudo -u",
            f"{ipc.IPC_ROOT_ENV} cannot point at another account's directory",
        ):
            self.assertIn(needle, hint)
        self.assertEqual(ipc.no_publisher_hint("/r/", "p_", []), "")


class Poses(unittest.TestCase):
    def test_pose_matrix_is_homogeneous(self):
        p = msg.PoseV2()
        rot = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        for i, v in enumerate(rot):
            p.rotation[i] = v
        p.position_m[0], p.position_m[1], p.position_m[2] = 0.1, 0.2, -0.3
        m = arm.pose_matrix(p)
        self.assertEqual(m.shape, (4, 4))
        numpy.testing.assert_array_equal(m[3], [0.0, 0.0, 0.0, 1.0])
        numpy.testing.assert_array_equal(m[:3, 3], [0.1, 0.2, -0.3])
        self.assertEqual(m[0, 1], -1.0)  # row-major


class Predicting(unittest.TestCase):
    def test_learns_period_and_phase(self):
        p = ipc.Predictor(1_000_000)
        t0 = 5_000_000
        for seq in range(40):
            p.observe(seq, t0 + seq * 1_000_000 + (30_000 if seq % 3 else 0))
        self.assertTrue(p.ready())
        self.assertTrue(math.isclose(p.period, 1_000_000, rel_tol=0.02), p.period)
        now = t0 + 39 * 1_000_000 + 100_000
        nxt = p.next_arrival_ns(now)
        # the next cycle (seq 40) at its early phase
        self.assertTrue(abs(nxt - (t0 + 40 * 1_000_000)) < 40_000, nxt - (t0 + 40 * 1_000_000))

    def test_restarts_on_a_new_publisher(self):
        p = ipc.Predictor(1_000_000)
        for seq in range(20):
            p.observe(seq, 1_000_000 * (seq + 1))
        p.observe(0, 50_000_000)
        self.assertFalse(p.ready())

    def test_guard_is_bounded(self):
        p = ipc.Predictor(1_000_000)
        for _ in range(100):
            p.graded(False)
        self.assertLessEqual(p.guard, 250_000)
        for _ in range(1000):
            p.graded(True)
        self.assertGreaterEqual(p.guard, 10_000)


class Arguments(unittest.TestCase):
    def test_bad_arm_arguments_are_named_before_any_iceoryx2_call(self):
        for kw, what in (({"age": float("nan")}, "age nan"), ({"timeout": -1}, "timeout -1"), ({"period_s": 0}, "period_s 0")):
            with self.assertRaisesRegex(ipc.ConfigError, what):
                arm.Arm("PSM1", **kw)
        with self.assertRaisesRegex(ipc.ConfigError, "arm name ''"):
            arm.Arm("")

    def test_unknown_wait_strategy_is_refused_before_any_iceoryx2_call(self):
        with self.assertRaisesRegex(ipc.ConfigError, "wait 'sleepy'"):
            ipc.Waiter(None, "PSM1", "sleepy")


class Backend(unittest.TestCase):
    """Which client an Arm gets: native whenever the module is built, the environment's choice
    otherwise. Each case in a fresh interpreter (BACKEND is decided at import)."""

    def _run(self, env_value, code):
        env = dict(os.environ)
        env.pop("DVRK_SIDECAR_BACKEND", None)
        if env_value is not None:
            env["DVRK_SIDECAR_BACKEND"] = env_value
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
        self.assertEqual(out.returncode, 0, out.stderr)
        return out.stdout.strip()

    def test_native_is_the_default_when_it_is_built(self):
        want = "native" if dvrk_sidecar.NATIVE_IMPORT_ERROR is None else "pure"
        self.assertEqual(self._run(None, "import dvrk_sidecar as d; print(d.BACKEND)"), want)
        self.assertEqual(self._run("", "import dvrk_sidecar as d; print(d.BACKEND)"), want)

    def test_the_environment_chooses(self):
        for choice in ("pure", "native"):
            self.assertEqual(self._run(choice, "import dvrk_sidecar as d; print(d.BACKEND)"), choice)

    def test_an_unknown_choice_is_named_when_an_arm_is_made(self):
        code = (
            "import dvrk_sidecar as d\n"
            "try:\n    d.Arm('PSM1')\nexcept d.ConfigError as e:\n    print(e)\n"
        )
        self.assertEqual(
            self._run("fast", code), "DVRK_SIDECAR_BACKEND='fast': expected 'native' or 'pure' (or unset)"
        )

    def test_an_unknown_backend_argument_is_refused(self):
        with self.assertRaisesRegex(ipc.ConfigError, "backend 'fast'"):
            arm.Arm("PSM1", backend="fast")


if __name__ == "__main__":
    unittest.main()
