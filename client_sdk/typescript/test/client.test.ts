/**
 * PosecastClient against a scripted in-process server (the `ws` package): join,
 * events, clock sync, typed refusals, and reconnect with back-off and resume. The
 * real server is in integration.test.ts.
 */

import assert from "node:assert/strict";
import { once } from "node:events";
import type { AddressInfo } from "node:net";
import { test } from "node:test";

import WebSocket, { WebSocketServer, type WebSocket as ServerSocket } from "ws";

import { connect, type ConnectOptions, PosecastClient, type WebSocketConstructor } from "../src/client.js";
import { decode, encode } from "../src/codec.js";
import { checkUrl } from "../src/dial.js";
import {
  ConfigInvalidError,
  ConnectFailedError,
  ConnectionClosedError,
  ForbiddenError,
  KickedError,
  NotNormalisedError,
  OutOfRangeError,
  TokenProviderError,
  UnauthenticatedError,
} from "../src/errors.js";
import type { ClientEvent } from "../src/events.js";
import {
  DEFAULT_LIMITS,
  type Hello,
  type Message,
  type Role,
  SUBPROTOCOL,
  type Welcome,
} from "../src/messages.js";

interface Peer {
  ws: ServerSocket;
  hello: Hello;
  received: Message[];
  send(msg: Message): void;
}

/** A server that answers hello with welcome (or `refuse`), pings with pongs (+100 s). */
class FakeServer {
  readonly peers: Peer[] = [];
  refuse: { code: string; fatal: boolean } | undefined;
  role: Role = "player";
  private readonly wss: WebSocketServer;
  private readonly waiters: (() => void)[] = [];

  constructor(port = 0) {
    this.wss = new WebSocketServer({
      port,
      host: "127.0.0.1",
      handleProtocols: (offered) => (offered.has(SUBPROTOCOL) ? SUBPROTOCOL : false),
    });
    this.wss.on("connection", (ws) => this.accept(ws));
  }

  async ready(): Promise<this> {
    await once(this.wss, "listening");
    return this;
  }

  get port(): number {
    return (this.wss.address() as AddressInfo).port;
  }

  get url(): string {
    return `ws://127.0.0.1:${this.port}/`;
  }

  /** Resolves once `n` peers have said hello. */
  async peer(n: number): Promise<Peer> {
    while (this.peers.length < n) await new Promise<void>((r) => this.waiters.push(r));
    return this.peers[n - 1]!;
  }

  async close(): Promise<void> {
    for (const c of this.wss.clients) c.terminate();
    await new Promise((r) => this.wss.close(r));
  }

  private accept(ws: ServerSocket): void {
    const received: Message[] = [];
    ws.on("message", (data: Buffer) => {
      const msg = decode(new Uint8Array(data));
      received.push(msg);
      const send = (m: Message): void => ws.send(encode(m));
      if (msg.type === "hello") {
        if (this.refuse !== undefined) {
          send({ type: "error", code: this.refuse.code, message: "refused", fatal: this.refuse.fatal });
          ws.close(1008, this.refuse.code);
          return;
        }
        const n = this.peers.length + 1;
        send(welcome(`p${n}`, msg.room, this.role));
        this.peers.push({ ws, hello: msg, received, send });
        this.waiters.splice(0).forEach((w) => w());
      } else if (msg.type === "ping") {
        send({ type: "pong", t0: msg.t0, t1: msg.t0 + 100.01, t2: msg.t0 + 100.01 }); // no hold: the test clock stands still
      } else if (msg.type === "bye") {
        send({ type: "bye", reason: "bye" });
        ws.close(1000);
      }
    });
  }
}

function welcome(player: string, room: string, role: Role): Welcome {
  return {
    type: "welcome", version: 1, player, session: "s1", role, room, t: 50, rate_hz: 60,
    lookahead_frames: 10, members: [{ player, name: "Ada" }], limits: DEFAULT_LIMITS,
  };
}

const positions = (x: number): Float64Array => Float64Array.from({ length: 57 }, (_, i) => (i % 3 === 0 ? x : 1));
const FAST: ConnectOptions = {
  WebSocket, timeoutS: 2, random: () => 0.999,
  reconnect: { initialDelayS: 0.05, maxDelayS: 0.2, maxAttempts: 4 },
};

async function take(it: AsyncIterator<ClientEvent>, type: ClientEvent["type"]): Promise<ClientEvent> {
  for (;;) {
    const r = await it.next();
    assert.ok(!r.done, `stream ended while waiting for ${type}`);
    if (r.value.type === type) return r.value;
  }
}

test("join, frames out, poses and presence in, clock synced, bye on close", async () => {
  const server = await new FakeServer().ready();
  try {
    let now = 5;
    const client = await connect(server.url, "tok", { ...FAST, clock: () => now });
    const w = await client.join("lobby", "Ada", "hmd3+waist", { rateHz: 72 });
    assert.equal(w.player, "p1");
    const peer = await server.peer(1);
    assert.deepEqual(
      [peer.hello.token, peer.hello.room, peer.hello.name, peer.hello.layout, peer.hello.rate_hz],
      ["tok", "lobby", "Ada", undefined, 72], // hmd3+waist is the default: left out
    );
    const at = { position: [0, 1.6, 0], orientation: [0, 0, 0, 1] } as const;
    assert.equal(client.sendFrame({ head: at, waist: at }), 0);
    assert.equal(client.sendFrame({ head: at, waist: at, t: 7.5 }), 1);
    assert.throws(() => client.sendFrame({ head: at, t: 7 }), RangeError); // time went back
    // No t after a stamp ahead of the clock (a WebXR predictedDisplayTime): the last t, not now (5).
    assert.equal(client.sendFrame({ head: at, waist: at }), 2);
    const nan = { position: [0, Number.NaN, 0], orientation: [0, 0, 0, 1] } as const;
    assert.throws(() => client.sendFrame({ head: at, waist: nan, t: 8 }), (e: unknown) =>
      e instanceof OutOfRangeError && e.field === "trackers[3]");
    const zero = { position: [0, 1, 0], orientation: [0, 0, 0, 0] } as const;
    assert.throws(() => client.sendFrame({ leftHand: zero, t: 8 }), NotNormalisedError);
    const tilted = { position: [0, 1, 0], orientation: [0, 0, 0, 2] } as const;
    client.calibrate({ heightM: 1.8 });
    peer.send({ type: "presence", event: "join", room: "lobby", player: "p9", name: "Bob" });
    peer.send({ type: "pose", player: "p9", seq: 3, t: 51, positions: positions(2) });
    const it = client.events();
    assert.equal((await take(it, "welcome")).type, "welcome");
    const presence = await take(it, "presence");
    assert.equal(presence.type === "presence" && presence.name, "Bob");
    const pose = await take(it, "pose");
    assert.ok(pose.type === "pose" && pose.player === "p9" && pose.positions[0] === 2);
    assert.deepEqual([...client.members.keys()], ["p1", "p9"]);
    assert.equal(client.poses.get("p9")?.seq, 3);
    peer.send({ type: "error", code: "RATE_LIMITED", message: "slow down", fatal: false });
    const err = await take(it, "error");
    assert.ok(err.type === "error" && err.error.code === "RATE_LIMITED");
    assert.equal(client.sendFrame({ rightHand: tilted, t: 9 }), 3); // normalised, not refused
    await sleep(0.05);
    const frames = peer.received.filter((m) => m.type === "frame");
    assert.deepEqual(frames.map((f) => [f.seq, f.t, f.valid]), [[0, 5, 0b1001], [1, 7.5, 0b1001], [2, 7.5, 0b1001], [3, 9, 0b0100]]);
    const third = frames[3]!;
    assert.ok("trackers" in third);
    assert.deepEqual(third.trackers[2], [0, 1, 0, 0, 0, 0, 1]);
    assert.ok(peer.received.some((m) => m.type === "calibrate" && "height_m" in m && m.height_m === 1.8));
    // The first pings go out at once; the fake server's clock runs 100 s ahead.
    for (let i = 0; i < 50 && client.clock.offsetS === undefined; i++) await sleep(0.01);
    assert.ok(Math.abs(client.clock.offsetS! - 100.01) < 1e-9);
    now = 6;
    await client.close();
    assert.equal(client.state, "closed");
    assert.equal(peer.received.at(-1)?.type, "bye");
    assert.equal((await it.next()).done, true);
  } finally {
    await server.close();
  }
});

test("a refused hello rejects join with the typed error and closes the client", async () => {
  const server = await new FakeServer().ready();
  try {
    server.refuse = { code: "UNAUTHENTICATED", fatal: true };
    const client = await connect(server.url, "forged", FAST);
    await assert.rejects(client.join("lobby", "Ada"), UnauthenticatedError);
    assert.equal(client.state, "closed");
    assert.equal(client.sendFrame({}), undefined);
  } finally {
    await server.close();
  }
});

test("connect fails with ConnectFailedError, naming the URL, when nobody listens", async () => {
  const server = await new FakeServer().ready();
  const url = server.url;
  await server.close(); // a port bound a moment ago, now refused
  await assert.rejects(connect(url, "tok", FAST), (err: unknown) => {
    assert.ok(err instanceof ConnectFailedError && err instanceof ConnectionClosedError);
    assert.equal(err.code, "CONNECTION_CLOSED"); // what reconnects retry
    assert.equal(err.url, url);
    assert.ok(err.message.startsWith(`could not connect to ${url}: connection refused`), err.message);
    assert.ok(err.hint.includes("posecast serve --dev") && err.message.includes(err.hint));
    assert.equal((err.cause as { code?: string } | undefined)?.code, "ECONNREFUSED");
    return true;
  });
});

test("an HTTP refusal of the upgrade is a ConnectFailedError with its status", async () => {
  for (const status of [429, 503, 404]) {
    const wss = new WebSocketServer({
      port: 0,
      host: "127.0.0.1",
      verifyClient: (_info, done) => done(false, status, "too many connection attempts"),
    });
    await once(wss, "listening");
    try {
      const url = `ws://127.0.0.1:${(wss.address() as AddressInfo).port}/`;
      await assert.rejects(connect(url, "tok", FAST), (err: unknown) => {
        assert.ok(err instanceof ConnectFailedError, String(err));
        assert.equal(err.status, status);
        assert.ok(err.message.includes(`HTTP ${status}`), err.message);
        assert.ok(err.hint.includes(status === 404 ? "endpoint" : "back"), err.hint);
        return true;
      });
    } finally {
      await new Promise((r) => wss.close(r));
    }
  }
});

/** A WebSocket class that counts how often it is made (dialing). */
function countingWebSocket(): { made: string[]; WebSocket: WebSocketConstructor } {
  const made: string[] = [];
  class Counting extends WebSocket {
    constructor(url: string, protocols?: string[]) {
      made.push(url);
      super(url, protocols);
    }
  }
  return { made, WebSocket: Counting };
}

test("a URL the client cannot dial is a ConfigInvalidError before dialing", async () => {
  const cases: [unknown, string][] = [
    ["http://127.0.0.1:8765/", "use ws://127.0.0.1:8765/"],
    ["https://posecast.example/v1", "use wss://posecast.example/v1"],
    ["localhost:8765", "did you mean ws://localhost:8765/?"],
    ["127.0.0.1:8765", "did you mean ws://127.0.0.1:8765/?"],
    ["ftp://127.0.0.1/", "not a WebSocket URL"],
    ["ws://", "names no host"],
    ["ws://127.0.0.1:99999/", "bad port"],
    ["ws://127.0.0.1:0/", "bad port (0)"],
    ["ws://[::1", "bad port"],
    ["ws://127.0.0.1:8765/#room", "#fragment"],
    ["", "no server URL (got an empty string)"],
    [undefined, "no server URL (got undefined)"], // process.env of an unset variable
  ];
  const { made, WebSocket: Counting } = countingWebSocket();
  for (const [url, words] of cases) {
    await assert.rejects(connect(url as string, "tok", { ...FAST, WebSocket: Counting }), (err: unknown) => {
      assert.ok(err instanceof ConfigInvalidError, `${String(url)}: ${String(err)}`);
      assert.equal(err.code, "CONFIG_INVALID");
      assert.ok(err.message.includes(words) && err.message.endsWith(`(hint: ${err.hint})`), err.message);
      return true;
    });
  }
  assert.deepEqual(made, []);
});

test("good URLs are taken, whitespace around them dropped (a regression refusing them fails here)", () => {
  const cases: [string, string][] = [
    ["ws://[::1]:8765/", "ws://[::1]:8765/"], // an IPv6 literal
    ["wss://[2001:db8::1]/posecast", "wss://[2001:db8::1]/posecast"],
    ["ws://127.0.0.1:8765/rooms/lobby?x=1&y=two", "ws://127.0.0.1:8765/rooms/lobby?x=1&y=two"],
    ["WS://127.0.0.1:8765/", "WS://127.0.0.1:8765/"], // schemes are case-insensitive
    ["Wss://posecast.example/", "Wss://posecast.example/"],
    ["ws://bücher.example:8765/", "ws://bücher.example:8765/"], // a unicode host
    ["ws://localhost:65535/", "ws://localhost:65535/"],
    ["ws://h:1/", "ws://h:1/"],
    ["ws://user:pw@h/", "ws://user:pw@h/"],
    ["ws://h:8765/ ", "ws://h:8765/"],
    ["\t ws://h:8765/\n", "ws://h:8765/"],
  ];
  for (const [url, kept] of cases) {
    assert.equal(checkUrl(url), kept, url);
    assert.equal(new PosecastClient(url, "tok", FAST).url, kept, url);
  }
});

test("the client dials the URL without the whitespace around it", async () => {
  const server = await new FakeServer().ready();
  try {
    const { made, WebSocket: Counting } = countingWebSocket();
    const client = await connect(` ${server.url} `, "tok", { ...FAST, WebSocket: Counting });
    assert.deepEqual(made, [server.url]);
    assert.equal(client.url, server.url);
    await client.close();
  } finally {
    await server.close();
  }
});

test("a token that is neither a string nor a function is a ConfigInvalidError before dialing", async () => {
  const { made, WebSocket: Counting } = countingWebSocket();
  const cases: [unknown, string][] = [
    [undefined, "no token (got undefined)"], // process.env.POSECAST_TOKEN, unset
    [null, "no token (got null)"],
    ["", "no token (got an empty string)"],
    [" ", "no token (got a blank string)"],
    [42, "no token (got a value of type number)"],
  ];
  for (const [token, words] of cases) {
    await assert.rejects(
      connect("ws://127.0.0.1:8765/", token as string, { ...FAST, WebSocket: Counting }),
      (err: unknown) => {
        assert.ok(err instanceof ConfigInvalidError && err.message.includes(words), String(err));
        assert.ok(err.hint.includes("unset environment variable"));
        return true;
      },
    );
  }
  assert.deepEqual(made, []);
});

test("a token function that returns no token fails the join with ConfigInvalidError", async () => {
  const server = await new FakeServer().ready();
  try {
    const client = await connect(server.url, (() => undefined) as unknown as () => string, FAST);
    await assert.rejects(client.join("lobby", "Ada"), (err: unknown) => {
      assert.ok(err instanceof ConfigInvalidError, String(err));
      assert.ok(err.message.includes("the token function returned undefined"));
      return true;
    });
    assert.equal(server.peers.length, 0); // no hello went out
    assert.equal(client.state, "closed");
  } finally {
    await server.close();
  }
});

test("a lost connection is resumed: back-off, a fresh token, hello again, seq goes on", async () => {
  const server = await new FakeServer().ready();
  try {
    let tokens = 0;
    const client = await connect(server.url, () => `tok${++tokens}`, FAST);
    await client.join("lobby", "Ada");
    const it = client.events();
    await take(it, "welcome");
    const at = { position: [0, 1, 0], orientation: [0, 0, 0, 1] } as const;
    client.sendFrame({ head: at });
    client.sendFrame({ head: at });
    (await server.peer(1)).ws.terminate(); // the network goes away: no close frame
    const rec = await take(it, "reconnecting");
    assert.ok(rec.type === "reconnecting" && rec.attempt === 1 && rec.cause instanceof ConnectionClosedError);
    assert.ok(Math.abs(rec.delayS - 0.05 * 0.999) < 1e-9);
    assert.equal(client.sendFrame({ head: at }), undefined); // dropped while away
    const resumed = await take(it, "welcome");
    assert.ok(resumed.type === "welcome" && resumed.resumed && resumed.welcome.player === "p2");
    const peer = await server.peer(2);
    assert.equal(peer.hello.token, "tok2");
    assert.equal(peer.hello.room, "lobby");
    assert.equal(client.sendFrame({ head: at }), 3); // 2 was dropped while away
    assert.equal(client.state, "joined");
    await client.close();
  } finally {
    await server.close();
  }
});

test("SERVER_SHUTDOWN is resumed on the next server; back-off grows until it is up", async () => {
  const first = await new FakeServer().ready();
  const port = first.port;
  const client = await connect(first.url, "tok", FAST);
  await client.join("lobby", "Ada");
  const it = client.events();
  await take(it, "welcome");
  const peer = await first.peer(1);
  peer.send({ type: "bye", reason: "SERVER_SHUTDOWN" });
  await sleep(0.01);
  await first.close();
  const delays: number[] = [];
  for (let i = 0; i < 2; i++) {
    const rec = await take(it, "reconnecting");
    assert.ok(rec.type === "reconnecting");
    delays.push(rec.delayS);
    if (i === 0) assert.equal(rec.cause.code, "SERVER_SHUTDOWN");
  }
  assert.ok(delays[1]! > delays[0]! * 1.9, `${delays}`);
  const second = await new FakeServer(port).ready();
  try {
    const resumed = await take(it, "welcome");
    assert.ok(resumed.type === "welcome" && resumed.resumed);
    await client.close();
  } finally {
    await second.close();
  }
});

test("KICKED ends the stream with KickedError; no reconnect", async () => {
  const server = await new FakeServer().ready();
  try {
    const client = await connect(server.url, "tok", FAST);
    await client.join("lobby", "Ada");
    const peer = await server.peer(1);
    peer.send({ type: "error", code: "KICKED", message: "be nice", fatal: true });
    peer.ws.close(1008, "KICKED");
    const seen: string[] = [];
    await assert.rejects(async () => {
      for await (const ev of client) seen.push(ev.type);
    }, (err: unknown) => err instanceof KickedError && err.message === "be nice");
    assert.deepEqual(seen, ["welcome"]);
    assert.equal(client.state, "closed");
    assert.equal(server.peers.length, 1);
  } finally {
    await server.close();
  }
});

test("giving up after maxAttempts throws the last cause", async () => {
  const server = await new FakeServer().ready();
  const url = server.url;
  const client = await connect(url, "tok", FAST);
  await client.join("lobby", "Ada");
  await server.close();
  const attempts: number[] = [];
  const causes: unknown[] = [];
  await assert.rejects(async () => {
    for await (const ev of client) {
      if (ev.type === "reconnecting") {
        attempts.push(ev.attempt);
        causes.push(ev.cause);
      }
    }
  }, ConnectFailedError); // the last attempt's: the server's port refuses
  assert.deepEqual(attempts, [1, 2, 3, 4]);
  assert.ok(!(causes[0] instanceof ConnectFailedError)); // the drop itself
  assert.ok(causes.slice(1).every((c) => c instanceof ConnectFailedError && c.url === url));
});

test("a token function that throws is retried on a rejoin (TokenProviderError), then works", async () => {
  const server = await new FakeServer().ready();
  try {
    let calls = 0;
    const token = (): string => {
      calls++;
      if (calls === 2 || calls === 3) throw new Error("token endpoint: HTTP 503"); // the first rejoin's two tries
      return `tok${calls}`;
    };
    const client = await connect(server.url, token, FAST);
    await client.join("lobby", "Ada");
    const it = client.events();
    await take(it, "welcome");
    (await server.peer(1)).ws.terminate();
    const causes: unknown[] = [];
    for (;;) {
      const ev = (await it.next()).value as ClientEvent;
      if (ev.type === "reconnecting") causes.push(ev.cause);
      if (ev.type === "welcome") {
        assert.ok(ev.resumed);
        break;
      }
    }
    assert.equal(calls, 4);
    assert.ok(causes[0] instanceof ConnectionClosedError);
    assert.ok(causes.slice(1).every((c) => c instanceof TokenProviderError), String(causes));
    const e = causes[1] as TokenProviderError;
    assert.equal(e.code, "TOKEN_PROVIDER_FAILED");
    assert.ok(e.cause instanceof Error && e.message.includes("HTTP 503"), e.message);
    assert.equal((await server.peer(2)).hello.token, "tok4");
    await client.close();
  } finally {
    await server.close();
  }
});

test("a token function that keeps throwing gives up with TokenProviderError; the first join rejects with it", async () => {
  const server = await new FakeServer().ready();
  try {
    let calls = 0;
    const token = async (): Promise<string> => {
      calls++;
      if (calls > 1) throw new Error("token endpoint down");
      return "tok";
    };
    const client = await connect(server.url, token, FAST);
    await client.join("lobby", "Ada");
    (await server.peer(1)).ws.terminate();
    await assert.rejects(async () => {
      for await (const _ of client) {
        // drain
      }
    }, (err: unknown) => err instanceof TokenProviderError && err.cause instanceof Error);
    assert.equal(calls, 1 + 4); // FAST: maxAttempts 4
    const first = await connect(server.url, () => {
      throw new TypeError("no session cookie");
    }, FAST);
    await assert.rejects(first.join("lobby", "Bea"), (err: unknown) => {
      assert.ok(err instanceof TokenProviderError && err.cause instanceof TypeError, String(err));
      assert.ok(err.message.includes("TypeError: no session cookie"), err.message);
      return true;
    });
  } finally {
    await server.close();
  }
});

test("spectators may not send frames; a missing WebSocket class is explained", async () => {
  const server = await new FakeServer().ready();
  try {
    server.role = "spectator";
    const client = await connect(server.url, "tok", FAST);
    await client.join("lobby", "Watcher");
    assert.throws(() => client.sendFrame({}), ForbiddenError);
    await client.close();
  } finally {
    await server.close();
  }
  const g = globalThis as { WebSocket?: unknown };
  const saved = g.WebSocket;
  delete g.WebSocket;
  try {
    assert.throws(() => new PosecastClient("ws://x/", "t"), /pass \{ WebSocket \} from the 'ws'/);
  } finally {
    if (saved !== undefined) g.WebSocket = saved;
  }
});

function sleep(s: number): Promise<void> {
  return new Promise((r) => setTimeout(r, s * 1000));
}
