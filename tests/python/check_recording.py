"""Reads a hydractl recording with the independent Python `mcap` reader
and its ROS 2 decoder, and prints, per channel, the schema, the message
count and the last message's decoded fields as JSON.

With `--stream`, reads record by record without the summary, as a reader
must for a file a killed recorder left, and prints the message count per
channel up to where the file stops."""

import json
import math
import sys

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory


def plain(value):
    # JSON has no NaN (a missing PDO's reading, a valve sample answering
    # no reading): null, as JSON.stringify writes it.
    if isinstance(value, float) and not math.isfinite(value):
        return None
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


def stream(path):
    topics, channels = {}, {}
    cut_short = False
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Message):
                    entry = channels.setdefault(topics[record.channel_id], {"count": 0})
                    entry["count"] += 1
        except McapError as error:
            # The end of a killed writer's file: a record cut off, or the
            # chunk being filled, whose length was never written.
            cut_short = type(error).__name__
    json.dump({"channels": channels, "cut_short": cut_short}, sys.stdout)


if __name__ == "__main__":
    if sys.argv[1] == "--stream":
        stream(sys.argv[2])
    else:
        main(sys.argv[1])
