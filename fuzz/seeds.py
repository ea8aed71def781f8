#!/usr/bin/env python3
"""Writes the seed corpus (corpus/<target>/) from the repository's real files, excerpts of the
2017 calibration data in data/2017, and the example bytes of the
board-protocol reference (section 9). Run from anywhere: python3 fuzz/seeds.py. Idempotent."""
import os, re, struct, pathlib

FUZZ = pathlib.Path(__file__).resolve().parent
REPO = FUZZ.parent
CORPUS = FUZZ / "corpus"
DATA = REPO / "data" / "2017"

def put(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    (d / name).write_bytes(data)

# --- replies, from the recorded exclusive-mode cycles (tests/data/io/*.frames) -------------
frames = (REPO / "tests/data/io/psm1-qla-rev8-exclusive.frames").read_text()
replies = [bytes.fromhex(l[2:].strip()) for l in frames.splitlines() if l.startswith("< ")]
seen = set()
for i, r in enumerate(replies):
    if r in seen:
        continue
    seen.add(r)
    put("eth_reply", f"recorded-{i:02}", r)
# The 8-byte "packet dropped" reply (reference 3.1: extra data only, flag 0x02).
put("eth_reply", "dropped", bytes([0x02, 0, 0, 0, 0, 0, 0, 0]))
# Reference section 9 request headers, as the FireWire part of a datagram (a request where a
# response is expected) followed by 8 bytes of extra data.
put("eth_reply", "ref9-quadlet-write", bytes.fromhex("ffff0400ffd000000000000b0100007f11c036d8") + bytes(8))
put("eth_reply", "ref9-quadlet-read", bytes.fromhex("ffff0840ffd000000000000458ffb182") + bytes(8))

# --- requests to the emulator: length-prefixed datagrams (the recorded cycles' requests, and
# the reference section 9 discovery datagrams) -------------------------------------------------
requests = [bytes.fromhex(l[2:].strip()) for l in frames.splitlines() if l.startswith("> ")]
ref9 = [bytes.fromhex("0100" "ffff0400" "ffd00000" "0000000b" "0100007f" "11c036d8"),
        bytes.fromhex("0100" "ffff0840" "ffd00000" "00000004" "58ffb182")]
def seq(ds):
    return b"".join(bytes([len(d)]) + d for d in ds)
put("emulator_request", "recorded-cycles", seq(requests))
put("emulator_request", "reference-9-discovery", seq(ref9))
for i, r in enumerate(requests[:3]):
    put("emulator_request", f"recorded-{i}", seq([r]))

# --- feedback blocks: the recorded Rev 8 QLA blocks, and synthetic ones per layout ----------
# Block responses: 20-byte header, payload (data_length in q3 >> 16), 4-byte data CRC, 8 extra.
blocks = []
for r in replies:
    tcode = (r[3] >> 4) & 0xF
    if tcode == 7:
        n = struct.unpack(">I", r[12:16])[0] >> 16
        blocks.append(r[20:20 + n])
LAYOUTS = [(7, "qla"), (8, "qla"), (8, "dqla"), (8, "drac"), (9, "qla"), (9, "dqla"), (9, "drac")]
MOTORS = {"qla": 4, "dqla": 8, "drac": 10}
ENCODERS = {"qla": 4, "dqla": 8, "drac": 7}
def synth(fw, kind, board=6, moving=False):
    m, e = MOTORS[kind], ENCODERS[kind]
    q = [0x0000bfff, (board << 24) | 0x000f0f00 | (0x80000 if kind != "drac" else 0), 0, 0x2a2b0000]
    q += [0x8000 + 100 * i for i in range(m)]                      # ADC: current bits at mid-scale
    q += [0x800000 + (1000 * i if moving else 0) for i in range(e)]  # encoder counts
    q += [(0x40000000 | 5000) if moving else 0x83ffffff for _ in range(e)]  # period
    q += [0x83ffffff] * e + [0x83ffffff] * e + [0] * e            # qtr1, qtr5, running
    if fw >= 8:
        q += [0x20000000 | 0x8000] * m                              # motor status: amp on
    return b"".join(struct.pack(">I", x) for x in q)
for sel, (fw, kind) in enumerate(LAYOUTS):
    put("feedback_block", f"rev{fw}-{kind}-rest", bytes([sel]) + synth(fw, kind))
    put("feedback_block", f"rev{fw}-{kind}-moving", bytes([sel]) + synth(fw, kind, moving=True))
for i, b in enumerate(blocks[:4]):
    put("feedback_block", f"recorded-rev8-qla-{i}", bytes([1]) + b)

# --- hub memory: boards 6 and 7 (count byte 1 -> 2 boards) after a broadcast query ----------
def hub(sel, bl):
    out = b""
    for seq, b in enumerate(bl):
        nq = len(b) // 4
        out += struct.pack(">I", ((nq + 1) << 24) | ((seq & 0xFF) << 16) | 0x0123) + b
    return bytes([len(bl) - 1, sel]) + out + struct.pack(">I", (0x0010 << 16) | 0x0450)
for sel, (fw, kind) in enumerate(LAYOUTS):
    put("hub_block", f"rev{fw}-{kind}-2boards", hub(sel, [synth(fw, kind, 6), synth(fw, kind, 7, True)]))
if len(blocks) >= 2:
    put("hub_block", "recorded-rev8-qla", hub(1, blocks[:2]))
put("hub_block", "rev8-qla-8boards", hub(1, [synth(8, "qla", b) for b in range(8)]))

# --- configs ---------------------------------------------------------------------------------
for p in sorted((REPO / "tests/data/io").glob("*.json")):
    put("saw_json", p.name, p.read_bytes())
saw = (REPO / "tests/data/io/sawRobotIO1394-PSM1-00000.json").read_text()
put("saw_json", "with-comments.json", "// dVRK style comments\n" + saw.replace("{", "{ /* c */", 1))
put("saw_json", "version-number.json", saw.replace('"6"', "6", 1))
for p in sorted((REPO / "config/io").glob("*.toml")) + sorted((REPO / "tests/data/io/bad").glob("*.toml")):
    put("io_toml", p.name, p.read_bytes())
for p in sorted((REPO / "config/compliance").glob("*.toml")) + sorted((REPO / "tests/data/bad-config").glob("compliance-*.toml")):
    put("compliance_toml", p.name, p.read_bytes())
for p in sorted((REPO / "config/sim").glob("*.toml")):
    put("scenario_toml", p.name, p.read_bytes())
# sidecar.toml: paths rewritten to the scratch directory of the target (io/, compliance/, sim/,
# data/ = tests/data/io, bad/ = tests/data/bad-config).
put("sidecar_toml", "sidecar.toml", (REPO / "config/sidecar.toml").read_bytes())
put("sidecar_toml", "sidecar-saw-json.toml",
    (REPO / "config/sidecar.toml").read_text().replace('"io/psm-classic.toml"', '"data/sawRobotIO1394-PSM1-00000.json"'))
put("sidecar_toml", "sidecar-udp.toml",
    re.sub(r'source = "sim"', 'source = "udp:169.254.0.100"', (REPO / "config/sidecar.toml").read_text()))
for p in sorted((REPO / "tests/data/bad-config").glob("sidecar-*.toml")):
    t = p.read_text().replace("../../../config/", "")
    t = re.sub(r'= "(compliance-[a-z-]+\.toml)"', r'= "bad/\1"', t)
    put("sidecar_toml", p.name, t)

# --- calibration CSVs: excerpts of the real 2017 files, and the project layout ---------------
def excerpt(path, depths, every):
    """The header and every `every`-th step of the given depths, in recorded order."""
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for l in lines[1:]:
        cols = l.split(",")
        if int(cols[1]) in depths and int(cols[0]) % every == 0:
            out.append(l)
    return "\n".join(out) + "\n"
clamp = DATA / "dvrk2017-clamp-joint1.csv"
sweep = DATA / "dvrk2017-torque-offset-joint1.csv"
# 4 depths (a cubic 1/K(L) needs 4) and every 8th step: enough for `fit` to succeed (4.3 KB).
clamp4 = excerpt(clamp, {0, 4, 9, 13}, 8)
# selector byte: bits 0-1 joint (0 none, 1, 2, 3), bit 2 also the sweep, bit 3 continuous.
put("calib_csv", "dvrk2017-clamp-j1", b"\x01" + clamp4.encode())
put("calib_csv", "dvrk2017-clamp-j1-as-sweep-continuous", b"\x0d" + clamp4.encode())
put("calib_csv", "dvrk2017-clamp-nojoint", b"\x00" + excerpt(clamp, {0}, 12).encode())
put("calib_csv", "dvrk2017-sweep-j1", b"\x05" + excerpt(sweep, {0, 4, 9, 13}, 8).encode())
put("calib_csv", "dvrk2017-sweep-j3", b"\x07" + excerpt(sweep, {2}, 6).encode())
# The same clamp steps in the project layout, as joint 2 (direction 0: from the row order).
proj = ["joint,depth_index,insertion_m,position_rad,effort_nm,torque_offset_nm,direction"]
for l in clamp4.splitlines()[1:]:
    c = l.split(",")
    proj.append(",".join(["2", c[1], c[2], c[3], c[4], c[5], "0"]))
put("calib_csv", "project-j2", b"\x00" + ("\n".join(proj) + "\n").encode())
put("calib_csv", "project-j2-also-sweep", b"\x04" + ("\n".join(proj) + "\n").encode())

# --- divot-push files (evaluate --data) -------------------------------------------------------
DIVOT = "push_index,joint,direction,t_s,position_1_rad,position_2_rad,insertion_m,position_4_rad,position_5_rad,position_6_rad,effort_1_nm,effort_2_nm,effort_3_n"
TRUTH = "true_position_1_rad,true_position_2_rad,true_tip_x_m,true_tip_y_m,true_tip_z_m"
rows, trows = [DIVOT], [DIVOT + "," + TRUTH]
for push in range(4):
    joint, sign = 1 + push // 2, 1 if push % 2 == 0 else -1
    for k in range(5):
        t = push * 2.0 + k * 0.4
        q = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]
        q[joint - 1] = sign * 0.004 * k
        e = [0.0, 0.0, 0.5]
        e[joint - 1] = sign * 0.25 * k
        base = f"{push},{joint},{sign if k else 0},{t}," + ",".join(map(str, q)) + "," + ",".join(map(str, e))
        rows.append(base)
        trows.append(base + f",{q[0] - 0.0005 * k * sign * (joint == 1)},{q[1] - 0.0005 * k * sign * (joint == 2)},0.001,-0.002,-0.108")
put("divot_csv", "divot", "\n".join(rows) + "\n")
put("divot_csv", "divot-truth", "\n".join(trows) + "\n")
