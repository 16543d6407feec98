/**
 * One WebSocket of the client: dialing it, and the bytes it receives. The client makes a
 * new one per connection (a reconnect dials again) and keeps the rest of its state.
 *
 * Any WebSocket class with the members of {@link WebSocketLike} serves: the browser's,
 * Node's (>= 22), `ws`, undici.
 */

import { ConfigInvalidError, ConnectFailedError, ConnectionClosedError } from "./errors.js";
import { clearTimer, setTimer } from "./env.js";
import { connectFailure } from "./dial.js";

/** The members of a WebSocket the client uses (browser `WebSocket`, `ws`, undici). */
export interface WebSocketLike {
  binaryType: string;
  readonly readyState: number;
  readonly protocol: string;
  send(data: Uint8Array): void;
  close(code?: number, reason?: string): void;
  onopen: ((ev: unknown) => void) | null;
  onmessage: ((ev: { readonly data: unknown }) => void) | null;
  onclose: ((ev: { readonly code: number; readonly reason: string }) => void) | null;
  onerror: ((ev: unknown) => void) | null;
}

/** A WebSocket class: `globalThis.WebSocket` in browsers, or `WebSocket` from `ws` in Node. */
export type WebSocketConstructor = abstract new (url: string, protocols?: string[]) => object;

/** The class the client makes its sockets with (a {@link WebSocketConstructor} it may call). */
export type WebSocketClass = new (url: string, protocols?: string[]) => WebSocketLike;

/** `readyState` of an open socket. */
export const WS_OPEN = 1;

/** What an open socket reports to its client. */
export interface SocketHandlers {
  /** The socket opened and the server selected `protocol`, one of those offered. */
  opened(protocol: string): void;
  /** A message's data, as the WebSocket class gives it (see {@link bytesOf}). */
  data(data: unknown): void;
  /** The socket closed (after it had opened). */
  closed(code: number, reason: string): void;
}

/**
 * Dial `url` offering the subprotocols `offered`. Returns the socket at once (closing it
 * cuts the dial short) and a promise of the open socket: it resolves once the server
 * selected one of `offered` (after `handlers.opened`), and from then on `handlers` hear
 * its messages and its close.
 *
 * @throws ConfigInvalidError the WebSocket class refused the URL (e.g. `ws://` from an https page)
 * @returns `open` rejects with {@link ConnectFailedError} (refused, unreachable, no
 *   handshake within `timeoutS`) or {@link ConnectionClosedError} (no offered subprotocol)
 */
export function dialSocket(
  WebSocketClass: WebSocketClass,
  url: string,
  offered: string[],
  timeoutS: number,
  handlers: SocketHandlers,
): { ws: WebSocketLike; open: Promise<WebSocketLike> } {
  let ws: WebSocketLike;
  try {
    ws = new WebSocketClass(url, offered);
  } catch (err) {
    // checkUrl passed it, so the host's own rule: e.g. a page served over https may
    // not open a ws:// URL (SecurityError).
    const why = err instanceof Error ? err.message : String(err);
    throw new ConfigInvalidError(
      `the WebSocket class refused ${JSON.stringify(url)} (${why})`,
      "a page served over https needs a wss:// URL",
      { cause: err },
    );
  }
  ws.binaryType = "arraybuffer";
  const open = new Promise<WebSocketLike>((resolve, reject) => {
    const timer = setTimer(() => {
      ws.close();
      reject(
        new ConnectFailedError(
          url,
          `no WebSocket handshake within ${timeoutS} s`,
          "is the host reachable from here (a firewall, a VPN)? options.timeoutS allows longer",
        ),
      );
    }, timeoutS);
    let errorEvent: unknown;
    ws.onerror = (ev) => {
      errorEvent = ev; // a close event follows every error; this one says why
    };
    ws.onclose = (ev) => {
      clearTimer(timer);
      reject(connectFailure(url, errorEvent, ev.code));
    };
    ws.onopen = () => {
      clearTimer(timer);
      ws.onmessage = (ev) => handlers.data(ev.data);
      ws.onclose = (ev) => handlers.closed(ev.code, ev.reason);
      if (!offered.includes(ws.protocol)) {
        ws.close(1002, "subprotocol");
        reject(new ConnectionClosedError(`server did not select ${offered.join(" or ")}`, 1002));
        return;
      }
      handlers.opened(ws.protocol);
      resolve(ws);
    };
  });
  return { ws, open };
}

/** A binary message's bytes (an ArrayBuffer or a view); `undefined` for text, which posecast servers never send. */
export function bytesOf(data: unknown): Uint8Array | undefined {
  if (data instanceof ArrayBuffer) return new Uint8Array(data);
  if (ArrayBuffer.isView(data)) return new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  return undefined;
}
