#!/usr/bin/env python3
"""Decodes every message of an MCAP file written by `dvrk-sidecar record` with the `mcap` and
`mcap-ros2-support` packages (the ROS 2 decoder Foxglove's tooling uses), and prints one JSON
object per message: topic, schema name, sequence, log time and the decoded fields. A float that is
not finite (the status of a cycle without a sample carries NaN) is printed as the string "nan",
"inf" or "-inf", so every line is strict JSON.

Usage: mcap_check.py FILE
"""

import json
import math
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def fields(m):
    if hasattr(m, "__slots__"):
        return {k: fields(getattr(m, k)) for k in m.__slots__}
    if isinstance(m, (list, tuple)):
        return [fields(x) for x in m]
    if isinstance(m, (bytes, bytearray)):
        return list(m)
    if isinstance(m, float) and not math.isfinite(m):
        return str(m)
    return m


def main():
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header_profile = reader.get_header().profile
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            print(json.dumps({
                "profile": header_profile,
                "topic": channel.topic,
                "encoding": channel.message_encoding,
                "schema": schema.name,
                "schema_encoding": schema.encoding,
                "sequence": message.sequence,
                "log_time": message.log_time,
                "msg": fields(decoded),
            }, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
