// Bytes <-> messages for protocols v1 and v2. Pure functions: no sockets, no clocks.
//
// Encode writes the canonical bytes (proto/README.md, "Canonical encoding"). Decode
// accepts any valid encoding and reports the first rule broken, in the spec's order:
//   1. more bytes than the size limit: TOO_LARGE (v2: 16384 for a server message;
//      a client's message stays within max_message_bytes);
//   2. not exactly one msgpack value (MALFORMED), or a str, bin, array or map over
//      its structural bound (TOO_LARGE);
//   3. the root is not a map: MALFORMED;
//   4. nesting deeper than 8, or a non-string key, anywhere: MALFORMED;
//   5. type missing, nil or not a str: BAD_FIELD; a type this version lacks: UNKNOWN_TYPE;
//   6. the fields of that type.

namespace Posecast.Client
{
    public static class Codec
    {
        /// <summary>The canonical msgpack bytes of a message.</summary>
        public static byte[] Encode(Message msg)
        {
            var w = new MsgPackWriter();
            w.Write(Wire.ToWire(msg));
            return w.ToArray();
        }

        /// <summary>The canonical wire map of a message (keys in canonical order), before msgpack.</summary>
        public static MsgValue ToWire(Message msg) { return Wire.ToWire(msg); }

        /// <summary>Parse and validate one whole WebSocket message.</summary>
        /// <param name="version">the connection's protocol version, 1 or 2</param>
        /// <param name="limits">the limits in force (the defaults until the welcome)</param>
        /// <exception cref="ProtocolException">the typed error for the first rule broken</exception>
        public static Message Decode(byte[] data, int version = Protocol.V1, Limits limits = null)
        {
            return Decode(data, 0, data.Length, version, limits);
        }

        public static Message Decode(byte[] data, int offset, int count, int version = Protocol.V1, Limits limits = null)
        {
            limits = limits ?? Limits.Default;
            bool v2 = version >= Protocol.V2;
            int cap = v2 ? Protocol.MaxServerMessageBytesV2 : limits.MaxMessageBytes;
            if (count > cap) throw ErrorCodes.TooLarge("message of " + count + " bytes, limit " + cap);
            var reader = new MsgPackReader(data, offset, count, new MsgBounds
            {
                MaxStrBytes = Protocol.MaxStrBytes,
                MaxBinBytes = v2 ? Protocol.MaxBinBytesV2 : Protocol.MaxBinBytes,
                MaxArrayLen = Protocol.MaxArrayLen,
                MaxMapLen = Protocol.MaxMapLen,
            });
            var root = reader.ReadWhole();
            if (root.Kind != MsgKind.Map) throw ErrorCodes.Malformed("a message is a msgpack map, not " + root.Kind);
            if (reader.MaxDepthSeen > Protocol.MaxDepth) throw ErrorCodes.Malformed("nested deeper than 8 maps and arrays");
            if (reader.BinKeySeen) throw ErrorCodes.Malformed("map keys must be strings");
            var kind = root.Get("type");
            if (v2 && count > limits.MaxMessageBytes && kind != null && kind.Kind == MsgKind.Str
                && Protocol.ClientTypesV2.Contains(kind.Str))
                throw ErrorCodes.TooLarge("a " + kind.Str + " of " + count + " bytes, limit " + limits.MaxMessageBytes);
            if (kind == null || kind.Kind != MsgKind.Str) throw ErrorCodes.BadField("type", "missing or non-string field type");
            if (!(v2 ? Protocol.TypesV2 : Protocol.TypesV1).Contains(kind.Str))
                throw new UnknownTypeException("unknown message type " + kind.Str).At("type");
            return Wire.Decode(kind.Str, root, limits, version);
        }
    }
}
