/** EventQueue: latest-wins per player for poses, bounded FIFO for the rest. */

import assert from "node:assert/strict";
import { test } from "node:test";

import { EventQueue } from "../src/events.js";
import type { Pose, Presence, Welcome } from "../src/messages.js";

const pose = (player: string, seq: number): Pose => ({
  type: "pose", player, seq, t: seq, positions: new Float64Array(57),
});
const presence = (player: string, event: Presence["event"] = "join"): Presence => ({
  type: "presence", event, room: "r", player, name: player,
});

async function drain(q: EventQueue): Promise<string[]> {
  q.end();
  const out: string[] = [];
  for (;;) {
    const r = await q.next();
    if (r.done) return out;
    const ev = r.value;
    const sign = (e: Presence): string => (e.event === "join" ? "+" : e.event === "leave" ? "-" : `${e.event} `);
    out.push(ev.type === "pose" ? `${ev.player}${ev.seq}` : ev.type === "presence" ? `${sign(ev)}${ev.player}` : ev.type);
  }
}

test("an unread pose is replaced in place by the same player's newer pose", async () => {
  const q = new EventQueue(10);
  q.push(pose("a", 1));
  q.push(presence("b"));
  q.push(pose("b", 1));
  q.push(pose("a", 2));
  q.push(pose("a", 3));
  assert.deepEqual(await drain(q), ["a3", "+b", "b1"]);
});

test("a player's pose after its leave and join stays after them", async () => {
  // A rejoin (another name or layout) on the server: the new session's pose must not
  // take the old unread pose's place, before the leave.
  const q = new EventQueue(10);
  q.push(pose("a", 1));
  q.push(presence("a", "leave"));
  q.push(presence("a"));
  q.push(pose("a", 2));
  q.push(pose("a", 3));
  q.push(pose("b", 1));
  q.push({ type: "welcome", welcome: {} as Welcome, resumed: true });
  q.push(pose("b", 2));
  assert.deepEqual(await drain(q), ["a1", "-a", "+a", "a3", "b1", "welcome", "b2"]);
});

test("a slow reader costs one pose per player plus the bound", async () => {
  const q = new EventQueue(3);
  for (let i = 0; i < 1000; i++) {
    q.push(pose("a", i));
    q.push(pose("b", i));
    if (i % 100 === 0) q.push(presence(`p${i}`));
  }
  assert.equal(q.size, 2 + 3);
  assert.equal(q.dropped, 7);
  assert.deepEqual(await drain(q), ["a999", "b999", "+p700", "+p800", "+p900"]);
});

test("a waiting reader gets the next event at once; end(error) throws once", async () => {
  const q = new EventQueue(4);
  const next = q.next();
  q.push(pose("a", 1));
  assert.deepEqual((await next).value, pose("a", 1));
  const waiting = q.next();
  q.end(new Error("kicked"));
  await assert.rejects(waiting, /kicked/);
  assert.equal((await q.next()).done, true);
});
