// Checking ConnectAsync's arguments and naming connect failures, as the Python and
// TypeScript SDKs do: a URL the client cannot dial or a missing token throws
// ConfigInvalidException before dialing; a server that cannot be reached or refuses
// the WebSocket upgrade gives ConnectFailedException with a reason, a hint and the
// HTTP status. PosecastClient.CheckUrl is the public face of CheckUrl.

using System;
using System.Net.Sockets;
using System.Security.Authentication;
using System.Text.RegularExpressions;

namespace Posecast.Client
{
    internal static class ConnectChecks
    {
        public const string ExampleUrl = "ws://127.0.0.1:8765/";
        public const string TokenHint = "pass the join token: a string your backend minted (DevTokens.Mint for a dev "
                                        + "server), or set Options.TokenProvider; an unset environment variable?";
        private const string RunningHint = "is a posecast server running there, and reachable from here? "
                                           + "`posecast serve --dev` starts one";

        /// <summary>How a missing string was missing: "null", "an empty string" or "a blank string".</summary>
        public static string What(string value)
        {
            return value == null ? "null" : value.Length == 0 ? "an empty string" : "a blank string";
        }

        /// <summary>
        /// `url` without leading or trailing whitespace (what the client keeps in Urls and
        /// dials), if the client can dial it: ws:// or wss:// (any case), a host, a port from
        /// 1 to 65535 (absent: 80 or 443), no #fragment; the Python and TypeScript SDKs take the same.
        /// Throws ConfigInvalidException otherwise, with a hint (an http:// URL: its ws://
        /// twin; host:port: the ws:// URL).
        /// </summary>
        public static string CheckUrl(string url)
        {
            if (string.IsNullOrWhiteSpace(url))
                throw new ConfigInvalidException("no server URL (got " + What(url) + ")",
                    "pass the server's WebSocket URL, such as " + ExampleUrl + "; an unset environment variable?");
            string text = url.Trim();
            var m = Regex.Match(text, "^([A-Za-z][A-Za-z0-9+.-]*):(//)?");
            string scheme = m.Success ? m.Groups[1].Value.ToLowerInvariant() : "";
            bool slashes = m.Success && m.Groups[2].Success;
            string quoted = "'" + url + "'";
            if ((scheme == "http" || scheme == "https") && slashes)
                throw new ConfigInvalidException(quoted + " is an HTTP URL, not a WebSocket one",
                    "use " + (scheme == "http" ? "ws" : "wss") + text.Substring(scheme.Length));
            if ((scheme != "ws" && scheme != "wss") || !slashes)
            {
                bool hostPort = !text.Contains("://") && scheme != "ws" && scheme != "wss" && scheme != "http" && scheme != "https";
                throw new ConfigInvalidException(quoted + " is not a WebSocket URL: it must start with ws:// (wss:// behind TLS)",
                    hostPort ? "did you mean ws://" + text + (text.Contains("/") ? "" : "/") + "?" : "such as " + ExampleUrl);
            }
            string authority = Regex.Match(text.Substring(scheme.Length + 3), "^[^/?#]*").Value;
            string hostPortText = authority.Substring(authority.LastIndexOf('@') + 1);
            int bracket = hostPortText.StartsWith("[", StringComparison.Ordinal) ? hostPortText.IndexOf(']') + 1 : 0;
            int colon = hostPortText.IndexOf(':', bracket);
            string host = colon < 0 ? hostPortText : hostPortText.Substring(0, colon);
            string port = colon < 0 ? "" : hostPortText.Substring(colon + 1);
            if (host.Length == 0 || host == "[]") throw new ConfigInvalidException(quoted + " names no host", "such as " + ExampleUrl);
            int p;
            if (port.Length > 0 && !(Regex.IsMatch(port, "^[0-9]{1,5}$") && int.TryParse(port, out p) && p >= 1 && p <= 65535))
                throw new ConfigInvalidException(quoted + " has a bad port (" + port + ")", "a port is a number from 1 to 65535");
            if (text.Contains("#"))
                throw new ConfigInvalidException(quoted + " has a #fragment, which a WebSocket URL may not", "leave out the # and what follows it");
            Uri uri;
            if (!Uri.TryCreate(text, UriKind.Absolute, out uri))
                throw new ConfigInvalidException(quoted + " is not a usable URL", "such as " + ExampleUrl);
            return text;
        }

        /// <summary>The ConnectFailedException for what opening `url` threw: reason, hint, HTTP status.</summary>
        public static ConnectFailedException ConnectFailure(string url, Exception e, double openTimeoutS)
        {
            var socket = Find<SocketException>(e);
            string text = "";
            for (var x = e; x != null; x = x.InnerException) text += " " + x.Message;
            var status = Regex.Match(text, "status code '([0-9]{3})'");
            if (e is OperationCanceledException || e is TimeoutException)
                return new ConnectFailedException(url, "no WebSocket handshake within " + openTimeoutS + " s",
                    "is the host reachable from here (a firewall, a VPN)? Options.OpenTimeoutS allows longer", null, e);
            if (status.Success)
            {
                int code = int.Parse(status.Groups[1].Value);
                string hint = code == 429 ? "this address connected (or broke the protocol) too often: back off, try again later"
                            : code == 503 ? "the server is starting, busy or full: try again in a moment, with back-off"
                            : "is the URL a posecast WebSocket endpoint, such as " + ExampleUrl + "?";
                return new ConnectFailedException(url, "the server refused the WebSocket upgrade with HTTP " + code, hint, code, e);
            }
            if (socket != null && socket.SocketErrorCode == SocketError.ConnectionRefused)
                return new ConnectFailedException(url, "connection refused (nothing listens at that port)", RunningHint, null, e);
            if (socket != null && (socket.SocketErrorCode == SocketError.HostNotFound || socket.SocketErrorCode == SocketError.TryAgain
                                   || socket.SocketErrorCode == SocketError.NoData))
                return new ConnectFailedException(url, "the host name does not resolve (" + socket.Message + ")",
                    "check the host in the URL, and this machine's network", null, e);
            if (Find<AuthenticationException>(e) != null)
                return new ConnectFailedException(url, "TLS failed (" + Find<AuthenticationException>(e).Message + ")",
                    "does the server speak TLS at that port, with a certificate trusted here? one without TLS takes ws://", null, e);
            // Mono says only "Unable to connect to the remote server", for a refused upgrade too.
            return new ConnectFailedException(url, (socket ?? e).Message, RunningHint + "; a server refusing the upgrade "
                + "(HTTP 429: this address connects too often, 503: starting or full) ends so here too: back off and retry", null, e);
        }

        private static TE Find<TE>(Exception e) where TE : Exception
        {
            for (var x = e; x != null; x = x.InnerException) if (x is TE) return (TE)x;
            return null;
        }
    }
}
