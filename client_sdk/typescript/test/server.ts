/**
 * A real `posecast serve --dev` process for the integration tests, and join tokens in
 * the server's format (JWTs, `server/posecast/online/auth/tokens.py`), minted HS256 with
 * Node's crypto (synchronously, for the tests' token functions; `src/mint.ts` mints
 * with `jose`, and test/mint.test.ts checks both against a server).
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

/** Start `posecast serve --dev` (8 samples) and wait until it listens; `env`: more
 * variables (POSECAST_TOKEN_KEYS). */
export async function startServer(
  options: { port?: number; secret?: string; args?: string[]; env?: Record<string, string> } = {},
): Promise<RunningServer> {
  const bin = posecastBin();
  if (bin === undefined) throw new Error("no posecast binary");
  const secret = options.secret ?? SECRET;
  const child: ChildProcess = spawn(
    bin,
    ["serve", "--dev", "--port", String(options.port ?? 0), "--samples", "8",
     "--log-level", "WARNING", ...(options.args ?? [])],
    {
      env: { ...process.env, POSECAST_TOKEN_SECRET: secret, ...options.env },
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

/** A join token as `posecast token` mints it: a JWT, HS256 with `secret`, no kid. */
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
  const body = {
    room: claims.room,
    player: claims.player,
    role: claims.role ?? "player",
    iat,
    exp: iat + (claims.ttlS ?? 600),
    jti: randomBytes(9).toString("base64url"),
  };
  const header = b64url(Buffer.from(JSON.stringify({ alg: "HS256", typ: "JWT" })));
  const signed = header + "." + b64url(Buffer.from(JSON.stringify(body)));
  return signed + "." + b64url(createHmac("sha256", secret).update(signed, "ascii").digest());
}
