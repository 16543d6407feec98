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

        /// <summary>A token for `player` in `room` with `role`, valid ttlS seconds from now.</summary>
        public static string Mint(string secret, string room, string player, string role = "player", int ttlS = 3600)
        {
            if (string.IsNullOrEmpty(secret)) throw new ArgumentException("the token secret must not be empty");
            if (Array.IndexOf(Protocol.Roles, role) < 0) throw new ArgumentException("no role " + role);
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
