// List an MCAP file's attachments and metadata records as Foxglove's @mcap/core reader reads them, as JSON.
// Usage: node read_attachments.mjs FILE.mcap
// Attachments are read with their CRCs checked and summarised by a SHA-256 of their data.
import { createHash } from "node:crypto";
import { open } from "node:fs/promises";

import { McapIndexedReader } from "@mcap/core";

const path = process.argv[2];
const handle = await open(path, "r");
const { size } = await handle.stat();
const readable = {
  size: async () => BigInt(size),
  read: async (offset, length) => {
    const buffer = new Uint8Array(Number(length));
    await handle.read(buffer, 0, buffer.length, Number(offset));
    return buffer;
  },
};
const reader = await McapIndexedReader.Initialize({ readable });
const out = { attachments: {}, metadata: {} };
for await (const attachment of reader.readAttachments({ validateCrcs: true })) {
  out.attachments[attachment.name] = {
    media_type: attachment.mediaType,
    sha256: createHash("sha256").update(attachment.data).digest("hex"),
  };
}
for await (const record of reader.readMetadata()) {
  out.metadata[record.name] = Object.fromEntries(record.metadata);
}
await handle.close();
process.stdout.write(JSON.stringify(out));
