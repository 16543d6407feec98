// What ConnectAsync and JoinAsync throw when they cannot go on: the SDK's own
// exceptions, never the runtime's. A URL or token the client cannot use is a
// ConfigInvalidException before any dialing; a server that cannot be reached or refuses
// the upgrade is a ConnectFailedException naming the URL, with a hint (the runtime's
// exception inside). The servers here are plain TCP listeners on loopback.

using System;
using System.Net;
using System.Net.Sockets;
using System.Text;
using System.Threading.Tasks;

namespace Posecast.Client.Tests
{
    public static class ConnectTests
    {
        /// <summary>A loopback listener that answers every connection with `reply` and hangs up (null: says nothing).</summary>
        private sealed class Listener : IDisposable
        {
            public readonly TcpListener Tcp = new TcpListener(IPAddress.Loopback, 0);
            public int Port { get { return ((IPEndPoint)Tcp.LocalEndpoint).Port; } }

            public Listener(string reply, bool accept = true)
            {
                Tcp.Start();
                if (!accept) return;
                Task.Run(async () =>
                {
                    while (true)
                    {
                        TcpClient c;
                        try { c = await Tcp.AcceptTcpClientAsync(); } catch (Exception) { return; }
                        if (reply == null) continue; // keep it open, silent
                        var s = c.GetStream();
                        await s.ReadAsync(new byte[4096], 0, 4096);
                        var b = Encoding.ASCII.GetBytes(reply);
                        await s.WriteAsync(b, 0, b.Length);
                        c.Close();
                    }
                });
            }

            public void Dispose() { Tcp.Stop(); }
        }

        private static Exception Connect(string url, string token, ClientOptions options = null)
        {
            return Connect(new[] { url }, token, options);
        }

        /// <summary>What ConnectAsync threw (a guard against a hang: Mono's ClientWebSocket can wait for good).</summary>
        private static Exception Connect(string[] urls, string token, ClientOptions options = null)
        {
            var task = Task.Run(() => PosecastClient.ConnectAsync(urls, token, options));
            if (!((IAsyncResult)task).AsyncWaitHandle.WaitOne(TimeSpan.FromSeconds(30)))
                throw new AssertException(string.Join(", ", urls) + ": ConnectAsync hung");
            if (task.Exception == null) throw new AssertException(string.Join(", ", urls) + ": connected");
            return task.Exception.GetBaseException();
        }

        private static ConnectFailedException Failed(Exception e, string url)
        {
            var f = e as ConnectFailedException;
            T.True(f != null, url + ": " + e.GetType().Name + " " + e.Message + ", not ConnectFailedException");
            T.Equal(url, f.Url, "url");
            T.True(f.Message.StartsWith("could not connect to " + url + ": ") && f.Message.EndsWith("(hint: " + f.Hint + ")"), f.Message);
            T.True(f is ConnectionLostException && f.Retryable && ClientSession.IsRetryable(f), "retryable, as a lost connection");
            T.True(f.InnerException != null, "the runtime's exception inside");
            return f;
        }

        public static void Register()
        {
            T.Run("connect: a URL the client cannot dial is a ConfigInvalidException, with a hint", () =>
            {
                var cases = new[]
                {
                    new[] { "http://127.0.0.1:8765/", "use ws://127.0.0.1:8765/" },
                    new[] { "https://posecast.example/v1", "use wss://posecast.example/v1" },
                    new[] { "localhost:8765", "did you mean ws://localhost:8765/?" },
                    new[] { "127.0.0.1:8765", "did you mean ws://127.0.0.1:8765/?" },
                    new[] { "ftp://127.0.0.1/", "not a WebSocket URL" },
                    new[] { "ws://", "names no host" },
                    new[] { "ws://127.0.0.1:99999/", "bad port" },
                    new[] { "ws://127.0.0.1:0/", "bad port (0)" },
                    new[] { "ws://[::1", "bad port" },
                    new[] { "ws://127.0.0.1:8765/#room", "#fragment" },
                    new[] { "", "no server URL (got an empty string)" },
                    new[] { null, "no server URL (got null)" }, // Environment.GetEnvironmentVariable of an unset one
                };
                foreach (var c in cases)
                {
                    var e = Connect(c[0], "tok") as ConfigInvalidException;
                    T.True(e != null, c[0] + ": a ConfigInvalidException");
                    T.True(e.Message.Contains(c[1]) && e.Message.EndsWith("(hint: " + e.Hint + ")"), c[0] + ": " + e.Message);
                    T.True(!e.Retryable && !ClientSession.IsRetryable(e), "never retried");
                    T.True(Connect(new[] { "ws://127.0.0.1:8765/", c[0] }, "tok") is ConfigInvalidException, c[0] + " in a list");
                }
            });
            T.Run("connect: good URLs are taken, whitespace around them dropped (a regression refusing them fails here)", () =>
            {
                var cases = new[]
                {
                    new[] { "ws://[::1]:8765/", "ws://[::1]:8765/" }, // an IPv6 literal
                    new[] { "wss://[2001:db8::1]/posecast", "wss://[2001:db8::1]/posecast" },
                    new[] { "ws://127.0.0.1:8765/rooms/lobby?x=1&y=two", "ws://127.0.0.1:8765/rooms/lobby?x=1&y=two" },
                    new[] { "WS://127.0.0.1:8765/", "WS://127.0.0.1:8765/" }, // schemes are case-insensitive
                    new[] { "Wss://posecast.example/", "Wss://posecast.example/" },
                    new[] { "ws://b\u00fccher.example:8765/", "ws://b\u00fccher.example:8765/" }, // a unicode host
                    new[] { "ws://localhost:65535/", "ws://localhost:65535/" },
                    new[] { "ws://h:1/", "ws://h:1/" },
                    new[] { "ws://user:pw@h/", "ws://user:pw@h/" },
                    new[] { "ws://h:8765/ ", "ws://h:8765/" },
                    new[] { "\t ws://h:8765/\n", "ws://h:8765/" },
                };
                foreach (var c in cases) T.Equal(c[1], PosecastClient.CheckUrl(c[0]), c[0]);
            });
            T.Run("connect: the client keeps and dials the URL without the whitespace around it", () =>
            {
                int port = Server.FreePort(); // refused: the URL dialed is in the exception
                string url = "ws://127.0.0.1:" + port + "/";
                Failed(Connect(" " + url + " ", "tok"), url);
                Failed(Connect(new[] { url + "\n" }, "tok"), url);
            });
            T.Run("connect: no token (null, empty) is a ConfigInvalidException before dialing; a TokenProvider stands in", () =>
            {
                using (var server = new Listener(null, accept: false))
                {
                    string url = "ws://127.0.0.1:" + server.Port + "/";
                    foreach (var token in new[] { null, "", "  " })
                    {
                        var e = Connect(url, token) as ConfigInvalidException;
                        T.True(e != null && e.Message.StartsWith("no token (got "), "token '" + token + "': " + e);
                        T.True(e.Hint.Contains("unset environment variable"), "hint: " + e.Hint);
                    }
                    T.True(!server.Tcp.Pending(), "nothing dialed the server");
                }
                using (var refused = new Listener(null, accept: false))
                {
                    string url = "ws://127.0.0.1:" + refused.Port + "/";
                    refused.Tcp.Stop(); // a port bound a moment ago, now refused
                    Failed(Connect(url, null, new ClientOptions { TokenProvider = () => "tok" }), url);
                }
            });
            T.Run("connect: a refused port is a ConnectFailedException naming the URL; with several URLs, the last one's", () =>
            {
                int port = Server.FreePort();
                string url = "ws://127.0.0.1:" + port + "/";
                var f = Failed(Connect(url, "tok"), url);
                T.True(f.Reason.StartsWith("connection refused") && f.Hint.Contains("posecast serve --dev"), f.Message);
                T.True(f.Status == null, "no HTTP status");
                string other = "ws://127.0.0.1:" + Server.FreePort() + "/";
                Failed(Connect(new[] { url, other }, "tok"), other);
            });
            T.Run("connect: an HTTP refusal of the upgrade (429) is a ConnectFailedException", () =>
            {
                using (var server = new Listener("HTTP/1.1 429 Too Many Requests\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"))
                {
                    string url = "ws://127.0.0.1:" + server.Port + "/";
                    var f = Failed(Connect(url, "tok"), url);
                    // .NET names the status; Mono's ClientWebSocket does not (the hint then says 429/503).
                    T.True(f.Status == 429 || (f.Status == null && f.Hint.Contains("429")), f.Message);
                }
            });
            T.Run("connect: TLS to a server without it is a ConnectFailedException", () =>
            {
                using (var server = new Listener("HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"))
                {
                    string url = "wss://127.0.0.1:" + server.Port + "/";
                    var f = Failed(Connect(url, "tok"), url);
                    T.True(f.Reason.StartsWith("TLS failed") && f.Hint.Contains("ws://"), f.Message);
                }
            });
            T.Run("connect: no handshake within OpenTimeoutS is a ConnectFailedException (Mono ignores the token there)", () =>
            {
                using (var server = new Listener(null))
                {
                    string url = "ws://127.0.0.1:" + server.Port + "/";
                    var f = Failed(Connect(url, "tok", new ClientOptions { OpenTimeoutS = 0.2 }), url);
                    T.True(f.Reason.StartsWith("no WebSocket handshake within 0.2 s"), f.Message);
                }
            });
        }
    }
}
