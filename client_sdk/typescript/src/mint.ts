/**
 * Minting join tokens in Node: `import { mintToken } from "@posecast/client/mint"`.
 *
 * A join token is a JWT (RFC 7519, compact JWS; proto/README.md, Join tokens), signed
 * here with `jose`, a well-kept JWT library: HS256 with the server's shared secret, or
 * ES256 / EdDSA with a private key (a JWK, as `posecast keygen` writes it) whose public
 * half is in the servers' key set. For a game backend written in Node, and for tests.
 *
 * A separate entry point, never imported by the SDK's core (`@posecast/client`), so a
 * browser bundle carries neither it nor `jose`; and it refuses to run outside Node: a
 * key in a browser lets anyone who opens the page mint tokens for any room.
 * `jose` is an optional peer dependency: `npm install jose` where you mint.
 */

import { base64url, importJWK, type JWK, SignJWT } from "jose";

import { ID_PATTERN } from "./fields.js";
import { MAX_ID_BYTES, ROLES, type Role } from "./messages.js";
import { utf8, utf8Length } from "./msgpack.js";

/** What a server verifies, each algorithm with its one kind of key. */
export const TOKEN_ALGORITHMS = ["HS256", "ES256", "EdDSA"] as const;
export type TokenAlgorithm = (typeof TOKEN_ALGORITHMS)[number];
/** The server refuses shorter HS256 secrets (characters of text, keyed as UTF-8). */
export const MIN_SECRET_CHARS = 32;
/** The longest lifetime the server's minting tool allows, seconds (7 days). */
export const MAX_TTL_S = 7 * 24 * 3600;

export interface MintOptions {
  readonly room: string;
  readonly player: string;
  /** `player` (default), `spectator` or `backend`. */
  readonly role?: Role;
  /** Further rooms a backend may watch. */
  readonly rooms?: readonly string[];
  /** Seconds from `now` until it expires (default 3600). */
  readonly ttlS?: number;
  /** Unix seconds of issue (default: the clock). */
  readonly now?: number;
  /** The token's unique id (default: 12 random bytes, base64url). */
  readonly jti?: string;
  /** The key id in the header (default: the JWK's `kid`; none for a secret). */
  readonly kid?: string;
  /** Checked against the key's algorithm (default: the key's). */
  readonly alg?: TokenAlgorithm;
}

interface Random {
  getRandomValues(array: Uint8Array): Uint8Array;
}

function algOf(key: JWK): TokenAlgorithm {
  if (key.kty === "oct") return "HS256";
  if (key.kty === "EC" && key.crv === "P-256") return "ES256";
  if (key.kty === "OKP" && key.crv === "Ed25519") return "EdDSA";
  throw new TypeError(
    `a ${String(key.kty)} ${String(key.crv ?? "")} key: posecast verifies oct (HS256), EC P-256 (ES256), OKP Ed25519 (EdDSA)`,
  );
}

function checkId(what: string, value: string): void {
  if (utf8Length(value) > MAX_ID_BYTES || !ID_PATTERN.test(value)) {
    throw new TypeError(`${what} ${JSON.stringify(value)} is not an id: 1 to ${MAX_ID_BYTES} of A-Z a-z 0-9 _ . : -`);
  }
}

/**
 * A join token (a JWT) for `options.player` in `options.room`.
 *
 * `key`: the server's token secret (`POSECAST_TOKEN_SECRET`, at least
 * {@link MIN_SECRET_CHARS} characters) signing HS256, or a JWK: a private EC P-256
 * (ES256) or Ed25519 (EdDSA) key, or an `oct` key (HS256). Throws a `TypeError` for
 * what no server would take (a short secret, a public key, an unknown role, a room or
 * player that is not a wire id, a ttl outside 1 s to 7 days, `alg` not the key's).
 */
export async function mintToken(key: string | JWK, options: MintOptions): Promise<string> {
  const proc = (globalThis as { process?: { versions?: { node?: string } } }).process;
  if (proc?.versions?.node === undefined) {
    throw new TypeError("mintToken runs in Node only: a key in a browser lets anyone mint tokens");
  }
  let alg: TokenAlgorithm;
  let material: Uint8Array | Awaited<ReturnType<typeof importJWK>>;
  let kid: string | undefined;
  if (typeof key === "string") {
    if ([...key].length < MIN_SECRET_CHARS) {
      throw new TypeError(
        `the secret has ${[...key].length} characters; a server takes none under ${MIN_SECRET_CHARS}, so no server verifies tokens minted with it`,
      );
    }
    alg = "HS256";
    material = utf8(key);
  } else {
    alg = algOf(key);
    if (alg !== "HS256" && key.d === undefined) {
      throw new TypeError("this is a public key: minting needs the private key (its d)");
    }
    material = await importJWK(key, alg);
    kid = key.kid;
  }
  if (options.alg !== undefined && options.alg !== alg) {
    throw new TypeError(`alg ${options.alg} does not fit the key, which signs ${alg}`);
  }
  const role = options.role ?? "player";
  if (!ROLES.includes(role)) throw new TypeError(`role must be one of ${ROLES.join(", ")}, not ${String(role)}`);
  const rooms = options.rooms ?? [];
  if (rooms.length > 0 && role !== "backend") throw new TypeError("only a backend token may list extra rooms");
  const ttlS = options.ttlS ?? 3600;
  if (!Number.isInteger(ttlS) || ttlS <= 0 || ttlS > MAX_TTL_S) {
    throw new TypeError(`ttlS must be an integer in (0, ${MAX_TTL_S}]`);
  }
  checkId("room", options.room);
  checkId("player", options.player);
  for (const r of rooms) checkId("rooms", r);
  const iat = Math.floor(options.now ?? Date.now() / 1000);
  const random = (globalThis as unknown as { crypto: Random }).crypto;
  const jti = options.jti ?? base64url.encode(random.getRandomValues(new Uint8Array(12)));
  const claims: Record<string, unknown> = { room: options.room, player: options.player, role };
  if (rooms.length > 0) claims["rooms"] = [...rooms];
  const header: { alg: TokenAlgorithm; typ: string; kid?: string } = { alg, typ: "JWT" };
  const headerKid = options.kid ?? kid;
  if (headerKid !== undefined && headerKid !== "") header.kid = headerKid;
  return new SignJWT(claims)
    .setProtectedHeader(header)
    .setIssuedAt(iat)
    .setExpirationTime(iat + ttlS)
    .setJti(jti)
    .sign(material);
}
