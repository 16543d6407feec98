// The WebSocket under a PosecastClient: dialing it (the posecast subprotocols offered,
// the handshake raced against OpenTimeoutS, failures named by ConnectChecks) and
// reading whole binary messages from it (one over MaxReceiveBytes skipped). No session
// state: PosecastClient feeds what it reads to its ClientSession.

using System;
using System.Net.Sockets;
using System.Net.WebSockets;
using System.Security.Authentication;
using System.Threading;
using System.Threading.Tasks;

namespace Posecast.Client
{
    internal static class Transport
    {
        /// <summary>
        /// A WebSocket open to `url` whose server selected one of options.Versions'
        /// subprotocols. Throws ConnectFailedException (unreachable, refused, no handshake
        /// within OpenTimeoutS) or VersionUnsupportedException.
        /// </summary>
        public static async Task<ClientWebSocket> OpenAsync(string url, ClientOptions options)
        {
            var ws = new ClientWebSocket();
            foreach (var v in options.Versions) ws.Options.AddSubProtocol(Protocol.Subprotocol(v));
            try
            {
                var limit = TimeSpan.FromSeconds(options.OpenTimeoutS);
                using (var cts = new CancellationTokenSource(limit))
                using (var timer = new CancellationTokenSource())
                {
                    var connect = ws.ConnectAsync(new Uri(url), cts.Token);
                    // Mono's ClientWebSocket stops heeding the token once TCP is up: a server
                    // that never answers the upgrade would hold ConnectAsync for good. Race a timer.
                    if (await Task.WhenAny(connect, Task.Delay(limit, timer.Token)).ConfigureAwait(false) != connect)
                    {
                        Observe(connect); // it ends when the server hangs up, if ever
                        throw new TimeoutException("no WebSocket handshake in time");
                    }
                    timer.Cancel();
                    await connect.ConfigureAwait(false);
                }
            }
            catch (Exception e) when (e is WebSocketException || e is System.IO.IOException || e is SocketException
                                      || e is OperationCanceledException || e is AuthenticationException
                                      || e is TimeoutException)
            {
                ws.Abort();
                ws.Dispose();
                throw ConnectChecks.ConnectFailure(url, e, options.OpenTimeoutS);
            }
            int version = VersionOf(ws);
            if (version == 0 || Array.IndexOf(options.Versions, version) < 0)
            {
                ws.Abort();
                throw new VersionUnsupportedException("the server selected no posecast subprotocol we offered (" + ws.SubProtocol + ")");
            }
            return ws;
        }

        /// <summary>The protocol version the server selected: 1, 2, or 0 for neither.</summary>
        public static int VersionOf(ClientWebSocket ws)
        {
            return ws.SubProtocol == Protocol.SubprotocolV2 ? Protocol.V2
                 : ws.SubProtocol == Protocol.SubprotocolV1 ? Protocol.V1 : 0;
        }

        /// <summary>
        /// One whole message, or null when the server closed. One over
        /// options.MaxReceiveBytes is read to its end, dropped, and reported to `onTooLarge`;
        /// a text message closes the connection (InvalidMessageType) and throws WebSocketException.
        /// </summary>
        public static async Task<byte[]> ReceiveMessageAsync(ClientWebSocket ws, ClientOptions options, Action onTooLarge,
                                                             CancellationToken ct)
        {
            var buf = new byte[8192];
            while (true)
            {
                int len = 0;
                bool tooLarge = false;
                WebSocketReceiveResult res;
                do
                {
                    if (len == buf.Length)
                    {
                        if (buf.Length < options.MaxReceiveBytes) Array.Resize(ref buf, Math.Min(buf.Length * 2, options.MaxReceiveBytes));
                        else { tooLarge = true; len = 0; } // keep reading, keep nothing
                    }
                    res = await ws.ReceiveAsync(new ArraySegment<byte>(buf, len, buf.Length - len), ct).ConfigureAwait(false);
                    if (res.MessageType == WebSocketMessageType.Close) return null;
                    len += res.Count;
                } while (!res.EndOfMessage);
                if (res.MessageType == WebSocketMessageType.Text)
                {
                    try { await ws.CloseOutputAsync(WebSocketCloseStatus.InvalidMessageType, "text", CancellationToken.None).ConfigureAwait(false); }
                    catch (Exception) { }
                    throw new WebSocketException("the server sent a text message");
                }
                if (tooLarge)
                {
                    onTooLarge();
                    continue;
                }
                var data = new byte[len];
                Buffer.BlockCopy(buf, 0, data, 0, len);
                return data;
            }
        }

        private static void Observe(Task task)
        {
            task.ContinueWith(t => t.Exception, TaskContinuationOptions.OnlyOnFaulted);
        }
    }
}
