// Unity-only: reads the headset and both controllers through Unity's XR input and
// streams them as posecast frames (layout "hmd3": no waist tracker). With a Manager
// (PosecastAvatarManager) it sends through the manager's connection, which owns the
// events and the avatars; without one it connects by itself (Token) and feeds its own
// jitter buffer, passing every event on to EventReceived. Everything it
// calls (the client, frame checks, frame conversion) is the tested library; make
// cs-test compiles this component against a stand-in UnityEngine (Tests~/UnityStub)
// and tests its device reads, but it was not run in Unity or on a headset.

using System;
using System.Collections.Generic;
using System.Threading.Tasks;
using UnityEngine;
using UnityEngine.XR;

namespace Posecast.Client.Unity
{
    public sealed class PosecastXRStreamer : MonoBehaviour
    {
        [Tooltip("Send through this manager's connection (it joins, spawns avatars and raises the events); unset: connect here")]
        public PosecastAvatarManager Manager;
        public string Url = "ws://127.0.0.1:8765/";
        public string Token = "";            // minted by your game backend
        public string Room = "lobby";
        public string DisplayName = "Player";
        [Tooltip("Poses per second to receive: 60, 30, 20 or 15")]
        public float PoseRateHz = 60f;

        /// <summary>The connection frames go through: the Manager's, or this component's own.</summary>
        public PosecastClient Client { get { return Manager != null ? Manager.Client : _own; } }
        /// <summary>Every player's jitter buffer (the Manager's, or fed here in Update; read it from PosecastAvatarDriver).</summary>
        public Interpolator Poses { get { return Manager != null ? Manager.Poses : _poses; } }
        /// <summary>Without a Manager: every event this component drained, passed on after its jitter buffer took it.</summary>
        public event Action<ClientEvent> EventReceived;

        private PosecastClient _own;
        private readonly Interpolator _poses = new Interpolator();

        private readonly Vec3[] _pos = new Vec3[4];
        private readonly Quat[] _rot = new Quat[4];
        private bool _sending;
        private bool _floor; // the tracking origin is settled (floor level, or warned that it cannot be)

        private async void Start()
        {
            if (Manager != null) return;
            _own = await PosecastClient.ConnectAsync(Url, Token);
            await _own.JoinAsync(Room, DisplayName, layout: "hmd3", poseRateHz: PoseRateHz);
        }

        // A controller that lost tracking (out of the cameras' view) still reports its last
        // pose, frozen: it reads as untracked (its valid bit clear) when the runtime says so.
        // The head is read all the same (its rotation still tracked, its position held), as
        // fromXRFrame does in the TypeScript SDK.
        private static bool Read(XRNode node, out Vector3 p, out Quaternion q)
        {
            var d = InputDevices.GetDeviceAtXRNode(node);
            p = Vector3.zero; q = Quaternion.identity;
            bool tracked;
            if (!d.isValid) return false;
            if (node != XRNode.Head && d.TryGetFeatureValue(CommonUsages.isTracked, out tracked) && !tracked) return false;
            return d.TryGetFeatureValue(CommonUsages.devicePosition, out p)
                   && d.TryGetFeatureValue(CommonUsages.deviceRotation, out q);
        }

        // The protocol's y is the height above the floor (proto/README.md), and device
        // positions are in the tracking space: ask for a floor-level origin (Unity's
        // default on some runtimes is the eye level, y = 0 at the headset). False: no XR
        // input subsystem yet, ask again.
        internal static bool RequestFloor(XRInputSubsystem subsystem)
        {
            if (subsystem == null) return false;
            if (subsystem.GetTrackingOriginMode() != TrackingOriginModeFlags.Floor
                && !subsystem.TrySetTrackingOriginMode(TrackingOriginModeFlags.Floor))
                Debug.LogWarning("posecast: the XR runtime has no floor-level tracking origin; the avatar's height will be wrong");
            return true;
        }

        private async void Update()
        {
            var client = Client;
            if (client == null || !client.Connected) return;
            if (Manager == null) Drain(client);
            if (_sending) return; // one frame in flight at a time; frames supersede each other
            if (!_floor) _floor = RequestFloor(InputDevices.GetDeviceAtXRNode(XRNode.Head).subsystem);
            int valid = ReadTrackers(_pos, _rot);
            _sending = true;
            try { await client.SendFrameAsync(_pos, _rot, valid); }
            finally { _sending = false; }
        }

        // Without a Manager: every waiting event into the jitter buffer, then on to EventReceived.
        private void Drain(PosecastClient client)
        {
            ClientEvent e;
            while (client.TryGetEvent(out e))
            {
                _poses.Feed(e);
                var listeners = EventReceived;
                if (listeners != null) listeners(e);
            }
        }

        private static readonly XRNode[] Nodes = { XRNode.Head, XRNode.LeftHand, XRNode.RightHand };

        // The headset and both controllers now, in posecast's frame, into pos/rot (4 slots;
        // an unread one and the waist slot, which hmd3 ignores, as origin + identity).
        // Returns the valid bits.
        internal static int ReadTrackers(Vec3[] pos, Quat[] rot)
        {
            int valid = 0;
            for (int i = 0; i < Nodes.Length; i++)
            {
                Vector3 p; Quaternion q;
                if (Read(Nodes[i], out p, out q))
                {
                    pos[i] = UnityFrames.FromUnity(p);
                    rot[i] = UnityFrames.FromUnity(q);
                    valid |= 1 << i;
                }
                else { pos[i] = Vec3.Zero; rot[i] = Quat.Identity; }
            }
            pos[3] = Vec3.Zero; rot[3] = Quat.Identity;
            return valid;
        }

        /// <summary>
        /// Calibrate from the pose the user holds now: a T-pose (standing straight, arms
        /// out to the sides, facing forward). Call it from your calibration step; until
        /// then the server takes each controller's own axes for its hand's and the default
        /// body height. False when not joined, or when the headset or a controller is not
        /// tracked (nothing is sent; ask again).
        /// </summary>
        public Task<bool> CalibrateTPoseAsync()
        {
            if (Client == null || !Client.Connected) return Task.FromResult(false);
            var pos = new Vec3[4];
            var rot = new Quat[4];
            if (ReadTrackers(pos, rot) != 0b0111) return Task.FromResult(false);
            return Client.CalibrateTPoseAsync(pos, rot);
        }

        /// <summary>Calibrate by the user's standing height, metres (0.9 .. 2.5), instead.</summary>
        public Task<bool> CalibrateHeightAsync(double heightM)
        {
            if (Client == null || !Client.Connected) return Task.FromResult(false);
            return Client.CalibrateAsync(heightM);
        }

        private async void OnDestroy()
        {
            if (_own != null) await _own.CloseAsync("quit");
        }
    }
}
