// Unity-only: reads the headset and both controllers through Unity's XR input and
// streams them as posecast frames (layout "hmd3": no waist tracker). Everything it
// calls (the client, frame checks, frame conversion) is the tested library; make
// cs-test compiles this component against a stand-in UnityEngine (Tests~/UnityStub)
// and tests its device reads, but it was not run in Unity or on a headset.

using System.Collections.Generic;
using UnityEngine;
using UnityEngine.XR;

namespace Posecast.Client.Unity
{
    public sealed class PosecastXRStreamer : MonoBehaviour
    {
        public string Url = "ws://127.0.0.1:8765/";
        public string Token = "";            // minted by your game backend
        public string Room = "lobby";
        public string DisplayName = "Player";
        [Tooltip("Poses per second to receive: 60, 30, 20 or 15")]
        public float PoseRateHz = 60f;

        public PosecastClient Client { get; private set; }
        /// <summary>Every player's jitter buffer, fed in Update (read it from PosecastAvatarDriver).</summary>
        public readonly Interpolator Poses = new Interpolator();

        private readonly Vec3[] _pos = new Vec3[4];
        private readonly Quat[] _rot = new Quat[4];
        private bool _sending;
        private bool _floor; // the tracking origin is settled (floor level, or warned that it cannot be)

        private async void Start()
        {
            Client = await PosecastClient.ConnectAsync(Url, Token);
            await Client.JoinAsync(Room, DisplayName, layout: "hmd3", poseRateHz: PoseRateHz);
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
            if (Client == null || !Client.Connected) return;
            ClientEvent e;
            while (Client.TryGetEvent(out e)) Poses.Feed(e);
            if (_sending) return; // one frame in flight at a time; frames supersede each other
            if (!_floor) _floor = RequestFloor(InputDevices.GetDeviceAtXRNode(XRNode.Head).subsystem);
            int valid = 0;
            var nodes = new[] { XRNode.Head, XRNode.LeftHand, XRNode.RightHand };
            for (int i = 0; i < 3; i++)
            {
                Vector3 p; Quaternion q;
                if (Read(nodes[i], out p, out q))
                {
                    _pos[i] = UnityFrames.FromUnity(p);
                    _rot[i] = UnityFrames.FromUnity(q);
                    valid |= 1 << i;
                }
                else { _pos[i] = Vec3.Zero; _rot[i] = Quat.Identity; }
            }
            _pos[3] = Vec3.Zero; _rot[3] = Quat.Identity; // hmd3: the waist slot is ignored
            _sending = true;
            try { await Client.SendFrameAsync(_pos, _rot, valid); }
            finally { _sending = false; }
        }

        private async void OnDestroy()
        {
            if (Client != null) await Client.CloseAsync("quit");
        }
    }
}
