/**
 * PosecastClient on protocol v2 against a scripted in-process server (the `ws` package):
 * negotiation (v2 offered first, v1 fallback), poses messages from the proto stream
 * vectors turned into pose events (FK positions, world and local rotations), a bad
 * record answered with an error event and a `resync`, and pose rates. The real server
 * is in integration.test.ts.
 */

import assert from "node:assert/strict";
import { once } from "node:events";
import { readFileSync } from "node:fs";
import type { AddressInfo } from "node:net";
import { join } from "node:path";
import { test } from "node:test";

import WebSocket, { WebSocketServer, type WebSocket as ServerSocket } from "ws";

import { connect, type ConnectOptions } from "../src/client.js";
import { decode, encode } from "../src/codec.js";
import { OutOfRangeError } from "../src/errors.js";
import type { ClientEvent } from "../src/events.js";
import { DEFAULT_LIMITS, type Member, type Message, SUBPROTOCOL, SUBPROTOCOL_V2 } from "../src/messages.js";
import { items2world } from "../src/records.js";
import { fromHex, repoRoot } from "./helpers.js";

interface StreamCase {
  // The vector file's keys, as in proto/vectors: `handle` is the avatar id.
  name: string;
  avatars: { handle: number; player: string; skeleton: { $bin: string } }[];
  messages: string[];
  expect: {
    handle: number;
    seq: number;
    keyframe: boolean;
    reach_limited: boolean;
    root: number[];
    items: number[][];
    positions: number[][];
  }[][];
  tolerance: number;
}

const STREAMS = new Map(
  (JSON.parse(readFileSync(join(repoRoot(), "proto", "vectors", "poses.json"), "utf8")) as StreamCase[])
    .filter((c) => "messages" in c)
    .map((c) => [c.name, c]),
);

/** A server that selects `pick` among the offered subprotocols and answers hello. */
class ScriptedServer {
  readonly received: Message[] = [];
  version = 0;
  private ws: ServerSocket | undefined;
  private readonly wss: WebSocketServer;

  constructor(
    pick: string,
    private readonly members: Member[],
  ) {
    this.wss = new WebSocketServer({
      port: 0,
      host: "127.0.0.1",
      handleProtocols: (offered) => (offered.has(pick) ? pick : false),
    });
    this.wss.on("connection", (ws) => {
      this.ws = ws;
      this.version = ws.protocol === SUBPROTOCOL_V2 ? 2 : 1;
      ws.on("message", (data: Buffer) => {
        const msg = decode(new Uint8Array(data), { version: this.version });
        this.received.push(msg);
        if (msg.type === "hello") {
          const v2 = this.version === 2;
          this.send({
            type: "welcome", version: this.version, player: "p1", session: "s1", role: "spectator",
            room: msg.room, t: 50, rate_hz: 60, lookahead_frames: 10,
            members: v2 ? this.members : this.members.map((m) => ({ player: m.player, name: m.name })),
            limits: DEFAULT_LIMITS, ...(v2 ? { pose_rate_hz: msg.pose_rate_hz ?? 60 } : {}),
          });
        }
      });
    });
  }

  async ready(): Promise<this> {
    await once(this.wss, "listening");
    return this;
  }

  get url(): string {
    return `ws://127.0.0.1:${(this.wss.address() as AddressInfo).port}/`;
  }

  send(msg: Message): void {
    this.ws!.send(encode(msg));
  }

  sendRaw(bytes: Uint8Array): void {
    this.ws!.send(bytes);
  }

  async close(): Promise<void> {
    for (const c of this.wss.clients) c.terminate();
    await new Promise((r) => this.wss.close(r));
  }
}

const OPTIONS: ConnectOptions = { WebSocket, timeoutS: 2, reconnect: false, pingIntervalS: 0 };
const sleep = (s: number): Promise<void> => new Promise((r) => setTimeout(r, s * 1000));

async function until(what: string, ok: () => boolean): Promise<void> {
  for (let i = 0; i < 200 && !ok(); i++) await sleep(0.01);
  assert.ok(ok(), `timed out waiting for ${what}`);
}

function membersOf(c: StreamCase): Member[] {
  return c.avatars.map((a) => ({ player: a.player, name: a.player, avatarId: a.handle, skeleton: fromHex(a.skeleton.$bin) }));
}

function assertClose(actual: ArrayLike<number>, expected: readonly number[], tol: number, what: string): void {
  assert.equal(actual.length, expected.length, what);
  for (let i = 0; i < expected.length; i++) {
    assert.ok(Math.abs(actual[i]! - expected[i]!) <= tol, `${what}[${i}]: ${actual[i]} vs ${expected[i]}`);
  }
}

test("v2: poses messages become pose events with FK positions, world and local rotations", async () => {
  const stream = STREAMS.get("poses_stream_two_avatars")!;
  const server = await new ScriptedServer(SUBPROTOCOL_V2, membersOf(stream)).ready();
  try {
    const client = await connect(server.url, "tok", OPTIONS);
    assert.equal(client.version, 2);
    const welcome = await client.join("lobby", "Ada", undefined, { poseRateHz: 30 });
    assert.equal(welcome.pose_rate_hz, 30);
    const hello = server.received.find((m) => m.type === "hello");
    assert.ok(hello?.type === "hello" && hello.version === 2 && hello.pose_rate_hz === 30);
    const playerOf = new Map(stream.avatars.map((a) => [a.handle, a.player]));
    let records = 0;
    for (const [k, hex] of stream.messages.entries()) {
      server.sendRaw(fromHex(hex));
      const expected = stream.expect[k]!;
      records += expected.length;
      const last = new Map(expected.map((e) => [playerOf.get(e.handle)!, e]));
      await until(`message ${k}`, () => [...last].every(([p, e]) => client.poses.get(p)?.seq === e.seq));
      for (const [player, e] of last) {
        const pose = client.poses.get(player)!;
        const at = `message ${k} ${player}`;
        assert.deepEqual([pose.keyframe, pose.reachLimited], [e.keyframe, e.reach_limited], at);
        assertClose(pose.positions, e.positions.flat(), stream.tolerance, `${at} positions`);
        assertClose(pose.localRotations!, e.items.flat(), stream.tolerance, `${at} local`);
        assertClose(pose.rotations!, [...items2world(e.items.flat())], 1e-9, `${at} world`);
      }
    }
    assert.ok(records >= 8, `only ${records} records`);
    assert.equal(client.badRecords, 0);
    assert.equal(client.skeletonOf("p-3")?.length, 57);
    await client.close();
  } finally {
    await server.close();
  }
});

test("v2: a record that cannot be applied is an error event and a resync, never a throw", async () => {
  const stream = STREAMS.get("poses_stream_delta_first")!;
  const server = await new ScriptedServer(SUBPROTOCOL_V2, membersOf(stream)).ready();
  try {
    const client = await connect(server.url, "tok", OPTIONS);
    await client.join("lobby", "Ada");
    const it = client.events();
    for (const hex of stream.messages) server.sendRaw(fromHex(hex));
    let ev: ClientEvent;
    do ev = (await it.next()).value as ClientEvent;
    while (ev.type !== "error");
    assert.equal(ev.error.code, "BAD_FIELD");
    assert.equal(ev.error.field, "data");
    await until("resync", () => server.received.some((m) => m.type === "resync"));
    assert.equal(client.badRecords, 1);
    // A presence join announces an avatar id; a skeleton for it is kept; leave forgets it.
    const skel = membersOf(stream)[0]!.skeleton!;
    server.send({ type: "presence", event: "join", room: "lobby", player: "p-9", name: "Bob", avatarId: 9, skeleton: skel });
    await until("join", () => client.members.get("p-9")?.avatarId === 9);
    assert.equal(client.skeletonOf("p-9")?.length, 57);
    server.send({ type: "presence", event: "leave", room: "lobby", player: "p-9", name: "Bob" });
    await until("leave", () => client.skeletonOf("p-9") === undefined);
    // Pose rates: sent as pose_rate; another number is refused before anything is sent.
    assert.equal(client.setPoseRate(15), true);
    assert.throws(() => client.setPoseRate(45), OutOfRangeError);
    await until("pose_rate", () => server.received.some((m) => m.type === "pose_rate" && m.rate_hz === 15));
    assert.equal(server.received.filter((m) => m.type === "pose_rate").length, 1);
    assert.equal(client.resync(), true);
    await client.close();
  } finally {
    await server.close();
  }
});

test("v2: a forecast asked at join and changed later; out of range is refused before sending", async () => {
  const server = await new ScriptedServer(SUBPROTOCOL_V2, []).ready();
  try {
    const client = await connect(server.url, "tok", OPTIONS);
    await assert.rejects(client.join("lobby", "Ada", undefined, { forecastMs: 150 }), OutOfRangeError);
    assert.equal(server.received.filter((m) => m.type === "hello").length, 0);
    await client.close();
    const again = await connect(server.url, "tok", OPTIONS);
    await again.join("lobby", "Ada", undefined, { forecastMs: 67 });
    const hello = server.received.find((m) => m.type === "hello");
    assert.ok(hello?.type === "hello" && hello.forecast_ms === 67);
    for (const bad of [-1, 100.5, Number.NaN]) assert.throws(() => again.setForecast(bad), OutOfRangeError);
    assert.equal(again.setForecast(33), true);
    assert.equal(again.setForecast(0), true);
    await until("forecast", () => server.received.filter((m) => m.type === "forecast").length === 2);
    const sent = server.received.filter((m) => m.type === "forecast").map((m) => (m.type === "forecast" ? m.ms : -1));
    assert.deepEqual(sent, [33, 0]);
    await again.close();
  } finally {
    await server.close();
  }
});

test("v2: after a bad record every reference is dropped, so no later delta decodes against a stale one", async () => {
  // The records the client skipped moved the server's references on: a delta after them
  // is refused (BAD_FIELD) until the resync's keyframes, never shown as a wrong pose.
  const stream = STREAMS.get("poses_stream_two_avatars")!;
  const server = await new ScriptedServer(SUBPROTOCOL_V2, membersOf(stream)).ready();
  try {
    const client = await connect(server.url, "tok", OPTIONS);
    await client.join("lobby", "Ada");
    const first = fromHex(stream.messages[0]!);
    const msg = decode(first, { version: 2 });
    assert.ok(msg.type === "poses");
    server.send({ ...msg, data: Uint8Array.from([...msg.data, 0x7f, 0x01]) }); // avatar id 127: bad
    await until("the bad record", () => client.badRecords === 1);
    const seqs = new Map([...client.poses].map(([p, pose]) => [p, pose.seq]));
    server.sendRaw(fromHex(stream.messages[1]!)); // deltas against the first message's state
    await until("the refused deltas", () => client.badRecords === 2);
    assert.deepEqual(new Map([...client.poses].map(([p, pose]) => [p, pose.seq])), seqs);
    await until("resync", () => server.received.some((m) => m.type === "resync"));
    await client.close();
  } finally {
    await server.close();
  }
});

test("v1 fallback: a server that selects posecast.v1 gets a v1 hello, and no pose rates", async () => {
  const server = await new ScriptedServer(SUBPROTOCOL, [{ player: "p1", name: "Ada" }]).ready();
  try {
    const client = await connect(server.url, "tok", OPTIONS);
    assert.equal(client.version, 1);
    await client.join("lobby", "Ada", undefined, { poseRateHz: 30 });
    const hello = server.received.find((m) => m.type === "hello");
    assert.ok(hello?.type === "hello" && hello.version === 1 && hello.pose_rate_hz === undefined);
    assert.equal(client.setPoseRate(30), false);
    assert.equal(client.resync(), false);
    await client.close();
  } finally {
    await server.close();
  }
});

test("protocol: 1 offers posecast.v1 alone", async () => {
  const server = await new ScriptedServer(SUBPROTOCOL_V2, []).ready();
  try {
    // The server wants v2 only, and the client offers only v1: the handshake fails.
    await assert.rejects(connect(server.url, "tok", { ...OPTIONS, protocol: 1 }));
  } finally {
    await server.close();
  }
});
