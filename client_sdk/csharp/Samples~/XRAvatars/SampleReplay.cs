// Streams a tracker recording as if a headset were worn: through a manager's
// connection (this player's own frames, desktop mode), or through a connection of its
// own (a second player in the room, a "bot"). One frame in flight at a time, at the
// display rate.

using System.Threading.Tasks;
using Posecast.Client;
using Posecast.Client.Unity;
using UnityEngine;

namespace Posecast.Samples
{
    public sealed class SampleReplay : MonoBehaviour
    {
        [Tooltip("Send through this manager's connection; unset: Connect() opens one of its own")]
        public PosecastAvatarManager Manager;
        [Tooltip("Metres added to every position (posecast's frame), to stand beside the others")]
        public Vector3 OffsetM;
        [Tooltip("Seconds into the recording to start at")]
        public float StartAtS;

        public TrackerRecording Recording;
        public PosecastClient Own { get; private set; }

        private readonly Vec3[] _pos = new Vec3[Protocol.NumTrackers];
        private readonly Quat[] _rot = new Quat[Protocol.NumTrackers];
        private float _started = -1f;
        private bool _sending;

        /// <summary>A connection of its own (a bot): connect and join `room` as `name`.</summary>
        public async Task Connect(string url, string token, string room, string name)
        {
            Own = await PosecastClient.ConnectAsync(url, token);
            await Own.JoinAsync(room, name, layout: "hmd3");
        }

        private PosecastClient Client { get { return Manager != null ? Manager.Client : Own; } }

        private async void Update()
        {
            var client = Client;
            if (Recording == null || client == null || !client.Connected || _sending) return;
            if (Own != null) { ClientEvent e; while (Own.TryGetEvent(out e)) { } } // a bot shows nothing
            if (_started < 0f) _started = Time.time;
            var offset = new Vec3(OffsetM.x, OffsetM.y, OffsetM.z);
            int valid = Recording.FrameAt(StartAtS + Time.time - _started, _pos, _rot, offset);
            _sending = true;
            try { await client.SendFrameAsync(_pos, _rot, valid); }
            finally { _sending = false; }
        }

        private async void OnDestroy()
        {
            if (Own != null) await Own.CloseAsync("quit");
        }
    }
}
