// Validate captured icefloe bus messages against the JSON Schemas in schemas/json.
//
//   npm ci                      # once: @msgpack/msgpack and ajv, versions from package-lock.json
//   node validate.mjs DIR       # DIR holds <Message>.msgpack files, e.g. Pose.msgpack, Pose-2.msgpack
//
// Each file is one payload as it came off the bus (MessagePack, a map keyed by
// field names); the message type is the file name up to the first "-" or ".".
// Prints "<file> ok" or "<file> invalid: <what>" per file, a JSON summary on
// stderr, and exits 1 if any message was invalid.
//
// Two things a JavaScript consumer must know about icefloe payloads:
// * `stamp` is integer nanoseconds since the epoch, about 1.8e18: more than a
//   JavaScript number holds exactly (2^53). We decode 64-bit integers as
//   BigInt, so nothing is lost, and check them as the integers they are.
// * MessagePack has a binary type (camera JPEGs, OLED pixels); JSON Schema
//   describes bytes as base64 strings (that is how they travel in JSON), so we
//   turn binary into base64 before validating.

import { readdirSync, readFileSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

import { decode } from "@msgpack/msgpack";
import Ajv2020 from "ajv/dist/2020.js";

const SCHEMAS = join(dirname(fileURLToPath(import.meta.url)), "..", "..", "schemas", "json");

const ajv = new Ajv2020({ allErrors: true });
ajv.addVocabulary(["x-icefloe-keys"]); // our annotation: which bus keys carry the message
const validators = new Map();

function validator(name) {
  if (!validators.has(name)) {
    const schema = JSON.parse(readFileSync(join(SCHEMAS, `${name}.json`), "utf8"));
    validators.set(name, ajv.compile(schema));
  }
  return validators.get(name);
}

// The message as JSON would carry it: bytes as base64, 64-bit integers as numbers
// (only for the schema check, which asks "is it an integer?").
function jsonShape(value) {
  if (value instanceof Uint8Array) return Buffer.from(value).toString("base64");
  if (typeof value === "bigint") return Number(value);
  if (Array.isArray(value)) return value.map(jsonShape);
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, jsonShape(v)]));
  }
  return value;
}

const dir = process.argv[2];
if (!dir) {
  console.error("usage: node validate.mjs DIR");
  process.exit(2);
}
const summary = { valid: 0, invalid: 0 };
for (const file of readdirSync(dir).filter((f) => f.endsWith(".msgpack")).sort()) {
  const name = file.split(/[-.]/)[0];
  const message = decode(readFileSync(join(dir, file)), { useBigInt64: true });
  const validate = validator(name);
  if (validate(jsonShape(message))) {
    summary.valid += 1;
    console.log(`${file} ok`);
  } else {
    summary.invalid += 1;
    const what = validate.errors.map((e) => `${e.instancePath || "/"} ${e.message}`).join("; ");
    console.log(`${file} invalid: ${what}`);
  }
}
console.error(JSON.stringify(summary));
process.exit(summary.invalid ? 1 : 0);
