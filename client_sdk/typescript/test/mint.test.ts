/**
 * Join tokens minted in Node (src/mint.ts, on `jose`), and by `jose` itself, against a
 * real `posecast serve` whose key set holds its secret, an ES256 and an EdDSA public
 * key: each kind joins; a wrong key, `alg: none`, an unknown kid, an expired token are
 * refused with their codes. And the core SDK never reaches the minter or `jose`.
 */

import assert from "node:assert/strict";
import { readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { after, before, describe, test } from "node:test";

import { exportJWK, generateKeyPair, importJWK, type JWK, SignJWT, UnsecuredJWT } from "jose";
import WebSocket from "ws";

import { connect, type ConnectOptions } from "../src/client.js";
import { TokenExpiredError, UnauthenticatedError } from "../src/errors.js";
import { mintToken } from "../src/mint.js";
import { repoRoot } from "./helpers.js";
import { type RunningServer, serverSkipReason, startServer } from "./server.js";

const skip = serverSkipReason();
const OPTS: ConnectOptions = { WebSocket, timeoutS: 10, reconnect: false };

async function pair(alg: "ES256" | "EdDSA", kid: string): Promise<{ privateJwk: JWK; publicJwk: JWK }> {
  const { privateKey, publicKey } = await generateKeyPair(alg, { extractable: true });
  const privateJwk = { ...(await exportJWK(privateKey)), kid, alg };
  const publicJwk = { ...(await exportJWK(publicKey)), kid, alg };
  return { privateJwk, publicJwk };
}

async function joins(url: string, token: string, player: string): Promise<void> {
  const client = await connect(url, token, OPTS);
  const me = await client.join("mint", player);
  assert.equal(me.player, player);
  await client.close();
}

async function refused(url: string, token: string): Promise<Error> {
  const client = await connect(url, token, OPTS);
  try {
    await client.join("mint", "mallory");
  } catch (err) {
    return err as Error;
  }
  throw new Error("the token joined");
}

describe("tokens minted in Node", { skip }, () => {
  let server: RunningServer;
  let es: { privateJwk: JWK; publicJwk: JWK };
  let ed: { privateJwk: JWK; publicJwk: JWK };
  before(async () => {
    es = await pair("ES256", "es-node");
    ed = await pair("EdDSA", "ed-node");
    const keys = JSON.stringify({ keys: [es.publicJwk, ed.publicJwk] });
    server = await startServer({ env: { POSECAST_TOKEN_KEYS: keys } });
  });
  after(async () => {
    await server?.stop();
  });

  test("mintToken: HS256 (the secret, kid secret), ES256 and EdDSA tokens join", async () => {
    await joins(server.url, await mintToken(server.secret, { room: "mint", player: "hs", kid: "secret" }), "hs");
    await joins(server.url, await mintToken(es.privateJwk, { room: "mint", player: "es", alg: "ES256" }), "es");
    await joins(server.url, await mintToken(ed.privateJwk, { room: "mint", player: "ed" }), "ed");
  });

  test("jose's own SignJWT tokens join", async () => {
    const now = Math.floor(Date.now() / 1000);
    for (const [key, alg, player] of [[es, "ES256", "jose-es"], [ed, "EdDSA", "jose-ed"]] as const) {
      const token = await new SignJWT({ room: "mint", player, role: "player" })
        .setProtectedHeader({ alg, kid: key.privateJwk.kid! })
        .setIssuedAt(now)
        .setExpirationTime(now + 600)
        .setJti(`jti-${player}`)
        .sign(await importJWK(key.privateJwk, alg));
      await joins(server.url, token, player);
    }
  });

  test("a wrong key, alg none, an unknown kid and an expired token are refused", async () => {
    const stranger = await pair("ES256", "es-node"); // a kid the server knows, another key
    const wrong = await mintToken(stranger.privateJwk, { room: "mint", player: "m1" });
    assert.ok((await refused(server.url, wrong)) instanceof UnauthenticatedError);
    const none = new UnsecuredJWT({ room: "mint", player: "m2", role: "player", jti: "j" })
      .setIssuedAt()
      .setExpirationTime("10m")
      .encode();
    const noneErr = await refused(server.url, none);
    assert.ok(noneErr instanceof UnauthenticatedError && /alg/.test(noneErr.message), noneErr.message);
    const retired = await mintToken(ed.privateJwk, { room: "mint", player: "m3", kid: "retired-2025" });
    const kidErr = await refused(server.url, retired);
    assert.ok(kidErr instanceof UnauthenticatedError && kidErr.message.includes("'retired-2025'"), kidErr.message);
    const old = await mintToken(es.privateJwk, { room: "mint", player: "m4", now: Date.now() / 1000 - 7200 });
    assert.ok((await refused(server.url, old)) instanceof TokenExpiredError);
  });
});

describe("mintToken refuses what no server takes", () => {
  test("a short secret, a public key, an alg not the key's, a bad id, a bad ttl", async () => {
    const { publicJwk, privateJwk } = await pair("EdDSA", "k");
    const secret = "s".repeat(32);
    await assert.rejects(mintToken("s".repeat(31), { room: "r", player: "p" }), /31 characters/);
    await assert.rejects(mintToken(publicJwk, { room: "r", player: "p" }), /public key/);
    await assert.rejects(mintToken(privateJwk, { room: "r", player: "p", alg: "ES256" }), /does not fit/);
    await assert.rejects(mintToken(secret, { room: "lob by", player: "p" }), /not an id/);
    await assert.rejects(mintToken(secret, { room: "r", player: "p", ttlS: 0 }), /ttlS/);
    await assert.rejects(mintToken(secret, { room: "r", player: "p", rooms: ["x"] }), /backend/);
    const token = await mintToken(secret, { room: "r", player: "p", now: 1_700_000_000, jti: "j", ttlS: 60 });
    const [header, claims] = token.split(".").slice(0, 2).map((p) => JSON.parse(Buffer.from(p!, "base64url").toString()));
    assert.deepEqual(header, { alg: "HS256", typ: "JWT" });
    assert.deepEqual(claims, { room: "r", player: "p", role: "player", iat: 1_700_000_000, exp: 1_700_000_060, jti: "j" });
  });
});

test("the core SDK never imports the minter or jose (browser bundles stay as they were)", () => {
  const src = join(repoRoot(), "client_sdk", "typescript", "src");
  for (const file of readdirSync(src).filter((f) => f.endsWith(".ts") && f !== "mint.ts")) {
    const text = readFileSync(join(src, file), "utf8");
    assert.doesNotMatch(text, /from "jose"|from "\.\/mint\.js"/, file);
  }
  const viewer = readFileSync(join(repoRoot(), "server/posecast/online/shell/static/viewer.js"), "utf8");
  assert.doesNotMatch(viewer, /SignJWT|mintToken/);
});
