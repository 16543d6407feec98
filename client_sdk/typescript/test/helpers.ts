/** Shared test helpers: where the repository is, hex <-> bytes, wire maps as JSON. */

import assert from "node:assert/strict";
import { existsSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

import type { InterpOptions } from "../src/interp.js";
import { Float64, type Wire } from "../src/msgpack.js";

/** The repository root: the first parent of this file that holds `proto/README.md`. */
export function repoRoot(): string {
  let dir = dirname(fileURLToPath(import.meta.url));
  for (;;) {
    if (existsSync(join(dir, "proto", "README.md"))) return dir;
    const up = dirname(dir);
    if (up === dir) throw new Error("no proto/README.md above " + import.meta.url);
    dir = up;
  }
}

export function fromHex(hex: string): Uint8Array {
  return Uint8Array.from(Buffer.from(hex, "hex"));
}

export function toHex(bytes: Uint8Array): string {
  return Buffer.from(bytes).toString("hex");
}

/**
 * A wire value as the vectors write it in JSON: bins as `{"$bin": hex}`, floats and
 * ints as plain numbers, maps as objects (key order kept).
 */
export function wireToJson(v: Wire): unknown {
  if (v instanceof Float64) return v.value;
  if (v instanceof Uint8Array) return { $bin: toHex(v) };
  if (v instanceof Map) {
    const out: Record<string, unknown> = {};
    for (const [k, item] of v) out[k] = wireToJson(item);
    return out;
  }
  if (Array.isArray(v)) return (v as readonly Wire[]).map(wireToJson);
  return v;
}

/** Every key of every nested object, in order: JSON equality ignores key order. */
export function keyOrder(v: unknown): string[] {
  if (Array.isArray(v)) return v.flatMap(keyOrder);
  if (v !== null && typeof v === "object") {
    return Object.entries(v).flatMap(([k, item]) => [k, ...keyOrder(item)]);
  }
  return [];
}

/** A table's config (Python names) as options; every knob must be known. */
export function interpOptions(c: Record<string, number | boolean>): InterpOptions {
  const names: Record<string, keyof InterpOptions> = {
    adaptive: "adaptive", delay_s: "delayS", min_delay_s: "minDelayS", max_delay_s: "maxDelayS",
    delay_quantile: "delayQuantile", delay_window: "delayWindow", delay_margin_s: "delayMarginS",
    delay_slew: "delaySlew", max_extrapolate_s: "maxExtrapolateS", teleport_m: "teleportM",
    gap_s: "gapS", capacity: "capacity", correction_s: "correctionS",
  };
  const out: Record<string, number | boolean> = {};
  for (const [k, v] of Object.entries(c)) {
    const name = names[k];
    assert.ok(name !== undefined, `unknown knob ${k}`);
    out[name] = v;
  }
  assert.equal(Object.keys(out).length, Object.keys(names).length, "every knob is named");
  return out as InterpOptions;
}
