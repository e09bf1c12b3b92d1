/**
 * An independent reader of a rosbag2 MCAP bag folder, in TypeScript with Foxglove's and the
 * MCAP project's libraries (the tools a non-Python consumer uses): the files listed in
 * metadata.yaml, each read through its summary (chunk indexes, any compression), every
 * message decoded from CDR with the message definition the file carries for its channel.
 *
 *   node dist/read_bag.js BAG_DIR  ->  JSON on stdout
 *
 * Per topic: type, message count, the sum of the header stamps [ns] (exact, as a decimal
 * string), the sums of the numeric fields (JointState position / velocity / effort,
 * WrenchStamped force / torque, DiagnosticArray levels; non-finite ones as strings), the
 * first message decoded, the first and last log times [ns]; per file its message count; the
 * chunks' compression; and metadata.yaml's counts, for the caller to compare.
 */
import { McapIndexedReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { open, readFile } from "node:fs/promises";
import { join } from "node:path";
import { parse as parseYaml } from "yaml";

type Stamp = { sec: number; nanosec: number };
type TopicSummary = {
  type: string;
  count: number;
  stamp_ns_sum: string;
  log_ns_first: string;
  log_ns_last: string;
  sums: Record<string, number>;
  first: unknown;
};

function stampNs(msg: { header?: { stamp?: Stamp } }): bigint | undefined {
  const stamp = msg.header?.stamp;
  return stamp === undefined ? undefined : BigInt(stamp.sec) * 1_000_000_000n + BigInt(stamp.nanosec);
}

/** The numeric fields summed per message type (the others are only counted). */
function fieldValues(type: string, msg: any): Record<string, ArrayLike<number>> {
  if (type === "sensor_msgs/msg/JointState") {
    return { position: msg.position, velocity: msg.velocity, effort: msg.effort };
  }
  if (type === "geometry_msgs/msg/WrenchStamped") {
    const { force: f, torque: m } = msg.wrench;
    return { force: [f.x, f.y, f.z], torque: [m.x, m.y, m.z] };
  }
  if (type === "diagnostic_msgs/msg/DiagnosticArray") {
    return { level: msg.status.map((s: { level: number }) => s.level) };
  }
  return {};
}

/** A decoded message as JSON-ready values (typed arrays to plain arrays). */
function plain(value: unknown): unknown {
  if (ArrayBuffer.isView(value)) {
    return Array.from(value as unknown as ArrayLike<number>, plain);
  }
  if (Array.isArray(value)) {
    return value.map(plain);
  }
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  if (typeof value === "number" && !Number.isFinite(value)) {
    return String(value);                 // NaN, Infinity: not representable in JSON
  }
  return typeof value === "bigint" ? value.toString() : value;
}

async function main(): Promise<void> {
  const bag = process.argv[2];
  if (!bag) {
    throw new Error("usage: node dist/read_bag.js BAG_DIR");
  }
  const meta = parseYaml(await readFile(join(bag, "metadata.yaml"), "utf8")).rosbag2_bagfile_information;
  const decompressHandlers = await loadDecompressHandlers();
  const topics: Record<string, TopicSummary> = {};
  const stampSums: Record<string, bigint> = {};
  const files: Record<string, number> = {};
  const compression = new Set<string>();
  for (const name of meta.relative_file_paths as string[]) {
    const handle = await open(join(bag, name), "r");
    try {
      const reader = await McapIndexedReader.Initialize({
        readable: new FileHandleReadable(handle),
        decompressHandlers,
      });
      for (const chunk of reader.chunkIndexes) {
        compression.add(chunk.compression === "" ? "none" : chunk.compression);
      }
      const decoders = new Map<number, { topic: string; type: string; reader: MessageReader }>();
      for (const [id, channel] of reader.channelsById) {
        const schema = reader.schemasById.get(channel.schemaId);
        if (!schema || schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
          throw new Error(`${name}: channel ${channel.topic} is not ros2msg + cdr`);
        }
        const definitions = parse(new TextDecoder().decode(schema.data), { ros2: true });
        decoders.set(id, { topic: channel.topic, type: schema.name, reader: new MessageReader(definitions) });
      }
      let count = 0;
      for await (const record of reader.readMessages()) {
        const decoder = decoders.get(record.channelId)!;
        const msg = decoder.reader.readMessage<any>(record.data);
        const summary = (topics[decoder.topic] ??= {
          type: decoder.type, count: 0, stamp_ns_sum: "0", log_ns_first: record.logTime.toString(),
          log_ns_last: "0", sums: {}, first: plain(msg),
        });
        summary.count += 1;
        summary.log_ns_last = record.logTime.toString();
        const stamp = stampNs(msg);
        if (stamp !== undefined) {
          stampSums[decoder.topic] = (stampSums[decoder.topic] ?? 0n) + stamp;
        }
        for (const [field, values] of Object.entries(fieldValues(decoder.type, msg))) {
          let sum = summary.sums[field] ?? 0;
          for (let i = 0; i < values.length; i++) {
            sum += values[i]!;
          }
          summary.sums[field] = sum;
        }
        count += 1;
      }
      files[name] = count;
    } finally {
      await handle.close();
    }
  }
  for (const [topic, sum] of Object.entries(stampSums)) {
    topics[topic]!.stamp_ns_sum = sum.toString();
  }
  for (const summary of Object.values(topics)) {
    summary.sums = plain(summary.sums) as Record<string, number>;
  }
  const metadataCounts: Record<string, number> = {};
  for (const entry of meta.topics_with_message_count) {
    metadataCounts[entry.topic_metadata.name] = entry.message_count;
  }
  process.stdout.write(JSON.stringify({
    files, compression: [...compression].sort(), topics,
    metadata: { message_count: meta.message_count, topics: metadataCounts },
  }));
}

main().catch((error: unknown) => {
  process.stderr.write(`read_bag: ${error instanceof Error ? error.stack : String(error)}\n`);
  process.exit(1);
});
