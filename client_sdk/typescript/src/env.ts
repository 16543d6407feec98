/**
 * The few host facilities the SDK uses, looked up on `globalThis` with local types,
 * so the SDK compiles without the DOM or Node type libraries and runs in both.
 */

export type TimerId = unknown;

interface Host {
  setTimeout(fn: () => void, ms: number): TimerId;
  clearTimeout(id: TimerId): void;
  performance?: { now(): number };
  WebSocket?: unknown;
}

const host = globalThis as unknown as Host;

/**
 * Call `fn` after `seconds`. With `background`, the timer alone does not keep a Node
 * process alive (periodic pings: the open socket does that); back-off and timeout
 * timers do, or a program waiting on a reconnect would simply exit.
 */
export function setTimer(fn: () => void, seconds: number, background = false): TimerId {
  const id = host.setTimeout(fn, Math.max(0, seconds * 1000));
  if (background) (id as { unref?: () => void } | null)?.unref?.();
  return id;
}

export function clearTimer(id: TimerId | undefined): void {
  if (id !== undefined) host.clearTimeout(id);
}

/** Seconds on a monotonic clock (`performance.now()`), arbitrary epoch. */
export function monotonicS(): number {
  const perf = host.performance;
  if (perf === undefined) throw new Error("no performance.now(): pass options.clock");
  return perf.now() / 1000;
}

/** The host's WebSocket constructor (browsers, Node >= 22), if it has one. */
export function globalWebSocket(): unknown {
  return host.WebSocket;
}
