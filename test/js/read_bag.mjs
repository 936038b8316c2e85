// Decode a roi_node ROI bag's MCAP files as Foxglove does and print what they hold as JSON.
// Usage: node read_bag.mjs FILE.mcap [FILE.mcap ...]
// Every message is decoded with the ros2msg schema the file carries (@foxglove/rosmsg parses it,
// @foxglove/rosmsg2-serialization reads the CDR); images are summarised by a SHA-256 of their data.
import { createHash } from "node:crypto";
import { open } from "node:fs/promises";

import { McapIndexedReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

async function readable(path) {
  const handle = await open(path, "r");
  const { size } = await handle.stat();
  return {
    handle,
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      await handle.read(buffer, 0, buffer.length, Number(offset));
      return buffer;
    },
  };
}

const sha256 = (bytes) => createHash("sha256").update(bytes).digest("hex");
const stamp = (header) => ({ sec: header.stamp.sec, nanosec: header.stamp.nanosec });

const out = { schemas: {}, images: {}, compressed: {}, markers: {}, metadata: {} };
for (const path of process.argv.slice(2)) {
  const source = await readable(path);
  const reader = await McapIndexedReader.Initialize({ readable: source });
  const readers = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    if (schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
      throw new Error(`${path}: ${channel.topic}: schema encoding ${schema.encoding}, message encoding ${channel.messageEncoding}`);
    }
    const text = new TextDecoder().decode(schema.data);
    readers.set(id, { topic: channel.topic, type: schema.name, reader: new MessageReader(parse(text, { ros2: true })) });
    out.schemas[channel.topic] = schema.name;
  }
  for await (const message of reader.readMessages()) {
    const { topic, type, reader: decoder } = readers.get(message.channelId);
    const msg = decoder.readMessage(message.data);
    const add = (group, value) => (out[group][topic] ??= []).push(value);
    if (type === "sensor_msgs/msg/Image") {
      add("images", { stamp: stamp(msg.header), frame_id: msg.header.frame_id, width: msg.width, height: msg.height,
                      encoding: msg.encoding, sha256: sha256(msg.data) });
    } else if (type === "sensor_msgs/msg/CompressedImage") {
      add("compressed", { stamp: stamp(msg.header), frame_id: msg.header.frame_id, format: msg.format, sha256: sha256(msg.data) });
    } else if (type === "visualization_msgs/msg/ImageMarker") {
      add("markers", { stamp: stamp(msg.header), frame_id: msg.header.frame_id, ns: msg.ns, type: msg.type,
                       points: msg.points.map((p) => [p.x, p.y]) });
    } else if (type === "std_msgs/msg/String") {
      const record = JSON.parse(msg.data); // stamp_ns is past 2^53: a JS number rounds it; "stamp" is exact
      add("metadata", { stamp: record.stamp, crop_boxes: Object.fromEntries(record.arms.map((a) => [a.arm_id, a.crop_box])) });
    }
  }
  await source.handle.close();
}
process.stdout.write(JSON.stringify(out));
