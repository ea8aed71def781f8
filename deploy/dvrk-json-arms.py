#!/usr/bin/env python3
"""Reads a lab's dVRK system JSON (dVRK 2.3+, `dvrk_system -j system.json`) or console JSON
(dVRK 2.1-2.2) and the sawRobotIO1394 JSON of each PSM next to it, for deploy/install.sh.

    dvrk-json-arms.py DVRK_JSON [ARM,ARM...]

Prints one fact per line, tab-separated, for install.sh to turn into /etc/dvrk-sidecar/sidecar.toml:
    source <TAB> SOURCE <TAB> where it came from      (SOURCE in the sidecar's spelling: fw:N, udp:IP)
    arm <TAB> NAME <TAB> IO_FILE <TAB> KIND <TAB> BOARDS <TAB> BASE_FRAME <TAB> SERIAL <TAB> HARDWARE
        KIND: classic or si; BOARDS: comma-separated board ids in the IO file's order;
        BASE_FRAME: transform, component:NAME (set at run time by that component, e.g. the SUJ)
        or none
    note <TAB> TEXT
On any error: one line on stderr naming the file, the field and the value, and exit status 1.

Only the Python standard library is used (json, os, re, sys): python3 is on every Ubuntu PC that
runs the dVRK, whose ROS 2 tools need it; the dVRK's JSON may hold // and /* */ comments, which
this strips as the dVRK's own reader accepts them.

The dVRK facts used (sawIntuitiveResearchKit share/schemas, dVRK 2.3):
- system JSON: "IOs": [{"name", "port"}], "arms": [{"name", "type", "serial", "IO",
  "name_on_IO", "simulation", "base_frame": {"reference_frame", "transform"} or
  {"component", "interface"}}]; the arm's IO file is sawRobotIO1394-<name_on_IO or name>-<serial>.json
  next to the system JSON.
- console JSON (2.1-2.2): "io": {"port"} (default: FireWire port 0), "arms": [{"name", "type",
  "serial", "io" (deprecated: the IO file), "base-frame": {"reference-frame", "transform"}}].
- port: fw, fw:X, udp, udp:IP, udpfw, udpfw:IP (udp alone: the boards' default 169.254.0.100).
- arm types that are PSMs on the boards: PSM, PSM_DERIVED (PSM_GENERIC has no IO).
- IO JSON ($version 6): robots[].{name, hardware_version (QLA1, DQLA: Classic; dRA1: Si),
  actuators[].board_id}.
"""

import json
import os
import re
import sys

PSM_TYPES = ("PSM", "PSM_DERIVED")
DEFAULT_UDP = "169.254.0.100"
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
FILE_RE = re.compile(r"^[A-Za-z0-9._-]+\.json$")
KINDS = {"QLA1": "classic", "DQLA": "classic", "dRA1": "si"}


class Refusal(Exception):
    pass


def strip_comments(text):
    """Removes // and /* */ comments outside strings (as the dVRK's JSON reader allows)."""
    out = []
    i, n = 0, len(text)
    in_str = False
    while i < n:
        c = text[i]
        if in_str:
            out.append(c)
            if c == "\\" and i + 1 < n:
                out.append(text[i + 1])
                i += 2
                continue
            if c == '"':
                in_str = False
            i += 1
            continue
        if c == '"':
            in_str = True
            out.append(c)
            i += 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            if j < 0:
                raise Refusal("unterminated /* comment")
            # keep the line count for error messages
            out.append("\n" * text.count("\n", i, j))
            i = j + 2
        else:
            out.append(c)
            i += 1
    return "".join(out)


def load_json(path, what):
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        raise Refusal(f"{what} {path}: {e.strerror}")
    try:
        return json.loads(strip_comments(text))
    except (ValueError, Refusal) as e:
        raise Refusal(f"{what} {path}: not valid JSON: {e}")


def source_from_port(port, where):
    """The sidecar's source for a dVRK port string."""
    if not isinstance(port, str):
        raise Refusal(f"{where}: port {port!r} is not a string")
    m = re.fullmatch(r"fw(?::([0-9]+))?", port)
    if m:
        return f"fw:{m.group(1) or 0}"
    m = re.fullmatch(r"(udp|udpfw)(?::([0-9]{1,3}(?:\.[0-9]{1,3}){3}))?", port)
    if m:
        return f"udp:{m.group(2) or DEFAULT_UDP}"
    raise Refusal(
        f"{where}: port \"{port}\" is not one the dVRK accepts (fw, fw:X, udp, udp:IP, udpfw, udpfw:IP)"
    )


def io_facts(path, robot_name, arm):
    """(kind, boards, hardware) of robot `robot_name` in the sawRobotIO1394 JSON at `path`."""
    io = load_json(path, f"arm {arm}: IO file")
    version = io.get("$version") if isinstance(io, dict) else None
    if str(version) != "6":
        raise Refusal(
            f"arm {arm}: IO file {path}: \"$version\" is {version!r}, the sidecar reads version 6 "
            f"(dVRK 2.2 and later)"
        )
    robots = io.get("robots")
    if not isinstance(robots, list) or not robots:
        raise Refusal(f"arm {arm}: IO file {path}: no \"robots\" list")
    names = [r.get("name") for r in robots if isinstance(r, dict)]
    robot = next((r for r in robots if isinstance(r, dict) and r.get("name") == robot_name), None)
    if robot is None:
        raise Refusal(
            f"arm {arm}: IO file {path}: no robot named \"{robot_name}\" (found: {', '.join(map(str, names))})"
        )
    hardware = robot.get("hardware_version", "QLA1")
    if hardware not in KINDS:
        raise Refusal(
            f"arm {arm}: IO file {path}: hardware_version \"{hardware}\" is not QLA1, DQLA (Classic) or dRA1 (Si)"
        )
    boards = []
    for i, a in enumerate(robot.get("actuators") or []):
        b = a.get("board_id") if isinstance(a, dict) else None
        if not isinstance(b, int) or isinstance(b, bool) or not 0 <= b <= 15:
            raise Refusal(
                f"arm {arm}: IO file {path}: robots \"{robot_name}\" actuator {i + 1}: board_id {b!r} is not 0-15"
            )
        if b not in boards:
            boards.append(b)
    if not boards:
        raise Refusal(f"arm {arm}: IO file {path}: robot \"{robot_name}\" has no actuators")
    return KINDS[hardware], boards, hardware


def main(argv):
    if len(argv) not in (2, 3):
        raise Refusal("usage: dvrk-json-arms.py DVRK_JSON [ARM,ARM...]")
    path = argv[1]
    wanted = [a for a in argv[2].split(",") if a] if len(argv) == 3 else None
    top = load_json(path, "--dvrk-json")
    here = os.path.dirname(os.path.abspath(path))
    if not isinstance(top, dict) or not isinstance(top.get("arms"), list):
        raise Refusal(f"--dvrk-json {path}: no \"arms\" list (is this a dVRK system or console JSON?)")
    system = "IOs" in top
    layout = "system JSON (dVRK 2.3+)" if system else "console JSON (dVRK 2.1-2.2)"
    print(f"note\tread {path} as a {layout}")

    arms = [a for a in top["arms"] if isinstance(a, dict)]
    psms = []
    others = []
    for a in arms:
        name, kind = a.get("name"), a.get("type")
        if kind in PSM_TYPES and "simulation" not in a:
            psms.append(a)
        else:
            why = f"{kind}, simulated" if "simulation" in a else f"{kind}"
            others.append(f"{name} ({why})")
    if not psms:
        raise Refusal(
            f"--dvrk-json {path}: no PSM on the boards in \"arms\" (found: {', '.join(others) or 'none'}); "
            f"the sidecar serves PSMs of type {' or '.join(PSM_TYPES)} that are not simulated"
        )
    if wanted is not None:
        by_name = {a.get("name"): a for a in arms}
        for w in wanted:
            if w not in by_name:
                raise Refusal(
                    f"--arms {','.join(wanted)}: no arm named \"{w}\" in {path} "
                    f"(PSMs there: {', '.join(a['name'] for a in psms)})"
                )
            if by_name[w] not in psms:
                raise Refusal(
                    f"--arms {','.join(wanted)}: {w} in {path} is not a PSM on the boards "
                    f"(type {by_name[w].get('type')}{', simulated' if 'simulation' in by_name[w] else ''})"
                )
        psms = [a for a in psms if a["name"] in wanted]
    for o in others:
        print(f"note\tskipped {o}: not a PSM on the boards")

    ios = {}
    if system:
        for io in top.get("IOs") or []:
            if isinstance(io, dict) and "name" in io:
                ios[io["name"]] = io
    sources = []
    for a in psms:
        name = a["name"]
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise Refusal(f"--dvrk-json {path}: arm name {name!r} is not a name the sidecar publishes under")
        serial = a.get("serial")
        if isinstance(serial, int) and not isinstance(serial, bool):
            serial = str(serial)
        # The port this arm is on.
        if system:
            io_name = a.get("IO")
            if io_name not in ios:
                raise Refusal(
                    f"--dvrk-json {path}: arm {name}: \"IO\": {io_name!r} is not one of the \"IOs\" "
                    f"({', '.join(map(str, ios)) or 'none'})"
                )
            if "port" not in ios[io_name]:
                raise Refusal(f"--dvrk-json {path}: IOs \"{io_name}\" has no \"port\"")
            port = ios[io_name]["port"]
            where = f"IOs \"{io_name}\" port \"{port}\" of {os.path.basename(path)}"
        else:
            io_sec = top.get("io") if isinstance(top.get("io"), dict) else {}
            port = io_sec.get("port", "fw")
            where = (
                f"io port \"{port}\" of {os.path.basename(path)}"
                if "port" in io_sec
                else f"no io port in {os.path.basename(path)}: the dVRK's default, FireWire port 0"
            )
        sources.append((name, source_from_port(port, f"--dvrk-json {path}: arm {name}"), where))
        # The arm's IO file.
        io_arm = a.get("name_on_IO", name)
        explicit = a.get("io") if not system else None
        if isinstance(explicit, str):
            if explicit.endswith(".xml"):
                raise Refusal(
                    f"--dvrk-json {path}: arm {name}: \"io\": \"{explicit}\" is an XML IO file "
                    f"(dVRK 2.1): the sidecar reads the sawRobotIO1394 JSON (version 6) of dVRK 2.2 and later"
                )
            io_path = explicit if os.path.isabs(explicit) else os.path.join(here, explicit)
        else:
            if not serial:
                raise Refusal(
                    f"--dvrk-json {path}: arm {name} has no \"serial\": the dVRK finds its IO file "
                    f"sawRobotIO1394-{io_arm}-<serial>.json by it"
                )
            io_path = os.path.join(here, f"sawRobotIO1394-{io_arm}-{serial}.json")
        if not os.path.isfile(io_path):
            xml = io_path[: -len(".json")] + ".xml"
            also = f" (there is {os.path.basename(xml)}: convert it with dVRK 2.2+)" if os.path.isfile(xml) else ""
            raise Refusal(
                f"--dvrk-json {path}: arm {name}: its IO file {io_path} does not exist{also}; "
                f"the dVRK names it sawRobotIO1394-<arm>-<serial>.json next to the system JSON"
            )
        if not FILE_RE.match(os.path.basename(io_path)):
            raise Refusal(
                f"arm {name}: IO file {io_path}: the file name must use only letters, digits, '.', '_' and '-'"
            )
        kind, boards, hardware = io_facts(io_path, io_arm, name)
        frame = a.get("base_frame", a.get("base-frame"))
        if isinstance(frame, dict) and "transform" in frame:
            base = "transform"
        elif isinstance(frame, dict) and "component" in frame:
            base = f"component:{frame['component']}"
        else:
            base = "none"
        print(
            "arm\t"
            + "\t".join(
                [name, io_path, kind, ",".join(map(str, boards)), base, serial or "-", hardware]
            )
        )
    distinct = sorted({s for _, s, _ in sources})
    if len(distinct) > 1:
        detail = "; ".join(f"{n}: {s} ({w})" for n, s, w in sources)
        raise Refusal(
            f"--dvrk-json {path}: the arms are on different ports ({detail}); one service reads one "
            f"port: choose the arms of one port with --arms"
        )
    print(f"source\t{sources[0][1]}\t{sources[0][2]}")


if __name__ == "__main__":
    try:
        main(sys.argv)
    except Refusal as e:
        print(f"install.sh: {e}", file=sys.stderr)
        sys.exit(1)
