/**
 * The SDK against a real `posecast serve --dev` process (8 samples): players stream,
 * a spectator watches, the clock syncs, refusals arrive as typed errors, and a
 * client survives a server restart (SIGTERM: bye SERVER_SHUTDOWN; a new process on
 * the same port and secret) by reconnecting and resuming.
 */

import assert from "node:assert/strict";
import { after, before, describe, test } from "node:test";

import WebSocket from "ws";

import { connect, type ConnectOptions, type PosecastClient } from "../src/client.js";
import {
  ForbiddenError,
  OutOfRangeError,
  TokenExpiredError,
  UnauthenticatedError,
} from "../src/errors.js";
import type { ClientEvent } from "../src/events.js";
import type { Pose } from "../src/messages.js";
import { type FrameInput, jointPosition, toTrackers } from "../src/trackers.js";
import { mintToken, type RunningServer, serverSkipReason, startServer } from "./server.js";

const skip = serverSkipReason();
if (skip !== undefined) console.warn(`\n*** integration tests ${skip} ***\n`);
const OPTS: ConnectOptions = {
  WebSocket, timeoutS: 10, reconnect: { initialDelayS: 0.1, maxDelayS: 0.5, maxAttempts: 40 },
};

/** A person standing at (x0, 0), swaying and swinging the arms, at time t (seconds). */
function body(t: number, x0: number): FrameInput {
  const yaw = 0.2 * Math.sin(t);
  const q = [0, Math.sin(yaw / 2), 0, Math.cos(yaw / 2)] as const;
  const swing = 0.15 * Math.sin(2 * Math.PI * t);
  const at = (x: number, y: number, z: number) => ({ position: [x0 + x, y, z] as const, orientation: q });
  return {
    head: at(0.02 * Math.sin(t), 1.62, 0.03),
    leftHand: at(0.22, 0.9, swing),
    rightHand: at(-0.22, 0.9, -swing),
    waist: at(0, 0.98, 0),
  };
}

/** Send `body` at 60 Hz until stopped. */
function stream(client: PosecastClient, x0: number): () => void {
  const t0 = performance.now() / 1000;
  const id = setInterval(() => client.sendFrame(body(performance.now() / 1000 - t0, x0)), 1000 / 60);
  return () => clearInterval(id);
}

async function until(
  it: AsyncIterator<ClientEvent>,
  match: (ev: ClientEvent) => boolean,
  timeoutS = 10,
): Promise<ClientEvent> {
  const deadline = Date.now() + timeoutS * 1000;
  for (;;) {
    const r = await Promise.race([
      it.next(),
      new Promise<never>((_, reject) =>
        setTimeout(() => reject(new Error("timed out waiting for an event")), Math.max(0, deadline - Date.now())).unref(),
      ),
    ]);
    assert.ok(!r.done, "the event stream ended");
    if (match(r.value)) return r.value;
  }
}

describe("against posecast serve", { skip }, () => {
  let server: RunningServer;
  before(async () => {
    server = await startServer();
  });
  after(async () => {
    await server?.stop();
  });
  const token = (player: string, room = "arena", role: "player" | "spectator" = "player") =>
    mintToken(server.secret, { room, player, role });

  test("players stream, everyone receives poses and presence, the clock syncs", async () => {
    const ada = await connect(server.url, token("ada"), OPTS);
    const welcome = await ada.join("arena", "Ada");
    assert.deepEqual([welcome.player, welcome.role, welcome.room], ["ada", "player", "arena"]);
    const spectator = await connect(server.url, token("cam", "arena", "spectator"), OPTS);
    await spectator.join("arena", "Camera");
    const events = spectator.events();
    const bob = await connect(server.url, token("bob"), OPTS);
    await bob.join("arena", "Bob");
    const stops = [stream(ada, -0.8), stream(bob, 0.8)];
    try {
      const joined = await until(events, (ev) => ev.type === "presence" && ev.player === "bob");
      assert.ok(joined.type === "presence" && joined.name === "Bob" && joined.event === "join");
      const poses = new Map<string, Pose>();
      await until(events, (ev) => {
        if (ev.type === "pose") poses.set(ev.player, ev);
        return poses.size === 2 && poses.get("ada")!.seq > 30;
      });
      for (const [player, x0] of [["ada", -0.8], ["bob", 0.8]] as const) {
        const pose = poses.get(player)!;
        const head = jointPosition(pose, "HEAD");
        assert.ok(Math.abs(head[0] - x0) < 0.3 && head[1] > 1.3 && head[1] < 1.9, `${player} head ${head}`);
        assert.ok(jointPosition(pose, "LEFT_TOE")[1] < 0.3, `${player} toes near the floor`);
      }
      assert.deepEqual([...spectator.members.values()].map((m) => m.name).sort(), ["Ada", "Bob"]);
      assert.ok(ada.poses.has("ada"), "a player receives its own pose too");
      // Clock sync: the first pings go out right after the welcome.
      const c = spectator.clock;
      assert.ok(c.rttS !== undefined && c.rttS >= 0 && c.rttS < 0.2, `rtt ${c.rttS}`);
      const latency = performance.now() / 1000 - c.toClient(poses.get("ada")!.t);
      assert.ok(latency > -0.05 && latency < 1, `pose age ${latency} s`);
    } finally {
      stops.forEach((stop) => stop());
      await Promise.all([ada.close(), bob.close(), spectator.close()]);
    }
  });

  test("v2 and a v1-pinned client see the same body: joints within 1 cm, rotations within 0.5 deg", async () => {
    const ada = await connect(server.url, token("ada3"), OPTS);
    await ada.join("arena", "Ada");
    const v2 = await connect(server.url, token("cam2", "arena", "spectator"), OPTS);
    await v2.join("arena", "Cam v2");
    const v1 = await connect(server.url, token("cam1", "arena", "spectator"), { ...OPTS, protocol: 1 });
    await v1.join("arena", "Cam v1");
    assert.deepEqual([ada.version, v2.version, v1.version], [2, 2, 1]);
    const slow = await connect(server.url, token("cam3", "arena", "spectator"), OPTS);
    await slow.join("arena", "Cam 20 Hz", undefined, { poseRateHz: 20 });
    const seen = { v2: new Map<number, Pose>(), v1: new Map<number, Pose>(), slow: new Map<number, Pose>() };
    const collect = async (client: PosecastClient, into: Map<number, Pose>): Promise<void> => {
      for await (const ev of client) {
        if (ev.type === "pose" && ev.player === "ada3") into.set(ev.seq, ev);
        if (into.size >= 60) return;
      }
    };
    const stop = stream(ada, 0.3);
    try {
      await Promise.race([
        Promise.all([collect(v2, seen.v2), collect(v1, seen.v1), collect(slow, seen.slow)]),
        new Promise((_, reject) => setTimeout(() => reject(new Error("too few poses")), 20_000).unref()),
      ]);
    } finally {
      stop();
    }
    let worstMm = 0;
    let worstDeg = 0;
    let common = 0;
    for (const [seq, a] of seen.v2) {
      const b = seen.v1.get(seq);
      if (b === undefined) continue;
      common++;
      assert.ok(a.rotations !== undefined && a.localRotations !== undefined && b.rotations !== undefined);
      for (let j = 0; j < 19; j++) {
        const d = Math.hypot(...[0, 1, 2].map((c) => a.positions[3 * j + c]! - b.positions[3 * j + c]!));
        worstMm = Math.max(worstMm, d * 1000);
        // v1 rotations are within 3.1e-5 of unit length, not renormalised: compare directions.
        const qa = a.rotations.subarray(4 * j, 4 * j + 4);
        const qb = b.rotations.subarray(4 * j, 4 * j + 4);
        const dot = Math.abs(qa.reduce((acc, v, c) => acc + v * qb[c]!, 0)) / (Math.hypot(...qa) * Math.hypot(...qb));
        const deg = (2 * Math.acos(Math.min(1, dot)) * 180) / Math.PI;
        worstDeg = Math.max(worstDeg, deg);
      }
    }
    console.log(`v2 vs v1 over ${common} poses: largest joint ${worstMm.toFixed(2)} mm, rotation ${worstDeg.toFixed(3)} deg`);
    assert.ok(common >= 30, `only ${common} poses in common`);
    assert.ok(worstMm < 10, `joints ${worstMm} mm apart`);
    assert.ok(worstDeg < 0.5, `rotations ${worstDeg} deg apart`);
    // A 20 Hz client gets every third tick's poses.
    const seqs = [...seen.slow.keys()].sort((x, y) => x - y);
    const steps = seqs.slice(1).map((s, i) => s - seqs[i]!);
    assert.ok(steps.filter((d) => d >= 3).length >= steps.length * 0.8, `20 Hz steps ${steps.slice(0, 20)}`);
    await Promise.all([ada.close(), v2.close(), v1.close(), slow.close()]);
  });

  test("refusals are typed errors: forged, expired, wrong room, bad frame", async () => {
    const forged = token("eve").slice(0, -4) + "AAAA";
    await assert.rejects((await connect(server.url, forged, OPTS)).join("arena", "Eve"), UnauthenticatedError);
    const old = mintToken(server.secret, { room: "arena", player: "eve", ttlS: 60, ageS: 600 });
    await assert.rejects((await connect(server.url, old, OPTS)).join("arena", "Eve"), TokenExpiredError);
    await assert.rejects(
      (await connect(server.url, token("eve", "other"), OPTS)).join("arena", "Eve"),
      ForbiddenError,
    );
    const ada = await connect(server.url, token("ada2"), OPTS);
    await ada.join("arena", "Ada");
    const events = ada.events();
    // The SDK refuses a NaN position itself; sent raw, the server refuses it the same way.
    const nan = { position: [Number.NaN, 1, 0], orientation: [0, 0, 0, 1] } as const;
    assert.throws(() => ada.sendFrame({ ...body(0, 0), head: nan }), OutOfRangeError);
    const { trackers } = toTrackers(body(0, 0));
    const bad = [[Number.NaN, 1, 0, 0, 0, 0, 1], trackers[1], trackers[2], trackers[3]] as const;
    ada.send({ type: "frame", seq: 77, t: 1, trackers: bad as unknown as typeof trackers });
    const ev = await until(events, (e) => e.type === "error");
    assert.ok(ev.type === "error" && ev.error instanceof OutOfRangeError);
    assert.deepEqual([ev.error.field, ev.error.refSeq, ev.error.fatal], ["trackers[0]", 77, false]);
    assert.equal(ada.state, "joined");
    await ada.close();
  });

  test("a server restart is survived: SERVER_SHUTDOWN, back-off, resume", async () => {
    const own = await startServer();
    let next: RunningServer | undefined;
    const ada = await connect(own.url, mintToken(own.secret, { room: "r", player: "ada" }), OPTS);
    try {
      await ada.join("r", "Ada");
      const events = ada.events();
      const stop = stream(ada, 0);
      try {
        const before = await until(events, (ev) => ev.type === "pose");
        await own.stop();
        const rec = await until(events, (ev) => ev.type === "reconnecting");
        assert.ok(rec.type === "reconnecting" && rec.cause.code === "SERVER_SHUTDOWN");
        next = await startServer({ port: own.port, secret: own.secret });
        const resumed = await until(events, (ev) => ev.type === "welcome", 20);
        assert.ok(resumed.type === "welcome" && resumed.resumed && resumed.welcome.player === "ada");
        const pose = await until(events, (ev) => ev.type === "pose");
        assert.ok(before.type === "pose" && pose.type === "pose" && pose.seq > before.seq, "seq goes on");
      } finally {
        stop();
      }
      await ada.close();
    } finally {
      await own.stop();
      await next?.stop();
    }
  });
});
