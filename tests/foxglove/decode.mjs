// Decode MCAP files the way Foxglove does: @mcap/core reads the file (through its
// summary when it has one, else record by record), @foxglove/rosmsg parses each
// channel's ros2msg schema, @foxglove/rosmsg2-serialization decodes every message.
// Usage: node decode.mjs FILE.mcap [...]; prints one JSON object (per file: per
// topic the schema name, messages decoded, errors and a digest of the values).
import { readFile, open } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { decompress as zstdDecompress } from "fzstd";

const decompressHandlers = {
  zstd: (buffer, decompressedSize) => zstdDecompress(buffer, new Uint8Array(Number(decompressedSize))),
};

function digest(topic, value) {
  // numbers a test can compare with msg_tools' own decode
  if (value && typeof value.data === "number") return [value.data];
  if (value && typeof value.data === "string") return [value.data];
  if (value && Array.isArray(value.name) && value.velocity !== undefined) {
    const s = value.header.stamp;
    return [s.sec, s.nanosec, ...Array.from(value.position), ...Array.from(value.velocity), ...Array.from(value.effort)];
  }
  if (value && Array.isArray(value.status)) return [value.status.length];
  if (value && Array.isArray(value.transforms)) {
    // per transform: stamp, parent and child frame, translation, rotation
    return value.transforms.flatMap((t) => [t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id,
      t.child_frame_id, t.transform.translation.x, t.transform.translation.y, t.transform.translation.z,
      t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w]);
  }
  return [];
}

function makeTopicState(schema) {
  const state = { schema: schema ? schema.name : "", count: 0, errors: 0, firstError: "", first: null, last: null };
  try {
    if (!schema || schema.encoding !== "ros2msg") throw new Error(`schema encoding ${schema && schema.encoding}`);
    const definitions = parse(new TextDecoder().decode(schema.data), { ros2: true });
    state.reader = new MessageReader(definitions);
  } catch (err) {
    state.schemaError = String(err && err.message ? err.message : err);
  }
  return state;
}

function decodeInto(state, topic, data) {
  if (!state.reader) {
    state.errors += 1;
    if (!state.firstError) state.firstError = state.schemaError;
    return;
  }
  try {
    const value = state.reader.readMessage(data);
    state.count += 1;
    const d = digest(topic, value);
    if (state.first === null) state.first = d;
    state.last = d;
  } catch (err) {
    state.errors += 1;
    if (!state.firstError) state.firstError = String(err && err.message ? err.message : err);
  }
}

async function decodeIndexed(path) {
  const handle = await open(path, "r");
  try {
    const size = BigInt((await handle.stat()).size);
    const readable = {
      size: async () => size,
      read: async (offset, length) => {
        const buf = new Uint8Array(Number(length));
        await handle.read(buf, 0, Number(length), Number(offset));
        return buf;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const topics = {};
    const byChannel = new Map();
    for (const [id, channel] of reader.channelsById) {
      const schema = reader.schemasById.get(channel.schemaId);
      byChannel.set(id, channel.topic);
      topics[channel.topic] = topics[channel.topic] || makeTopicState(schema);
    }
    for await (const message of reader.readMessages()) {
      const topic = byChannel.get(message.channelId);
      decodeInto(topics[topic], topic, message.data);
    }
    const stats = reader.statistics ? Number(reader.statistics.messageCount) : -1;
    return { mode: "indexed", summaryMessageCount: stats, topics };
  } finally {
    await handle.close();
  }
}

async function decodeStream(path) {
  const reader = new McapStreamReader({ decompressHandlers });
  reader.append(await readFile(path));
  const schemas = new Map();
  const channels = new Map();
  const topics = {};
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") {
      channels.set(record.id, record.topic);
      topics[record.topic] = topics[record.topic] || makeTopicState(schemas.get(record.schemaId));
    } else if (record.type === "Message") {
      const topic = channels.get(record.channelId);
      decodeInto(topics[topic], topic, record.data);
    }
  }
  return { mode: "stream", summaryMessageCount: -1, topics };
}

const out = {};
for (const path of process.argv.slice(2)) {
  let result;
  try {
    result = await decodeIndexed(path);
  } catch (err) {
    result = await decodeStream(path);
    result.indexedError = String(err && err.message ? err.message : err);
  }
  for (const state of Object.values(result.topics)) delete state.reader;
  out[path] = result;
}
process.stdout.write(JSON.stringify(out));
