/**
 * Clock sync from `ping`/`pong` (pure: times in, an offset out).
 *
 * With `t0` the client time a ping left, `t1`/`t2` the server times it arrived and
 * the pong left, and `t3` the client time the pong arrived (`proto/README.md`):
 *
 * ```text
 * offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
 * rtt    = (t3 - t0) - (t2 - t1)
 * ```
 *
 * A sample's error is at most rtt / 2, so the estimate is the sample with the
 * smallest rtt among the last `window` (default 8); one slow round trip (a GC pause,
 * a busy Wi-Fi channel) then never moves it.
 */

export interface ClockSample {
  /** Server time minus client time, seconds. */
  readonly offsetS: number;
  /** Round trip minus the server's own hold time, seconds. */
  readonly rttS: number;
  /** Client time the pong arrived, seconds. */
  readonly atS: number;
}

export class ClockSync {
  private readonly samples: ClockSample[] = [];

  /** @param window how many recent samples compete for the best (smallest rtt). */
  constructor(readonly window = 8) {
    if (!(window >= 1)) throw new RangeError("window must be >= 1");
  }

  /** Add one ping/pong exchange; returns that exchange's own sample. */
  add(t0: number, t1: number, t2: number, t3: number): ClockSample {
    const sample = { offsetS: (t1 - t0 + (t2 - t3)) / 2, rttS: t3 - t0 - (t2 - t1), atS: t3 };
    this.samples.push(sample);
    if (this.samples.length > this.window) this.samples.shift();
    return sample;
  }

  /** The best recent sample (smallest rtt), or undefined before the first pong. */
  get best(): ClockSample | undefined {
    let best: ClockSample | undefined;
    for (const s of this.samples) if (best === undefined || s.rttS < best.rttS) best = s;
    return best;
  }

  /** Estimated server time minus client time, seconds (undefined before a pong). */
  get offsetS(): number | undefined {
    return this.best?.offsetS;
  }

  /** Round-trip time of the best sample, seconds (undefined before a pong). */
  get rttS(): number | undefined {
    return this.best?.rttS;
  }

  /** The server time at client time `clientS` (seconds). Throws before the first pong. */
  toServer(clientS: number): number {
    return clientS + this.requireOffset();
  }

  /** The client time at server time `serverS`, e.g. of `pose.t`. Throws before a pong. */
  toClient(serverS: number): number {
    return serverS - this.requireOffset();
  }

  /** Forget every sample (a new connection may reach a new server process). */
  reset(): void {
    this.samples.length = 0;
  }

  private requireOffset(): number {
    const offset = this.offsetS;
    if (offset === undefined) throw new Error("no clock sample yet (no pong received)");
    return offset;
  }
}
