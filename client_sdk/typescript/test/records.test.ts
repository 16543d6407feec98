/**
 * records.ts and avatars.ts beyond the vectors: hostile `poses` data (every stream
 * vector's messages with bytes flipped, cut short and spliced, and random bytes) only
 * ever gives BAD_FIELD (field `data`), never another exception; the records before a
 * bad one are kept; a keyframe after a failure starts the avatar afresh.
 */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { test } from "node:test";

import { AvatarTable } from "../src/avatars.js";
import { decode } from "../src/codec.js";
import { ProtocolError } from "../src/errors.js";
import type { Member } from "../src/messages.js";
import { fromHex, repoRoot } from "./helpers.js";

interface StreamCase {
  // The vector file's keys, as in proto/vectors: `handle` is the avatar id.
  name: string;
  avatars: { handle: number; player: string; skeleton: { $bin: string } }[];
  messages: string[];
  error?: string;
}

const STREAMS = (JSON.parse(readFileSync(join(repoRoot(), "proto", "vectors", "poses.json"), "utf8")) as StreamCase[])
  .filter((c) => "messages" in c);

function members(c: StreamCase): Member[] {
  return c.avatars.map((a) => ({ player: a.player, name: a.player, avatarId: a.handle, skeleton: fromHex(a.skeleton.$bin) }));
}

function dataOf(hex: string): Uint8Array {
  const msg = decode(fromHex(hex), { version: 2 });
  assert.equal(msg.type, "poses");
  return msg.type === "poses" ? msg.data : new Uint8Array();
}

/** A small deterministic generator (mulberry32), so a failure can be replayed. */
function rng(seed: number): () => number {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 2 ** 32;
  };
}

test("hostile poses data gives BAD_FIELD on data or poses, never another exception", () => {
  const random = rng(14);
  let failures = 0;
  let decoded = 0;
  for (const c of STREAMS) {
    const datas = c.messages.map(dataOf);
    for (let trial = 0; trial < 150; trial++) {
      const table = new AvatarTable();
      table.reset(members(c));
      for (const original of datas) {
        const data = Uint8Array.from(original);
        const kind = trial % 3;
        if (kind === 0 && data.length > 0) {
          for (let n = 0; n < 1 + (trial % 4); n++) {
            const i = Math.floor(random() * data.length);
            data[i] = data[i]! ^ (1 << Math.floor(random() * 8));
          }
        }
        const cut = kind === 1 ? data.subarray(0, Math.floor(random() * (data.length + 1))) : data;
        const spliced = kind === 2 ? Uint8Array.from([...cut, ...datas[Math.floor(random() * datas.length)]!]) : cut;
        const result = table.poses({ type: "poses", t: 1, data: spliced });
        decoded += result.poses.length;
        for (const pose of result.poses) {
          assert.equal(pose.positions.length, 57);
          assert.ok(pose.positions.every(Number.isFinite), `${c.name}: positions not finite`);
        }
        if (result.error !== undefined) {
          failures++;
          assert.ok(result.error instanceof ProtocolError);
          assert.deepEqual([result.error.code, result.error.field], ["BAD_FIELD", "data"]);
        }
      }
    }
  }
  assert.ok(failures > 500 && decoded > 500, `${failures} failures, ${decoded} poses`);
});

test("random bytes as poses data or as a whole message: typed errors only", () => {
  const random = rng(7);
  const c = STREAMS[0]!;
  for (let trial = 0; trial < 2000; trial++) {
    const bytes = Uint8Array.from({ length: Math.floor(random() * 300) }, () => Math.floor(random() * 256));
    const table = new AvatarTable();
    table.reset(members(c));
    const result = table.poses({ type: "poses", t: 0, data: bytes });
    assert.ok(result.error === undefined || result.error.code === "BAD_FIELD");
    for (const version of [1, 2]) {
      try {
        decode(bytes, { version });
      } catch (err) {
        assert.ok(err instanceof ProtocolError, String(err));
      }
    }
  }
});

test("the records before a bad one are kept, and a keyframe starts afresh after it", () => {
  const c = STREAMS.find((s) => s.name === "poses_stream_two_avatars")!;
  const [first, second] = c.messages.map(dataOf);
  const table = new AvatarTable();
  table.reset(members(c));
  const good = table.poses({ type: "poses", t: 1, data: first! });
  assert.equal(good.error, undefined);
  assert.ok(good.poses.length >= 2 && good.poses.every((p) => p.keyframe));
  // The first message again, then a record for an avatar id nobody announced (0x7f).
  const bad = table.poses({ type: "poses", t: 2, data: Uint8Array.from([...first!, 0x7f, 0x01]) });
  assert.equal(bad.poses.length, good.poses.length);
  assert.equal(bad.error?.field, "data");
  table.dropState(); // as after a resync request: every reference gone
  const delta = table.poses({ type: "poses", t: 3, data: second! });
  assert.match(delta.error?.message ?? "", /before its keyframe/);
  const again = table.poses({ type: "poses", t: 4, data: first! });
  assert.equal(again.error, undefined);
  assert.deepEqual(again.poses.map((p) => p.positions), good.poses.map((p) => p.positions));
});

test("a join of a known player on its own avatar id keeps its reference; another player's does not", () => {
  // Cluster failover: the player moved from another node to this one and is announced
  // again on the same avatar id, and the server goes on with deltas against its reference.
  const c = STREAMS.find((s) => s.name === "poses_stream_two_avatars")!;
  const [first, second] = c.messages.map(dataOf);
  const table = new AvatarTable();
  const ms = members(c);
  table.reset(ms);
  assert.equal(table.poses({ type: "poses", t: 1, data: first! }).error, undefined);
  const m = ms[0]!;
  table.presence({ type: "presence", event: "join", room: "r", player: m.player, name: "again",
    avatarId: m.avatarId!, skeleton: m.skeleton! });
  const kept = table.poses({ type: "poses", t: 2, data: second! });
  assert.equal(kept.error, undefined);
  table.presence({ type: "presence", event: "join", room: "r", player: "someone-else", name: "x",
    avatarId: m.avatarId!, skeleton: m.skeleton! });
  const fresh = table.poses({ type: "poses", t: 3, data: c.messages.map(dataOf)[2]! });
  assert.match(fresh.error?.message ?? "", /before its keyframe/);
});

test("a skeleton announces an avatar id not known yet, keeps the same player's reference, not another's", () => {
  const c = STREAMS.find((s) => s.name === "poses_stream_two_avatars")!;
  const [first, second, third] = c.messages.map(dataOf);
  const table = new AvatarTable();
  const ms = members(c);
  table.reset([]); // no members announced: their skeletons do it
  for (const m of ms) table.skeleton({ type: "skeleton", player: m.player, avatarId: m.avatarId!, skeleton: m.skeleton! });
  const keyed = table.poses({ type: "poses", t: 1, data: first! });
  assert.equal(keyed.error, undefined);
  assert.deepEqual(new Set(keyed.poses.map((p) => p.player)), new Set(ms.map((m) => m.player)));
  const m = ms[0]!;
  table.skeleton({ type: "skeleton", player: m.player, avatarId: m.avatarId!, skeleton: m.skeleton! }); // a calibration
  assert.equal(table.poses({ type: "poses", t: 2, data: second! }).error, undefined);
  // The avatar id now another player's (its leave never arrived): wait for its keyframe.
  table.skeleton({ type: "skeleton", player: "someone-else", avatarId: m.avatarId!, skeleton: m.skeleton! });
  assert.match(table.poses({ type: "poses", t: 3, data: third! }).error?.message ?? "", /before its keyframe/);
});

test("an avatar id passed to another player is no longer the old player's: its late leave or new avatar id leaves the new avatar", () => {
  // The old player's leave never arrived before its avatar id went to someone else (as
  // the Python and C# SDKs keep it: the avatar id names one player, the newest).
  const c = STREAMS.find((s) => s.name === "poses_stream_two_avatars")!;
  const [first] = c.messages.map(dataOf);
  const ms = members(c);
  const m = ms[0]!;
  for (const late of ["leave", "join elsewhere"]) {
    const table = new AvatarTable();
    table.reset(ms);
    table.skeleton({ type: "skeleton", player: "someone-else", avatarId: m.avatarId!, skeleton: m.skeleton! });
    assert.equal(table.avatarIdOf(m.player), undefined, late);
    assert.equal(table.offsetsOf(m.player), undefined, late);
    if (late === "leave") table.presence({ type: "presence", event: "leave", room: "r", player: m.player, name: "" });
    else table.presence({ type: "presence", event: "join", room: "r", player: m.player, name: "again",
      avatarId: 999, skeleton: m.skeleton! });
    assert.equal(table.avatarIdOf("someone-else"), m.avatarId, late);
    const keyed = table.poses({ type: "poses", t: 1, data: first! });
    assert.equal(keyed.error, undefined, late);
    assert.ok(keyed.poses.some((p) => p.player === "someone-else"), late);
  }
});
