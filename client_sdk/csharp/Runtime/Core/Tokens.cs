// Minting join tokens, for development and tests only.
//
// In production the game backend mints tokens and keeps the secret; a client only
// passes its token on. For a `posecast serve --dev` server (which prints its secret)
// this mints tokens in the server's format:
//   base64url(JSON claims, compact, sorted keys) "." base64url(HMAC-SHA256(secret, first part))
// without padding; claims v (1), room, player, role, iat and exp (Unix seconds), jti.

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

        /// <summary>The server refuses a shorter token secret (posecast.online.config), in characters.</summary>
        public const int MinSecretChars = 16;

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
        /// server refuses at join.</summary>
        public static string Mint(string secret, string room, string player, string role = "player", int ttlS = 3600)
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
            long iat = DateTimeOffset.UtcNow.ToUnixTimeSeconds();
            var jti = new byte[12];
            using (var rng = RandomNumberGenerator.Create()) rng.GetBytes(jti);
            // Keys sorted, compact separators: as the server's json.dumps(sort_keys=True).
            string claims = "{\"exp\":" + (iat + ttlS) + ",\"iat\":" + iat + ",\"jti\":" + JsonStr(B64(jti))
                            + ",\"player\":" + JsonStr(player) + ",\"role\":" + JsonStr(role) + ",\"room\":" + JsonStr(room) + ",\"v\":1}";
            string payload = B64(Encoding.UTF8.GetBytes(claims));
            using (var mac = new HMACSHA256(Encoding.UTF8.GetBytes(secret)))
                return payload + "." + B64(mac.ComputeHash(Encoding.ASCII.GetBytes(payload)));
        }
    }
}
