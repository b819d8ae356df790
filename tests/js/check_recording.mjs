// Reads a hydractl recording with the libraries Foxglove itself uses
// (@mcap/core for the file, @foxglove/rosmsg to parse each ros2msg schema,
// @foxglove/rosmsg2-serialization to decode each CDR message) and prints,
// per channel, the schema, the message count and the last message's
// decoded fields as JSON: what Foxglove would show.
import { readFileSync } from "node:fs";
import { McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { decompress } from "fzstd";

const path = process.argv[2];
const reader = new McapStreamReader({
  decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
});
reader.append(readFileSync(path));
const schemas = new Map();
const channels = new Map();
const out = {};
for (let record; (record = reader.nextRecord()); ) {
  if (record.type === "Schema") {
    const text = new TextDecoder().decode(record.data);
    schemas.set(record.id, { name: record.name, reader: new MessageReader(parse(text, { ros2: true })) });
  } else if (record.type === "Channel") {
    channels.set(record.id, { topic: record.topic, encoding: record.messageEncoding, schema: schemas.get(record.schemaId) });
  } else if (record.type === "Message") {
    const channel = channels.get(record.channelId);
    const entry = (out[channel.topic] ??= { schema: channel.schema.name, encoding: channel.encoding, count: 0 });
    entry.count += 1;
    entry.last = channel.schema.reader.readMessage(record.data);
  }
}
const plain = (_key, value) =>
  typeof value === "bigint" ? Number(value) : ArrayBuffer.isView(value) ? Array.from(value) : value;
process.stdout.write(JSON.stringify(out, plain));
