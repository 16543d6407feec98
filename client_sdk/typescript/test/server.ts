/**
 * A real `posecast serve --dev` process for the integration tests, and join tokens in
 * the server's format (`server/posecast/online/auth/tokens.py`), minted with Node's crypto.
 */

import { type ChildProcess, spawn } from "node:child_process";
import { createHmac, randomBytes } from "node:crypto";
import { existsSync } from "node:fs";
import { join } from "node:path";

import { repoRoot } from "./helpers.js";

/** The `posecast` command: $POSECAST_BIN, else the repository's .venv. */
export function posecastBin(): string | undefined {
  const bin = process.env["POSECAST_BIN"] ?? join(repoRoot(), ".venv", "bin", "posecast");
  return existsSync(bin) ? bin : undefined;
}

/** Why the server tests cannot run here, or undefined when they can. */
export function serverSkipReason(): string | undefined {
  return posecastBin() === undefined
    ? "SKIPPED: no posecast server (make venv, or set POSECAST_BIN)"
    : undefined;
}

export interface RunningServer {
  readonly url: string;
  readonly port: number;
  readonly secret: string;
  /** SIGTERM (graceful: bye SERVER_SHUTDOWN to everyone), then wait for the exit. */
  stop(): Promise<void>;
  readonly output: string[];
}

export const SECRET = "ts-sdk-test-secret-" + randomBytes(8).toString("hex");

/** Start `posecast serve --dev` (8 samples) and wait until it listens. */
export async function startServer(
  options: { port?: number; secret?: string; args?: string[] } = {},
): Promise<RunningServer> {
  const bin = posecastBin();
  if (bin === undefined) throw new Error("no posecast binary");
  const secret = options.secret ?? SECRET;
  const child: ChildProcess = spawn(
    bin,
    ["serve", "--dev", "--port", String(options.port ?? 0), "--samples", "8",
     "--log-level", "WARNING", ...(options.args ?? [])],
    {
      env: { ...process.env, POSECAST_TOKEN_SECRET: secret },
      stdio: ["ignore", "pipe", "pipe"],
    },
  );
  const output: string[] = [];
  const exited = new Promise<void>((resolve) => child.once("exit", () => resolve()));
  const port = await new Promise<number>((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error("server did not start:\n" + output.join(""))), 30_000);
    const onData = (chunk: Buffer): void => {
      output.push(chunk.toString());
      const m = /listening on ws:\/\/[\d.]+:(\d+)/.exec(output.join(""));
      if (m !== null) {
        clearTimeout(timer);
        resolve(Number(m[1]));
      }
    };
    child.stdout!.on("data", onData);
    child.stderr!.on("data", (chunk: Buffer) => output.push(chunk.toString()));
    child.once("exit", (code) => {
      clearTimeout(timer);
      reject(new Error(`server exited with ${code}:\n${output.join("")}`));
    });
  });
  return {
    url: `ws://127.0.0.1:${port}/`,
    port,
    secret,
    output,
    async stop() {
      if (child.exitCode === null) child.kill("SIGTERM");
      await exited;
    },
  };
}

const b64url = (b: Buffer): string => b.toString("base64url");

/** A join token as `posecast token` mints it: base64url(claims JSON) "." base64url(HMAC). */
export function mintToken(
  secret: string,
  claims: {
    room: string;
    player: string;
    role?: "player" | "spectator" | "backend";
    ttlS?: number;
    /** Seconds to move the issue time back (an expired token: ageS > ttlS). */
    ageS?: number;
  },
): string {
  const iat = Math.floor(Date.now() / 1000) - (claims.ageS ?? 0);
  // Sorted keys and compact separators, as the server's json.dumps(sort_keys=True) writes.
  const body = {
    exp: iat + (claims.ttlS ?? 600),
    iat,
    jti: randomBytes(9).toString("base64url"),
    player: claims.player,
    role: claims.role ?? "player",
    room: claims.room,
    v: 1,
  };
  const payload = b64url(Buffer.from(JSON.stringify(body)));
  const mac = createHmac("sha256", secret).update(payload, "ascii").digest();
  return payload + "." + b64url(mac);
}
