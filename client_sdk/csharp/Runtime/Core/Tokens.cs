// Minting join tokens, for development and tests only.
//
// In production the game backend mints tokens and keeps the key; a client only
// passes its token on. For a `posecast serve --dev` server (which prints its secret)
// this mints the server's format, a JWT (RFC 7519, compact JWS) signed HS256 with the
// secret, with the base class library's HMACSHA256 (proto/README.md, Join tokens):
//   base64url(header) "." base64url(claims) "." base64url(HMAC-SHA256(secret, header.claims))
// without padding; header alg HS256, typ JWT and an optional kid; claims room, player,
// role, iat and exp (Unix seconds), jti. A backend in .NET mints with its JWT library
// (System.IdentityModel.Tokens.Jwt), ES256 included.

using System;
using System.Security.Cryptography;
using System.Text;

namespace Posecast.Client
{
    public static class DevTokens
    {
        private static string B64(byte[] raw)
        {
            return Convert.ToBase64String(raw).TrimEnd('=').Replace('+', '-').Replace('/', '_');
        }

        private static string JsonStr(string s)
        {
            var sb = new StringBuilder("\"");
            foreach (char c in s)
            {
                if (c == '"' || c == '\\') sb.Append('\\').Append(c);
                else if (c < 0x20 || c > 0x7e) sb.Append("\\u").Append(((int)c).ToString("x4"));
                else sb.Append(c);
            }
            return sb.Append('"').ToString();
        }

        /// <summary>The server refuses a shorter token secret (posecast.online.config), in characters:
        /// at least 32 bytes for HS256 (RFC 7518 3.2).</summary>
        public const int MinSecretChars = 32;

        /// <summary>Characters as the server (Python) counts them: code points, a UTF-16 surrogate pair one.</summary>
        private static int Characters(string s)
        {
            int n = 0;
            for (int i = 0; i < s.Length; i++, n++)
                if (char.IsHighSurrogate(s[i]) && i + 1 < s.Length && char.IsLowSurrogate(s[i + 1])) i++;
            return n;
        }

        /// <summary>The longest lifetime a minted token may have, seconds (7 days: the server's minting tool's).</summary>
        public const int MaxTtlS = 7 * 24 * 3600;

        /// <summary>A room or player the server takes in a token: a wire id, 1..Protocol.MaxIdBytes of A-Z a-z 0-9 _ . : -.</summary>
        private static void CheckId(string what, string value)
        {
            if (value == null) throw new ArgumentException("no " + what + " (null)");
            if (Encoding.UTF8.GetByteCount(value) > Protocol.MaxIdBytes || !Fields.IsId(value))
                throw new ArgumentException(what + " '" + value + "' is not an id: 1 to " + Protocol.MaxIdBytes
                                            + " of A-Z a-z 0-9 _ . : -");
        }

        /// <summary>A token for `player` in `room` with `role`, valid ttlS seconds from now, refused
        /// (ArgumentException) as the Python SDK's mint_token refuses it: a secret shorter than any server
        /// takes (MinSecretChars), for no server would verify the token; a role that is none of
        /// Protocol.Roles; ttlS not in (0, MaxTtlS]; a room or player that is not a wire id, which the
        /// server refuses at join. `kid`: the key id in the header, for a server whose key set holds
        /// several keys (its POSECAST_TOKEN_SECRET is kid "secret"); none by default.</summary>
        public static string Mint(string secret, string room, string player, string role = "player", int ttlS = 3600,
                                  string kid = null)
        {
            var jti = new byte[12];
            using (var rng = RandomNumberGenerator.Create()) rng.GetBytes(jti);
            return MintAt(secret, room, player, role, ttlS, kid, DateTimeOffset.UtcNow.ToUnixTimeSeconds(), B64(jti));
        }

        /// <summary>Mint with a given issue time (Unix seconds) and jti: the same bytes as the Python
        /// SDK's mint_token with the same arguments (a test compares them).</summary>
        public static string MintAt(string secret, string room, string player, string role, int ttlS, string kid,
                                    long iat, string jti)
        {
            if (secret == null) throw new ArgumentException("no token secret (POSECAST_TOKEN_SECRET)");
            int chars = Characters(secret);
            if (chars < MinSecretChars)
                throw new ArgumentException("the secret has " + chars + " characters; a server takes none under "
                                            + MinSecretChars + ", so no server verifies tokens minted with it");
            if (Array.IndexOf(Protocol.Roles, role) < 0) throw new ArgumentException("no role " + role);
            if (ttlS <= 0 || ttlS > MaxTtlS) throw new ArgumentException("ttlS must be in (0, " + MaxTtlS + "], not " + ttlS);
            CheckId("room", room);
            CheckId("player", player);
            if (string.IsNullOrEmpty(jti)) throw new ArgumentException("no jti");
            // Compact JSON in PyJWT's order: header keys sorted, claims as mint_token writes them.
            string header = kid == null ? "{\"alg\":\"HS256\",\"typ\":\"JWT\"}"
                                        : "{\"alg\":\"HS256\",\"kid\":" + JsonStr(kid) + ",\"typ\":\"JWT\"}";
            string claims = "{\"room\":" + JsonStr(room) + ",\"player\":" + JsonStr(player) + ",\"role\":" + JsonStr(role)
                            + ",\"iat\":" + iat + ",\"exp\":" + (iat + ttlS) + ",\"jti\":" + JsonStr(jti) + "}";
            string signed = B64(Encoding.UTF8.GetBytes(header)) + "." + B64(Encoding.UTF8.GetBytes(claims));
            using (var mac = new HMACSHA256(Encoding.UTF8.GetBytes(secret)))
                return signed + "." + B64(mac.ComputeHash(Encoding.ASCII.GetBytes(signed)));
        }
    }
}
