/**
 * The options of the client's public calls ({@link connect}, {@link PosecastClient.join})
 * and the states it goes through.
 */

import type { TokenSource } from "./dial.js";
import type { ReconnectOptions } from "./reconnect.js";
import type { WebSocketConstructor } from "./socket.js";

export type { ReconnectOptions, TokenSource, WebSocketConstructor };

export interface ConnectOptions {
  /** The WebSocket class; default `globalThis.WebSocket` (browsers, Node >= 22). */
  readonly WebSocket?: WebSocketConstructor;
  /** Reconnect after a lost connection (default on), or `false`. */
  readonly reconnect?: boolean | ReconnectOptions;
  /** Seconds between clock-sync pings once joined; 0 turns them off. Default 2. */
  readonly pingIntervalS?: number;
  /** Seconds to wait for the socket to open, and for the `welcome`. Default 10. */
  readonly timeoutS?: number;
  /** Non-pose events kept for a reader that falls behind. Default 1024. */
  readonly maxQueuedEvents?: number;
  /** The client's monotonic clock in seconds. Default `performance.now() / 1000`. */
  readonly clock?: () => number;
  /** Random numbers in [0, 1) for the back-off jitter. Default `Math.random`. */
  readonly random?: () => number;
  /** The highest protocol to offer: 2 (default: `posecast.v2, posecast.v1`) or 1 (v1 only). */
  readonly protocol?: 1 | 2;
}

export interface JoinOptions {
  /** Frames per second this client will send (announced in `hello`). Absent: 60. */
  readonly rateHz?: number;
  /** Backends only: further rooms to watch. */
  readonly watch?: readonly string[];
  /** v2: poses per second wanted, 60, 30, 20 or 15 (ignored by a v1 server). Absent: 60. */
  readonly poseRateHz?: number;
  /**
   * v2: poses forecast this many ms ahead, 0 to 100, to cancel this client's network and
   * render delay (ignored by a v1 server). The server rounds it to whole ticks
   * (`welcome.forecast_ms`) and stamps each pose's `t` that far past its tick. Absent: 0.
   */
  readonly forecastMs?: number;
}

export type ClientState = "open" | "joining" | "joined" | "reconnecting" | "closed";
