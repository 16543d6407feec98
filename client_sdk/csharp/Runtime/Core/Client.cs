// PosecastClient: a thin shell that moves bytes between a ClientWebSocket and the
// Sans-I/O ClientSession. No Unity types: the Unity components call it.
//
// Lifecycle:
//   ConnectAsync --> JoinAsync --> (SendFrameAsync)* + TryGetEvent/NextEventAsync --> CloseAsync
//                       |
//                       +-- connection lost / SERVER_SHUTDOWN / TIMED_OUT / SLOW_CONSUMER / INTERNAL:
//                           Reconnecting(attempt, delay) ... back-off ... rejoin --> Welcome
//
// Versions: the client offers posecast.v2 and posecast.v1 and speaks the one the
// server selects (v2: one poses message per tick, FK from the announced skeletons).
//
// Reconnect and resume: when a joined connection ends for a retryable reason the
// client waits an exponential back-off with jitter (BackoffInitialS doubling up to
// BackoffMaxS), opens a new connection (the next URL, for a cluster) and sends the
// same hello again (a fresh token when TokenProvider is set). Frames sent meanwhile
// are dropped, not queued, but their seq is used up, so seq keeps increasing. Errors
// a retry cannot fix (a refused token, ROOM_FULL, KICKED, REPLACED...) end the
// client: the next TryGetEvent/SendFrameAsync throws that typed error.
//
// Threads: one receive task per connection and one pinger (clock sync: four pings
// after each join, then one every PingIntervalS) run on the thread pool. Events wait
// in a bounded queue; a Unity Update drains it with TryGetEvent.
//
// Around it: ClientOptions.cs (the options), ConnectChecks.cs (the arguments checked
// before dialing, connect failures named), Transport.cs (dialing, whole messages
// read) and EventQueue.cs (the bounded event queue and the error that ended the session).

using System;
using System.Diagnostics;
using System.Net.WebSockets;
using System.Threading;
using System.Threading.Tasks;

namespace Posecast.Client
{
    public sealed class PosecastClient : IDisposable
    {
        private static readonly Stopwatch Mono = Stopwatch.StartNew();

        /// <summary>This process's monotonic clock, seconds (what frames' T and the clock use).</summary>
        public static double Now { get { return Mono.Elapsed.TotalSeconds; } }

        public readonly string[] Urls;
        public readonly ClientOptions Options;
        public readonly ClientSession Session;
        private readonly string _token;
        private readonly object _lock = new object();
        private readonly EventQueue _events;
        private readonly SemaphoreSlim _sendLock = new SemaphoreSlim(1, 1);
        private readonly Random _rng = new Random();
        private readonly CancellationTokenSource _closing = new CancellationTokenSource();
        private ClientWebSocket _ws;
        private int _urlIndex;
        private Func<Hello> _hello;
        private double? _forecastMs;  // v2: the forecast asked for (kept for a reconnect's hello)
        private volatile bool _joined;
        private Task _runTask, _pingTask;
        private readonly Action _tooLarge;  // Transport's report of a message over MaxReceiveBytes

        private PosecastClient(string[] urls, string token, ClientOptions options)
        {
            Urls = urls;
            _token = token;
            Options = options ?? new ClientOptions();
            Session = new ClientSession(Options.Seq0);
            _events = new EventQueue(Options, Session.Stats);
            _tooLarge = OnTooLarge;
        }

        /// <summary>
        /// Open a WebSocket to a posecast server. The token travels in hello, never in the
        /// URL. Several URLs (one cluster's nodes) are tried in order; reconnects move on.
        /// Throws ConfigInvalidException before dialing for a URL that is not ws:// or wss://
        /// with a host (http://..., host:port) or no token (null, empty) without a
        /// TokenProvider; ConnectFailedException (Url, Reason, Hint, Status) when the server
        /// cannot be reached or refuses the upgrade (with several URLs, the last one's).
        /// </summary>
        public static async Task<PosecastClient> ConnectAsync(string url, string token, ClientOptions options = null)
        {
            return await ConnectAsync(new[] { url }, token, options).ConfigureAwait(false);
        }

        public static async Task<PosecastClient> ConnectAsync(string[] urls, string token, ClientOptions options = null)
        {
            if (urls == null || urls.Length == 0) throw new ConfigInvalidException("no server URL", "pass one, such as " + ConnectChecks.ExampleUrl);
            var checkedUrls = new string[urls.Length]; // what the client keeps and dials: trimmed
            for (int i = 0; i < urls.Length; i++) checkedUrls[i] = ConnectChecks.CheckUrl(urls[i]);
            if ((options == null || options.TokenProvider == null) && string.IsNullOrWhiteSpace(token))
                throw new ConfigInvalidException("no token (got " + ConnectChecks.What(token) + ")", ConnectChecks.TokenHint);
            var c = new PosecastClient(checkedUrls, token, options);
            for (int i = 0; i < urls.Length; i++)
            {
                c._urlIndex = i;
                try { c._ws = await c.OpenAsync().ConfigureAwait(false); break; }
                catch (ConnectFailedException) when (i < urls.Length - 1) { }
            }
            return c;
        }

        /// <summary>
        /// `url` without leading or trailing whitespace (what the client keeps in Urls and
        /// dials), if the client can dial it: ws:// or wss:// (any case), a host, a port from
        /// 1 to 65535 (absent: 80 or 443), no #fragment; the Python and TypeScript SDKs take the same.
        /// Throws ConfigInvalidException otherwise, with a hint (an http:// URL: its ws://
        /// twin; host:port: the ws:// URL).
        /// </summary>
        public static string CheckUrl(string url) { return ConnectChecks.CheckUrl(url); }

        // --- state -------------------------------------------------------------------

        public string Url { get { return Urls[_urlIndex]; } }
        public bool Connected { get { return _joined; } }
        /// <summary>The connection's protocol version (1 or 2).</summary>
        public int Version { get { return Session.Version; } }
        public Welcome Welcome { get { return Session.Welcome; } }
        public string Player { get { var w = Session.Welcome; return w == null ? null : w.Player; } }
        public ClockSync Clock { get { return Session.Clock; } }
        public Stats Stats { get { return Session.Stats; } }
        /// <summary>
        /// Server time now on the clock sync's display clock (Clock.DisplayTime(Now); Now before
        /// the first pong): the time to sample the interpolator at each frame. It slews the offset
        /// estimate's steps (tens of ms when the best ping leaves the window) at 5 ms a second
        /// instead of moving every avatar by them; Clock.ToServer(PosecastClient.Now) is the
        /// estimate itself.
        /// </summary>
        public double ServerNow { get { lock (_lock) return Session.Clock.DisplayTime(Now); } }

        // --- connecting and joining ----------------------------------------------------

        private async Task<ClientWebSocket> OpenAsync()
        {
            var ws = await Transport.OpenAsync(Url, Options).ConfigureAwait(false);
            int version = Transport.VersionOf(ws);
            lock (_lock) Session.Connected(version);
            return ws;
        }

        private async Task<Welcome> HandshakeAsync(ClientWebSocket ws)
        {
            string token = _token;
            if (Options.TokenProvider != null)
            {
                try { token = Options.TokenProvider(); }
                catch (Exception e) // the backend's token endpoint down, say: worth a retry
                {
                    throw new TokenProviderException("the TokenProvider threw " + e.GetType().Name + ": " + e.Message, e);
                }
            }
            if (string.IsNullOrWhiteSpace(token))
                throw new ConfigInvalidException("the TokenProvider returned " + ConnectChecks.What(token), "it must return the join token, a non-empty string");
            Hello hello;
            lock (_lock) { hello = _hello(); hello.Token = token; }
            try
            {
                await SendRawAsync(ws, Codec.Encode(hello)).ConfigureAwait(false);
                using (var cts = CancellationTokenSource.CreateLinkedTokenSource(_closing.Token))
                {
                    cts.CancelAfter(TimeSpan.FromSeconds(Options.JoinTimeoutS));
                    while (true)
                    {
                        byte[] data = await Transport.ReceiveMessageAsync(ws, Options, _tooLarge, cts.Token).ConfigureAwait(false);
                        if (data == null) throw new ConnectionLostException(Url + " closed the connection during the join");
                        Received r;
                        lock (_lock) r = Session.Receive(data, Now);
                        var reply = ClientSession.ClassifyJoinReply(r);
                        if (reply is Exception) throw (Exception)reply;
                        if (reply is Welcome)
                        {
                            foreach (var e in r.Events) _events.Push(e);
                            return (Welcome)reply;
                        }
                    }
                }
            }
            catch (OperationCanceledException e) when (!_closing.IsCancellationRequested)
            {
                throw new ConnectionLostException("no welcome from " + Url + " within " + Options.JoinTimeoutS + " s", e);
            }
            catch (Exception e) when (e is WebSocketException || e is System.IO.IOException)
            {
                throw new ConnectionLostException(Url + " closed the connection during the join (" + e.Message + ")", e);
            }
        }

        /// <summary>
        /// Join a room as `name` (shown to others) and start receiving.
        /// layout: "hmd3+waist" (head, hands, waist; the default) or "hmd3" (headset and
        /// controllers only), or a tracker set (TrackerSet, e.g.
        /// "head,left_hand,right_hand,waist,left_foot,right_foot"): SendFrameAsync then
        /// takes one row per site of the set (ArgumentException for a bad set).
        /// rateHz: frames per second this client sends (null: 60).
        /// poseRateHz (v2): poses per second to receive, 60, 30, 20 or 15 (null: 60).
        /// forecastMs (v2): poses forecast this many ms ahead, 0-100, to cancel this client's
        /// network and render delay (null: none; ArgumentOutOfRangeException outside, nothing
        /// sent). The server rounds it to whole ticks (Welcome.ForecastMs) and stamps each
        /// pose's T that far past its tick.
        /// Throws the typed refusal (UnauthenticatedException, RoomFullException...).
        /// </summary>
        public async Task<Welcome> JoinAsync(string room, string name, string layout = null, double? rateHz = null,
                                             string[] watch = null, double? poseRateHz = null,
                                             double? forecastMs = null)
        {
            if (forecastMs.HasValue) ClientSession.CheckForecast(forecastMs.Value);
            if (_closing.IsCancellationRequested) throw new ClientClosedException("the client is closed");
            if (_ws == null || _hello != null) throw new InvalidOperationException("JoinAsync once per client, after ConnectAsync");
            var set = TrackerSet.Of(layout);
            lock (_lock) Session.Set = set;
            _forecastMs = forecastMs;
            _hello = () => Session.BuildHello("", room, name, layout, rateHz, watch, poseRateHz, _forecastMs);
            Welcome w;
            try { w = await HandshakeAsync(_ws).ConfigureAwait(false); }
            catch { _hello = null; throw; }
            _joined = true;
            var ws = _ws;
            _runTask = Task.Run(() => RunAsync(ws));
            if (Options.PingIntervalS > 0) _pingTask = Task.Run(() => PingerAsync());
            return w;
        }

        // --- the connection task ---------------------------------------------------------

        private async Task RunAsync(ClientWebSocket ws)
        {
            while (true)
            {
                var cause = await ReadAsync(ws).ConfigureAwait(false);
                _joined = false;
                try { ws.Dispose(); } catch (Exception) { }
                if (_closing.IsCancellationRequested) return;
                if (!(Options.Reconnect && ClientSession.IsRetryable(cause))) { _events.Fail(cause); return; }
                ws = await ReconnectAsync(cause).ConfigureAwait(false);
                if (ws == null) return;
                _ws = ws;
                _joined = true;
            }
        }

        private async Task<Exception> ReadAsync(ClientWebSocket ws)
        {
            Exception cause = null;
            try
            {
                while (true)
                {
                    byte[] data = await Transport.ReceiveMessageAsync(ws, Options, _tooLarge, _closing.Token).ConfigureAwait(false);
                    if (data == null) break;
                    Received r;
                    lock (_lock) r = Session.Receive(data, Now);
                    foreach (var e in r.Events) _events.Push(e);
                    if (r.Reply != null) await TrySendAsync(ws, r.Reply).ConfigureAwait(false);
                    if (r.End != null && cause == null) cause = r.End; // the server closes right after
                }
            }
            catch (OperationCanceledException) { }
            catch (Exception e) when (e is WebSocketException || e is System.IO.IOException || e is ObjectDisposedException)
            {
                if (cause == null) cause = new ConnectionLostException("connection lost: " + e.Message, e);
            }
            return cause ?? new ConnectionLostException("connection closed");
        }

        /// <summary>A message over MaxReceiveBytes was skipped: counted and reported as a Bad event.</summary>
        private void OnTooLarge()
        {
            lock (_lock) Session.Stats.BadMessages++;
            _events.Push(new ClientEvent { Kind = EventKind.Bad, Cause = new TooLargeException("a message over " + Options.MaxReceiveBytes + " bytes") });
        }

        private async Task<ClientWebSocket> ReconnectAsync(Exception cause)
        {
            int attempt = 0;
            while (!_closing.IsCancellationRequested)
            {
                attempt++;
                if (Options.MaxReconnectAttempts.HasValue && attempt > Options.MaxReconnectAttempts.Value) { _events.Fail(cause); return null; }
                double delay;
                lock (_lock) delay = ClientSession.BackoffDelay(attempt, Options.BackoffInitialS, Options.BackoffMaxS, _rng);
                _events.Push(new ClientEvent { Kind = EventKind.Reconnecting, Attempt = attempt, DelayS = delay, Cause = cause });
                try { await Task.Delay(TimeSpan.FromSeconds(delay), _closing.Token).ConfigureAwait(false); }
                catch (OperationCanceledException) { return null; }
                _urlIndex = (_urlIndex + 1) % Urls.Length;
                ClientWebSocket ws = null;
                try
                {
                    ws = await OpenAsync().ConfigureAwait(false);
                    await HandshakeAsync(ws).ConfigureAwait(false);
                    lock (_lock) Session.Stats.Reconnects++;
                    return ws;
                }
                catch (Exception e)
                {
                    if (ws != null) { try { ws.Abort(); ws.Dispose(); } catch (Exception) { } }
                    if (_closing.IsCancellationRequested) return null;
                    if (e is OperationCanceledException) e = new TimeoutException("no welcome in time");
                    if (!ClientSession.IsRetryable(e)) { _events.Fail(e); return null; }
                    cause = e;
                }
            }
            return null;
        }

        private async Task PingerAsync()
        {
            try
            {
                while (!_closing.IsCancellationRequested)
                {
                    while (!_joined) await Task.Delay(50, _closing.Token).ConfigureAwait(false);
                    for (int k = 0; k < 4 && _joined; k++)
                    {
                        await PingAsync().ConfigureAwait(false);
                        await Task.Delay(100, _closing.Token).ConfigureAwait(false);
                    }
                    while (_joined)
                    {
                        await Task.Delay(TimeSpan.FromSeconds(Options.PingIntervalS), _closing.Token).ConfigureAwait(false);
                        await PingAsync().ConfigureAwait(false);
                    }
                }
            }
            catch (OperationCanceledException) { }
        }

        private Task PingAsync()
        {
            var ws = _ws;
            return ws == null ? Task.FromResult(false) : TrySendAsync(ws, new Ping { T0 = Now });
        }

        // --- the application's side -------------------------------------------------------

        private void CheckUsable()
        {
            if (_events.Failure != null) throw _events.Failure;
            if (_closing.IsCancellationRequested) throw new ClientClosedException("the client is closed");
            if (_hello == null) throw new InvalidOperationException("JoinAsync first");
        }

        private async Task SendRawAsync(ClientWebSocket ws, byte[] data)
        {
            await _sendLock.WaitAsync().ConfigureAwait(false);
            try { await ws.SendAsync(new ArraySegment<byte>(data), WebSocketMessageType.Binary, true, CancellationToken.None).ConfigureAwait(false); }
            finally { _sendLock.Release(); }
        }

        private async Task<bool> TrySendAsync(ClientWebSocket ws, Message msg)
        {
            try { await SendRawAsync(ws, Codec.Encode(msg)).ConfigureAwait(false); return true; }
            catch (Exception e) when (e is WebSocketException || e is ObjectDisposedException || e is InvalidOperationException || e is System.IO.IOException)
            {
                return false; // the receive task notices and reconnects
            }
        }

        /// <summary>Send any client message (calibrate, selector, kick, pose_rate, resync...);
        /// false when it was dropped because the client is reconnecting.</summary>
        public async Task<bool> SendAsync(Message msg)
        {
            CheckUsable();
            var ws = _ws;
            if (ws == null || !_joined) return false;
            return await TrySendAsync(ws, msg).ConfigureAwait(false);
        }

        /// <summary>
        /// Send one tracker frame (4 world positions and orientations in slot order HEAD,
        /// LEFT_HAND, RIGHT_HAND, WAIST, or one row per site of the player's tracker set,
        /// an IMU's world acceleration in m/s^2 for its position; valid bit i set: row i
        /// tracked, null: all). Returns its seq,
        /// or null when it was dropped because the client is reconnecting.
        /// Throws OutOfRangeException / NotNormalisedException for an unusable tracked
        /// slot (nothing is sent), or the error that ended the session.
        /// </summary>
        public async Task<long?> SendFrameAsync(Vec3[] positions, Quat[] orientations, int? valid = null)
        {
            CheckUsable();
            double now = Now;
            Frame f;
            lock (_lock) f = Session.BuildFrame(positions, orientations, now, valid);
            var ws = _ws;
            if (ws != null && _joined && await TrySendAsync(ws, f).ConfigureAwait(false))
            {
                lock (_lock) Session.Sent(f, now);
                return f.Seq;
            }
            lock (_lock) Session.Dropped(f);
            return null;
        }

        /// <summary>Calibrate the avatar by standing height, metres (0.9 .. 2.5).</summary>
        public Task<bool> CalibrateAsync(double heightM) { return SendAsync(new Calibrate { HeightM = heightM }); }

        /// <summary>
        /// Calibrate the avatar from one frame of the user standing in a T-pose (arms out
        /// to the sides, facing forward): the scale from the head's height and, for a
        /// headset-only player or a tracker set, each device's rotation offset to its body
        /// part (without it a controller's own axes are taken for the hand's). All rows
        /// tracked, checked as frames are (OutOfRange, NotNormalised; nothing is sent); an
        /// implausible T-pose comes back as a CALIBRATION_FAILED error event.
        /// </summary>
        public Task<bool> CalibrateTPoseAsync(Vec3[] positions, Quat[] orientations)
        {
            Calibrate c;
            lock (_lock) c = Session.BuildTPose(positions, orientations);
            return SendAsync(c);
        }

        /// <summary>v2: receive poses at 60, 30, 20 or 15 Hz from now on.</summary>
        public Task<bool> SetPoseRateAsync(double rateHz) { return SendAsync(new PoseRate { RateHz = rateHz }); }

        /// <summary>v2: receive poses forecast ms (0-100) ahead from now on, 0 for none, and
        /// after a reconnect too (ArgumentOutOfRangeException outside, nothing sent).</summary>
        public Task<bool> SetForecastAsync(double ms)
        {
            ClientSession.CheckForecast(ms);
            _forecastMs = ms;
            return SendAsync(new Forecast { Ms = ms });
        }

        /// <summary>The next event if one is waiting (for a game loop). Throws the error that ended the session.</summary>
        public bool TryGetEvent(out ClientEvent e) { return _events.TryGet(out e); }

        /// <summary>The next event, waiting for it; null after CloseAsync or when `ct` is cancelled.</summary>
        public async Task<ClientEvent> NextEventAsync(CancellationToken ct = default(CancellationToken))
        {
            return await _events.NextAsync(_closing.Token, ct).ConfigureAwait(false);
        }

        /// <summary>Say bye and close. The server refuses this token afterwards (replay guard).</summary>
        public async Task CloseAsync(string reason = null)
        {
            if (_closing.IsCancellationRequested) return;
            var ws = _ws;
            if (ws != null && _hello != null && _joined)
                await TrySendAsync(ws, new Bye { Reason = reason }).ConfigureAwait(false);
            _closing.Cancel();
            _joined = false;
            if (ws != null)
            {
                try
                {
                    using (var cts = new CancellationTokenSource(TimeSpan.FromSeconds(2)))
                        await ws.CloseOutputAsync(WebSocketCloseStatus.NormalClosure, reason ?? "", cts.Token).ConfigureAwait(false);
                }
                catch (Exception) { }
            }
            foreach (var t in new[] { _runTask, _pingTask })
            {
                if (t == null) continue;
                try { await Task.WhenAny(t, Task.Delay(3000)).ConfigureAwait(false); } catch (Exception) { }
            }
            if (ws != null) { try { ws.Abort(); ws.Dispose(); } catch (Exception) { } }
            _events.Wake();
        }

        public void Dispose() { CloseAsync().Wait(5000); }
    }
}
