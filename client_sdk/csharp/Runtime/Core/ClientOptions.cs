// ClientOptions: what a PosecastClient is configured with (reconnect back-off,
// timeouts, the versions offered, the event queue's bound), with its defaults.

using System;

namespace Posecast.Client
{
    /// <summary>The options of a PosecastClient, with their defaults.</summary>
    public sealed class ClientOptions
    {
        /// <summary>
        /// Called at every join for a fresh token (else the token given to ConnectAsync). One
        /// that throws gives TokenProviderException (InnerException: what it threw), retried on
        /// a rejoin like a lost connection; one that returns no token, ConfigInvalidException,
        /// which ends the session.
        /// </summary>
        public Func<string> TokenProvider;
        /// <summary>Protocol versions offered, best first ({2, 1}); {1} pins posecast.v1.</summary>
        public int[] Versions = { Protocol.V2, Protocol.V1 };
        public bool Reconnect = true;
        public double BackoffInitialS = 0.25;
        public double BackoffMaxS = 8.0;
        /// <summary>Give up after this many failed attempts in a row (null: never).</summary>
        public int? MaxReconnectAttempts;
        /// <summary>Seconds between clock-sync pings (2; 0 turns pings off).</summary>
        public double PingIntervalS = 2.0;
        public double OpenTimeoutS = 5.0;
        public double JoinTimeoutS = 5.0;
        /// <summary>Events kept before the oldest are dropped (4096).</summary>
        public int MaxEvents = 4096;
        /// <summary>seq of the first frame (0).</summary>
        public long Seq0;
        /// <summary>The largest WebSocket message read; beyond it a message is skipped as TOO_LARGE.</summary>
        public int MaxReceiveBytes = 65536;
    }
}
