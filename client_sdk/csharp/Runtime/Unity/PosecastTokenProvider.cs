// Unity-only: where a PosecastAvatarManager gets its join token, as an asset. Subclass
// it (your backend's token endpoint, a login service) and assign the asset in the
// inspector; game code can instead set PosecastAvatarManager.TokenProvider, a delegate.

using UnityEngine;

namespace Posecast.Client.Unity
{
    public abstract class PosecastTokenProvider : ScriptableObject
    {
        /// <summary>
        /// A join token for `room`, fresh on every call: the manager calls it at the join and
        /// at each rejoin after a lost connection. It runs on a worker thread (the client's
        /// reconnect loop), so it must not touch the scene. Throwing is retried as a lost
        /// connection is (TokenProviderException); returning null or "" ends the session
        /// (ConfigInvalidException).
        /// </summary>
        public abstract string GetToken(string room);
    }
}
