/**
 * room-state.ts alone (no sockets): the welcome's members and limits, presence in this
 * room and in another, poses forgotten when their player is gone, and a `poses` message
 * cut short by a bad record: counted, and every reference dropped, so the next delta is
 * refused rather than applied to a stale reference (the proto/vectors stream).
 */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { test } from "node:test";

import { decode } from "../src/codec.js";
import { BadFieldError } from "../src/errors.js";
import { DEFAULT_LIMITS, type Member, type Pose, type Poses, type Welcome } from "../src/messages.js";
import { RoomState } from "../src/room-state.js";
import { fromHex, repoRoot } from "./helpers.js";

interface StreamCase {
  name: string;
  avatars: { handle: number; player: string; skeleton: { $bin: string } }[];
  messages: string[];
}

const STREAM = (JSON.parse(readFileSync(join(repoRoot(), "proto", "vectors", "poses.json"), "utf8")) as StreamCase[])
  .find((c) => c.name === "poses_stream_two_avatars")!;

function welcome(members: Member[], room = "lobby"): Welcome {
  return {
    type: "welcome", version: 2, player: "me", session: "s", role: "spectator", room, t: 1, rate_hz: 60,
    lookahead_frames: 0, members, limits: { ...DEFAULT_LIMITS, max_players: 7 }, pose_rate_hz: 60,
  };
}

function pose(player: string): Pose {
  return { type: "pose", player, seq: 1, t: 1, positions: new Float64Array(57) };
}

const streamMembers = (): Member[] =>
  STREAM.avatars.map((a) => ({ player: a.player, name: a.player, avatarId: a.handle, skeleton: fromHex(a.skeleton.$bin) }));
const streamMessage = (k: number): Poses => decode(fromHex(STREAM.messages[k]!), { version: 2 }) as Poses;

test("joined: the welcome's limits and members; poses of players gone are forgotten", () => {
  const room = new RoomState();
  assert.equal(room.limits, DEFAULT_LIMITS);
  room.joined(welcome([{ player: "a", name: "A" }, { player: "b", name: "B" }]));
  room.pose(pose("a"));
  room.pose(pose("b"));
  assert.equal(room.limits.max_players, 7);
  assert.equal(room.welcome?.room, "lobby");
  room.joined(welcome([{ player: "b", name: "B" }])); // a resume: a left meanwhile
  assert.deepEqual([...room.members.keys()], ["b"]);
  assert.deepEqual([...room.poses.keys()], ["b"]);
});

test("presence: joins and leaves of this room change the members; another room's do not", () => {
  const room = new RoomState();
  room.joined(welcome([{ player: "a", name: "A" }]));
  room.pose(pose("a"));
  room.presence({ type: "presence", event: "join", room: "lobby", player: "b", name: "B" });
  room.presence({ type: "presence", event: "join", room: "elsewhere", player: "c", name: "C" });
  assert.deepEqual([...room.members.keys()], ["a", "b"]);
  const skeleton = fromHex(STREAM.avatars[0]!.skeleton.$bin);
  room.presence({ type: "presence", event: "join", room: "lobby", player: "b", name: "Bee", avatarId: 9, skeleton });
  assert.deepEqual(room.members.get("b"), { player: "b", name: "Bee", avatarId: 9, skeleton });
  room.presence({ type: "presence", event: "stale", room: "lobby", player: "b", name: "Bee!" });
  assert.deepEqual(room.members.get("b"), { player: "b", name: "Bee!", avatarId: 9, skeleton }); // kept
  room.presence({ type: "presence", event: "leave", room: "lobby", player: "a", name: "A" });
  room.presence({ type: "presence", event: "leave", room: "elsewhere", player: "b", name: "B" });
  assert.deepEqual([...room.members.keys()], ["b"]);
  assert.equal(room.poses.size, 0);
});

test("v2: the stream's poses; a bad record is counted and drops every reference", () => {
  const fresh = (): RoomState => {
    const room = new RoomState();
    const w = welcome(streamMembers());
    room.welcomed(w, 2);
    room.joined(w);
    return room;
  };
  const room = fresh();
  const first = room.posesOf(streamMessage(0));
  assert.equal(first.error, undefined);
  assert.deepEqual(first.poses.map((p) => p.keyframe), [true, true]);
  for (const p of first.poses) room.pose(p);
  assert.equal(room.poses.size, 2);
  assert.ok(room.offsetsOf(STREAM.avatars[0]!.player) instanceof Float64Array);

  // The control: without a bad record between, message 1's deltas apply.
  const control = fresh();
  control.posesOf(streamMessage(0));
  assert.deepEqual(control.posesOf(streamMessage(1)).poses.map((p) => p.keyframe), [false, false]);
  assert.equal(control.badRecords, 0);

  const bad = room.posesOf({ type: "poses", t: 1, data: Uint8Array.of(0xff, 0xff, 0xff) });
  assert.ok(bad.error instanceof BadFieldError, String(bad.error));
  assert.equal(room.badRecords, 1);
  const next = room.posesOf(streamMessage(1)); // deltas, but the references are gone
  assert.ok(next.error instanceof BadFieldError);
  assert.deepEqual(next.poses, []);
  assert.equal(room.badRecords, 2);
});
