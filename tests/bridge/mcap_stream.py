#!/usr/bin/env python3
"""Reads an MCAP file the way a standard tool reads a recording that may have lost its end
(killed, power loss, full disk): the `mcap` package's streaming reader (NonSeekingReader, what
`make_reader` returns for a stream that cannot seek) in file order, decoding every message with
`mcap-ros2-support`, until the footer or the first record that is not complete.

Prints one JSON object per message (topic, sequence, log_time), then one last object:
{"end": "footer" | "truncated", "error": ..., "seeking": true | false, "seeking_messages": N},
where "seeking" says whether the seeking reader opens the file too (`make_reader` on the file,
as most tools open a recording: it reads the footer first, then the summary if there is one,
else the file in order) and "seeking_messages" how many messages it reads (null if it fails).

Usage: mcap_stream.py FILE
"""

import json
import sys

from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory


def main():
    end, error = "footer", None
    with open(sys.argv[1], "rb") as f:
        reader = NonSeekingReader(f, decoder_factories=[DecoderFactory()])
        try:
            for _schema, channel, message, _decoded in reader.iter_decoded_messages(
                log_time_order=False
            ):
                print(json.dumps({
                    "topic": channel.topic,
                    "sequence": message.sequence,
                    "log_time": message.log_time,
                }))
        except Exception as e:  # the end of a file cut short: stop there, as `mcap recover` does
            end, error = "truncated", f"{type(e).__name__}: {e}"
    seeking, seeking_messages = True, None
    try:
        with open(sys.argv[1], "rb") as f:
            reader = make_reader(f)
            reader.get_summary()
            seeking_messages = sum(1 for _ in reader.iter_messages(log_time_order=False))
    except Exception:
        seeking = False
    print(json.dumps({
        "end": end, "error": error, "seeking": seeking, "seeking_messages": seeking_messages,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
