/**
 * socket.ts with a scripted WebSocket class (no network): the subprotocol check, the
 * handshake timeout, a class that refuses the URL, a refused dial, and the bytes of a
 * message. Real sockets are in client.test.ts.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { ConfigInvalidError, ConnectFailedError, ConnectionClosedError } from "../src/errors.js";
import { bytesOf, dialSocket, type SocketHandlers, type WebSocketLike } from "../src/socket.js";

/** A socket the test opens, closes and feeds by hand; the last one made is `Scripted.last`. */
class Scripted implements WebSocketLike {
  static last: Scripted | undefined;
  binaryType = "blob";
  readyState = 0;
  protocol = "";
  readonly closes: (number | undefined)[] = [];
  onopen: ((ev: unknown) => void) | null = null;
  onmessage: ((ev: { readonly data: unknown }) => void) | null = null;
  onclose: ((ev: { readonly code: number; readonly reason: string }) => void) | null = null;
  onerror: ((ev: unknown) => void) | null = null;

  constructor(
    readonly url: string,
    readonly protocols?: string[],
  ) {
    Scripted.last = this;
  }

  send(): void {}

  close(code?: number): void {
    this.closes.push(code);
  }

  open(protocol: string): void {
    this.protocol = protocol;
    this.readyState = 1;
    this.onopen?.({});
  }
}

function recorder(): { log: string[]; handlers: SocketHandlers } {
  const log: string[] = [];
  return {
    log,
    handlers: {
      opened: (p) => log.push(`opened ${p}`),
      data: (d) => log.push(`data ${String(d)}`),
      closed: (code, reason) => log.push(`closed ${code} ${reason}`),
    },
  };
}

test("an open socket with an offered subprotocol: opened before it resolves, then data and close", async () => {
  const { log, handlers } = recorder();
  const { ws, open } = dialSocket(Scripted, "ws://h/", ["posecast.v2", "posecast.v1"], 5, handlers);
  const s = Scripted.last!;
  assert.equal(ws, s);
  assert.deepEqual(s.protocols, ["posecast.v2", "posecast.v1"]);
  assert.equal(s.binaryType, "arraybuffer");
  s.open("posecast.v1");
  assert.deepEqual(log, ["opened posecast.v1"]); // synchronously, before any message
  assert.equal(await open, s);
  s.onmessage!({ data: "x" });
  s.onclose!({ code: 1001, reason: "going away" });
  assert.deepEqual(log, ["opened posecast.v1", "data x", "closed 1001 going away"]);
});

test("a server that selects no offered subprotocol is closed with 1002", async () => {
  const { log, handlers } = recorder();
  const { open } = dialSocket(Scripted, "ws://h/", ["posecast.v2"], 5, handlers);
  Scripted.last!.open("chat");
  await assert.rejects(open, (err: unknown) => {
    assert.ok(err instanceof ConnectionClosedError && !(err instanceof ConnectFailedError), String(err));
    assert.equal(err.closeCode, 1002);
    assert.ok(err.message.includes("did not select posecast.v2"));
    return true;
  });
  assert.deepEqual(Scripted.last!.closes, [1002]);
  assert.deepEqual(log, []);
});

test("no handshake in time, a dial refused, a URL the class refuses", async () => {
  const { handlers } = recorder();
  const slow = dialSocket(Scripted, "ws://h/", ["posecast.v2"], 0.02, handlers);
  await assert.rejects(slow.open, (err: unknown) => err instanceof ConnectFailedError && err.reason.includes("no WebSocket handshake within 0.02 s"));
  assert.deepEqual(Scripted.last!.closes, [undefined]);

  const refused = dialSocket(Scripted, "ws://h/", ["posecast.v2"], 5, handlers);
  Scripted.last!.onerror!({ error: { code: "ECONNREFUSED" } });
  Scripted.last!.onclose!({ code: 1006, reason: "" });
  await assert.rejects(refused.open, (err: unknown) => err instanceof ConnectFailedError && err.reason.startsWith("connection refused"));

  class Refusing extends Scripted {
    constructor(url: string) {
      super(url);
      throw new Error("insecure");
    }
  }
  assert.throws(
    () => dialSocket(Refusing, "ws://h/", ["posecast.v2"], 5, handlers),
    (err: unknown) => err instanceof ConfigInvalidError && err.message.includes("(insecure)") && err.hint.includes("wss://"),
  );
});

test("bytesOf: an ArrayBuffer or a view (offset kept); nothing for text", () => {
  assert.deepEqual(bytesOf(Uint8Array.of(1, 2).buffer), Uint8Array.of(1, 2));
  const backing = Uint8Array.of(9, 1, 2, 9);
  const view = bytesOf(new DataView(backing.buffer, 1, 2))!;
  assert.deepEqual(view, Uint8Array.of(1, 2));
  assert.equal(view.buffer, backing.buffer); // no copy
  assert.deepEqual(bytesOf(Buffer.from([3])), Uint8Array.of(3));
  assert.equal(bytesOf("text"), undefined);
  assert.equal(bytesOf(undefined), undefined);
});
