// Unity-only: the avatars of everyone else in the room, spawned and removed by
// themselves. The manager owns the connection (Connect / Disconnect, a token from a
// delegate, an asset or a fixed string), drains the client's events once per frame
// and, for each, in this order:
//
//   1. feeds the jitter buffer (Poses: a pose is kept, a leave forgets, a welcome clears);
//   2. keeps the avatars in step with the room:
//        Welcome (the join, and each rejoin)  -> Joined(own id), then one avatar per member
//        Presence join / leave                -> spawn + PlayerJoined / remove + PlayerLeft
//        Reconnecting (the connection lost)   -> every avatar removed (PlayerLeft each),
//                                                then Reconnecting; the rejoin's welcome
//                                                spawns whoever is still there
//        Error (non-fatal)                    -> Error(code, message)
//   3. passes the event on, unchanged, to EventReceived (game code sees every event).
//
// An error that ends the session (a refused token, KICKED, the server gone for good)
// raises Error, removes every avatar and raises Disconnected. Each avatar is a copy of
// AvatarPrefab (any Humanoid rig) under AvatarParent, with a PosecastAvatarDriver that
// LateUpdate poses from the jitter buffer at the server's time; this player's own
// avatar only with ShowLocalAvatar. Stream the headset with a PosecastXRStreamer whose
// Manager is this one. make cs-test tests it against a stand-in UnityEngine and a real
// posecast serve (Tests~/ManagerTests.cs), not in Unity.

using System;
using System.Collections.Generic;
using System.Threading.Tasks;
using UnityEngine;
using UnityEngine.Events;

namespace Posecast.Client.Unity
{
    public sealed class PosecastAvatarManager : MonoBehaviour
    {
        [Header("Server")]
        public string Url = "ws://127.0.0.1:8765/";
        public string Room = "lobby";
        public string DisplayName = "Player";
        [Tooltip("hmd3: headset and controllers (PosecastXRStreamer); hmd3+waist adds a waist tracker")]
        public string Layout = "hmd3";
        [Tooltip("Poses per second to receive: 60, 30, 20 or 15")]
        public float PoseRateHz = 60f;
        [Tooltip("Connect and join in Start; off: call Connect() from game code")]
        public bool ConnectOnStart = true;

        [Header("Token (the first set is used: TokenProvider, TokenAsset, Token)")]
        [Tooltip("An asset that asks your backend for a fresh token at every join")]
        public PosecastTokenProvider TokenAsset;
        [Tooltip("A fixed token (development: posecast token, or DevTokens.Mint)")]
        public string Token = "";
        /// <summary>Game code's token source, called at the join and each rejoin (a worker thread).</summary>
        public Func<string> TokenProvider;

        [Header("Avatars")]
        [Tooltip("Any Humanoid rig (a prefab, or an inactive template in the scene); one copy per player in the room")]
        public GameObject AvatarPrefab;
        [Tooltip("Where the copies go (unset: under this GameObject); poses play in its frame")]
        public Transform AvatarParent;
        [Tooltip("Also show this player's own avatar (as the server sees it)")]
        public bool ShowLocalAvatar;

        [Header("Events")]
        public UnityEvent Connected = new UnityEvent();
        public PosecastPlayerEvent Joined = new PosecastPlayerEvent();
        public PosecastPlayerEvent PlayerJoined = new PosecastPlayerEvent();
        public PosecastPlayerEvent PlayerLeft = new PosecastPlayerEvent();
        public PosecastErrorEvent Error = new PosecastErrorEvent();
        public PosecastReconnectingEvent Reconnecting = new PosecastReconnectingEvent();
        public UnityEvent Disconnected = new UnityEvent();

        /// <summary>Every client event, after the manager has handled it (poses included).</summary>
        public event Action<ClientEvent> EventReceived;

        /// <summary>The connection (null before Connect and after Disconnect or a fatal error).</summary>
        public PosecastClient Client { get; private set; }
        /// <summary>Every player's jitter buffer, fed in Update.</summary>
        public readonly Interpolator Poses = new Interpolator();
        /// <summary>The error that ended the last session, or null.</summary>
        public Exception LastError { get; private set; }

        // The players shown, by id; a null driver when there is no AvatarPrefab.
        private readonly Dictionary<string, PosecastAvatarDriver> _avatars = new Dictionary<string, PosecastAvatarDriver>();
        private readonly List<string> _scratch = new List<string>();
        private bool _connecting;

        /// <summary>The players in the room with an avatar (this one's own only with ShowLocalAvatar).</summary>
        public IReadOnlyDictionary<string, PosecastAvatarDriver> Avatars { get { return _avatars; } }

        private void Start()
        {
            if (ConnectOnStart) Forget(Connect());
        }

        /// <summary>
        /// Connect to Url and join Room; true when joined. A failure raises Error (and returns
        /// false): the server unreachable, a refused token, a full room; after Connected, then
        /// Disconnected.
        /// </summary>
        public async Task<bool> Connect()
        {
            if (Client != null || _connecting) return Client != null;
            _connecting = true;
            var options = new ClientOptions { TokenProvider = ResolveTokenProvider() };
            PosecastClient client = null;
            try
            {
                client = await PosecastClient.ConnectAsync(Url, Token, options);
                Client = client;
                Connected.Invoke();
                await client.JoinAsync(Room, DisplayName, layout: Layout, poseRateHz: PoseRateHz);
                return true;
            }
            catch (Exception e)
            {
                bool ours = client == null || Client == client; // else Disconnect() came first and said so
                if (client != null && Client == client) Client = null;
                if (client != null) Forget(client.CloseAsync());
                if (!ours) return false;
                Fail(e);
                if (client != null) Disconnected.Invoke(); // Connected was raised: close the pair
                return false;
            }
            finally { _connecting = false; }
        }

        private Func<string> ResolveTokenProvider()
        {
            if (TokenProvider != null) return TokenProvider;
            if (TokenAsset != null)
            {
                var asset = TokenAsset;
                var room = Room;
                return () => asset.GetToken(room);
            }
            return null;
        }

        /// <summary>Leave the room and close: every avatar removed (PlayerLeft each), then Disconnected.</summary>
        public async Task Disconnect()
        {
            var client = Client;
            if (client == null) return;
            Client = null;
            RemoveAll();
            Poses.Clear();
            await client.CloseAsync("disconnect");
            Disconnected.Invoke();
        }

        private void Update() { Pump(); }

        private void LateUpdate()
        {
            var client = Client;
            if (client != null) DriveAvatars(client.ServerNow);
        }

        private void OnDestroy() { Forget(Disconnect()); }

        /// <summary>Drain and handle every waiting event (Update calls it once per frame).</summary>
        public void Pump()
        {
            var client = Client;
            while (client != null && Client == client)
            {
                ClientEvent e;
                try
                {
                    if (!client.TryGetEvent(out e)) return;
                }
                catch (Exception end)
                {
                    Client = null;
                    RemoveAll();
                    Poses.Clear();
                    Forget(client.CloseAsync());
                    Fail(end);
                    Disconnected.Invoke();
                    return;
                }
                OnEvent(e);
            }
        }

        /// <summary>Pose every avatar as its player is shown at server time `now` (LateUpdate).</summary>
        public void DriveAvatars(double now)
        {
            foreach (var kv in _avatars)
            {
                if (kv.Value == null) continue;
                InterpolatedPose shown;
                if (!_shown.TryGetValue(kv.Key, out shown)) _shown[kv.Key] = shown = new InterpolatedPose();
                if (Poses.PoseAt(kv.Key, now, shown)) kv.Value.Apply(shown.Positions, shown.Rotations);
            }
        }

        // Each avatar's pose as last shown, filled in place every frame (no garbage).
        private readonly Dictionary<string, InterpolatedPose> _shown = new Dictionary<string, InterpolatedPose>();

        /// <summary>One event: the jitter buffer, the avatars, the UnityEvents, then EventReceived.</summary>
        internal void OnEvent(ClientEvent e)
        {
            Poses.Feed(e);
            switch (e.Kind)
            {
                case EventKind.Welcome:
                {
                    var w = e.Welcome;
                    _scratch.Clear();
                    foreach (var kv in _avatars)
                        if (!IsMember(w, kv.Key) || !Shows(w.Player, kv.Key)) _scratch.Add(kv.Key);
                    foreach (var gone in _scratch) Remove(gone);
                    Joined.Invoke(w.Player);
                    foreach (var m in w.Members)
                        if (Shows(w.Player, m.Player)) Spawn(m.Player, m.Name);
                    break;
                }
                case EventKind.Presence:
                {
                    var p = e.Presence;
                    if (p.Event == "join" && Shows(Client == null ? null : Client.Player, p.Player)) Spawn(p.Player, p.Name);
                    else if (p.Event == "leave") Remove(p.Player);
                    break;
                }
                case EventKind.Reconnecting:
                    RemoveAll();
                    Reconnecting.Invoke(e.Attempt, (float)e.DelayS);
                    break;
                case EventKind.Error:
                    Error.Invoke(e.Error.Code, e.Error.Text);
                    break;
            }
            var listeners = EventReceived;
            if (listeners != null) listeners(e);
        }

        private bool Shows(string self, string player) { return ShowLocalAvatar || player != self; }

        private static bool IsMember(Welcome w, string player)
        {
            foreach (var m in w.Members) if (m.Player == player) return true;
            return false;
        }

        private void Spawn(string player, string name)
        {
            if (_avatars.ContainsKey(player)) return;
            PosecastAvatarDriver driver = null;
            if (AvatarPrefab != null)
            {
                var avatar = Instantiate(AvatarPrefab, AvatarParent != null ? AvatarParent : transform);
                avatar.SetActive(true); // a template kept inactive in the scene gives inactive copies
                avatar.name = "posecast " + player + (string.IsNullOrEmpty(name) ? "" : " (" + name + ")");
                driver = avatar.GetComponent<PosecastAvatarDriver>();
                if (driver == null) driver = avatar.AddComponent<PosecastAvatarDriver>();
                driver.Player = player;
                if (driver.Avatar == null) Debug.LogWarning("posecast: AvatarPrefab has no Animator; " + player + "'s avatar will not move");
            }
            _avatars[player] = driver;
            PlayerJoined.Invoke(player);
        }

        private void Remove(string player)
        {
            PosecastAvatarDriver driver;
            if (!_avatars.TryGetValue(player, out driver)) return;
            _avatars.Remove(player);
            _shown.Remove(player);
            if (driver != null) Destroy(driver.gameObject);
            PlayerLeft.Invoke(player);
        }

        private void RemoveAll()
        {
            _scratch.Clear();
            foreach (var kv in _avatars) _scratch.Add(kv.Key);
            foreach (var player in _scratch) Remove(player);
        }

        private void Fail(Exception e)
        {
            LastError = e;
            var wire = e as ProtocolException;
            Error.Invoke(wire != null ? wire.Code : e.GetType().Name, e.Message);
        }

        // A task nobody awaits (Start, OnDestroy): its failure is logged, not lost.
        private static async void Forget(Task task)
        {
            try { await task; }
            catch (Exception e) { Debug.LogException(e); }
        }
    }
}
