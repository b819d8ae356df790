"""Reads a hydractl recording with the independent Python `mcap` reader
and its ROS 2 decoder, and prints, per channel, the schema, the message
count and the last message's decoded fields as JSON."""

import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def plain(value):
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "__slots__"):
        return {name: plain(getattr(value, name)) for name in value.__slots__}
    return value


def main(path):
    channels = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            entry = channels.setdefault(
                channel.topic,
                {"schema": schema.name, "encoding": channel.message_encoding, "count": 0},
            )
            entry["count"] += 1
            entry["last"] = plain(decoded)
            entry["last_log_time"] = message.log_time
    json.dump(channels, sys.stdout)


if __name__ == "__main__":
    main(sys.argv[1])
