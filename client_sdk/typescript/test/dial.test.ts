/**
 * dial.ts alone (no sockets): the URL and token checks before dialing, the token
 * function's result, and the reasons and hints a failed dial is explained with. The same
 * checks through `connect`, and real refused dials, are in client.test.ts.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { checkToken, checkUrl, connectFailure, fetchToken } from "../src/dial.js";
import { ConfigInvalidError, ConnectFailedError, TokenProviderError } from "../src/errors.js";

test("checkUrl refuses what the client cannot dial, saying what to use instead", () => {
  const cases: [unknown, string, string][] = [
    ["http://h:8765/", "is an HTTP URL", "use ws://h:8765/"],
    ["HTTPS://h/x", "is an HTTP URL", "use wss://h/x"],
    ["h:8765", "is not a WebSocket URL", "did you mean ws://h:8765/?"],
    ["h:8765/path", "is not a WebSocket URL", "did you mean ws://h:8765/path?"],
    ["ftp://h/", "is not a WebSocket URL", "such as ws://127.0.0.1:8765/"],
    ["ws:h", "is not a WebSocket URL", "such as ws://127.0.0.1:8765/"],
    ["ws://", "names no host", "such as"],
    ["ws://[]:80/", "names no host", "such as"],
    ["ws://h:65536/", "bad port (65536)", "1 to 65535"],
    ["ws://h:x/", "bad port (x)", "1 to 65535"],
    ["ws://h/#a", "#fragment", "leave out the #"],
    ["  ", "no server URL (got a blank string)", "unset environment variable"],
    [null, "no server URL (got null)", "unset environment variable"],
    [8765, "no server URL (got a value of type number)", "unset environment variable"],
  ];
  for (const [url, words, hint] of cases) {
    assert.throws(
      () => checkUrl(url),
      (err: unknown) => {
        assert.ok(err instanceof ConfigInvalidError, `${String(url)}: ${String(err)}`);
        assert.ok(err.message.includes(words), `${String(url)}: ${err.message}`);
        assert.ok(err.hint.includes(hint), `${String(url)}: ${err.hint}`);
        return true;
      },
    );
  }
  assert.equal(checkUrl(" wss://h:443/x?y=1 "), "wss://h:443/x?y=1");
});

test("checkToken takes a non-blank string or a function, and nothing else", () => {
  checkToken("tok");
  checkToken(() => "tok");
  checkToken(async () => "tok");
  for (const [token, words] of [
    [undefined, "got undefined"],
    ["", "got an empty string"],
    ["\t", "got a blank string"],
    [{}, "got a value of type object"],
  ] as const) {
    assert.throws(
      () => checkToken(token),
      (err: unknown) => err instanceof ConfigInvalidError && err.message.includes(words),
    );
  }
});

test("fetchToken: what the function returns, TokenProviderError when it throws, ConfigInvalidError for no token", async () => {
  assert.equal(await fetchToken(() => "a"), "a");
  assert.equal(await fetchToken(async () => "b"), "b");
  const why = new Error("backend down");
  await assert.rejects(fetchToken(() => Promise.reject(why)), (err: unknown) => {
    assert.ok(err instanceof TokenProviderError, String(err));
    assert.equal(err.code, "TOKEN_PROVIDER_FAILED");
    assert.equal(err.cause, why);
    assert.ok(err.message.includes("the token function threw Error: backend down"), err.message);
    return true;
  });
  await assert.rejects(
    fetchToken(() => {
      throw "a string"; // not an Error: described as the value itself
    }),
    (err: unknown) => err instanceof TokenProviderError && err.message.includes("threw a string"),
  );
  for (const [result, words] of [
    ["", "returned an empty string"],
    [" ", "returned a blank string"],
    [undefined, "returned undefined"],
    [7, "returned a value of type number"],
  ] as const) {
    await assert.rejects(fetchToken(() => result as unknown as string), (err: unknown) => {
      assert.ok(err instanceof ConfigInvalidError, String(err));
      assert.ok(err.message.includes(`the token function ${words}`), err.message);
      return true;
    });
  }
});

test("connectFailure reads the cause the WebSocket class gives, and hints at the fix", () => {
  const url = "ws://h:8765/";
  const failure = (error: unknown, closeCode = 1006, at = url): ConnectFailedError =>
    connectFailure(at, error === undefined ? undefined : { error }, closeCode);
  const refused = failure({ code: "ECONNREFUSED", message: "connect ECONNREFUSED" });
  assert.equal(refused.reason, "connection refused (nothing listens at that port)");
  assert.ok(refused.hint.includes("posecast serve --dev"));
  assert.equal((refused.cause as { code: string }).code, "ECONNREFUSED");
  assert.equal(refused.closeCode, 1006);
  for (const code of ["ENOTFOUND", "EAI_AGAIN"]) {
    const f = failure({ code });
    assert.equal(f.reason, `the host name does not resolve (${code})`);
    assert.ok(f.hint.includes("check the host"));
  }
  const tls = failure({ code: "CERT_HAS_EXPIRED", message: "certificate has expired" }, 1006, "wss://h/");
  assert.equal(tls.reason, "TLS failed (certificate has expired)");
  assert.ok(tls.hint.includes("ws://"));
  assert.equal(failure({ code: "ECONNRESET" }, 1006, "wss://h/").reason, "TLS failed (ECONNRESET)");
  assert.ok(!failure({ code: "ECONNRESET" }).reason.startsWith("TLS")); // ws://: a reset is not TLS
  for (const [status, hint] of [
    [429, "too often"],
    [503, "busy or full"],
    [404, "a posecast WebSocket endpoint"],
  ] as const) {
    const f = failure({ message: `Unexpected server response: ${status}` });
    assert.equal(f.status, status);
    assert.equal(f.reason, `the server refused the WebSocket upgrade with HTTP ${status}`);
    assert.ok(f.hint.includes(hint), f.hint);
  }
  // A browser tells nothing: the close code, and the running-server hint.
  const browser = connectFailure(url, { type: "error" }, 1006);
  assert.equal(browser.reason, "the socket closed (code 1006)");
  assert.ok(browser.hint.includes("posecast serve"));
  assert.equal(connectFailure(url, { message: "net::ERR_FAILED" }, 1006).reason, "net::ERR_FAILED");
});
