// The error table is proto/errors.json, row for row, and fields.json's constants are
// the SDK's.

using System;

namespace Posecast.Client.Tests
{
    public static class ErrorsTests
    {
        public static void Register()
        {
            T.Run("errors: one class per code of proto/errors.json, in order, same fatal and decoder", () =>
            {
                var rows = T.Load("proto", "errors.json");
                T.Equal(rows.Count, ErrorCodes.All.Count, "codes");
                for (int i = 0; i < rows.Count; i++)
                {
                    var row = rows[i];
                    var mine = ErrorCodes.All[i];
                    T.Equal(row["code"].S, mine.Code, "code " + i);
                    T.Equal(row["fatal"].Bool, mine.Fatal, mine.Code + " fatal");
                    T.Equal(row["decoder"].Bool, mine.Decoder, mine.Code + " decoder");
                    var exc = ProtocolException.FromWire(mine.Code, "x");
                    T.Equal(mine.Code, exc.Code, "typed exception code");
                    T.True(exc.GetType() != typeof(ProtocolException), mine.Code + " has its own class");
                    T.Equal(mine.Fatal, exc.Fatal, mine.Code + " default fatal");
                }
            });
            T.Run("errors: an unknown code is a ProtocolException with that code; fatal is the message's", () =>
            {
                var exc = ProtocolException.FromWire("NEW_CODE", "later", fatal: true, field: "x");
                T.Equal(typeof(ProtocolException), exc.GetType(), "type");
                T.True(exc.Fatal && exc.Code == "NEW_CODE" && exc.Field == "x", "fields");
                T.True(!ProtocolException.FromWire("MALFORMED", "m", fatal: false).Fatal, "override");
                T.True(new ServerShutdownException("x").Retryable && !new KickedException("x").Retryable, "retryable");
            });
            T.Run("errors: a TokenProvider that threw is retried; one that returned no token is not", () =>
            {
                var e = new TokenProviderException("the TokenProvider threw", new InvalidOperationException("503"));
                T.True(e.Retryable && ClientSession.IsRetryable(e), "TokenProviderException is retryable");
                T.True(!ClientSession.IsRetryable(new ConfigInvalidException("the TokenProvider returned null", "h")), "ConfigInvalid is not");
            });
            T.Run("schema: constants, bounds, limits and v2 record constants match proto/fields.json", () =>
            {
                var s = T.Load("proto", "fields.json");
                var c = s["constants"];
                T.Equal(Protocol.MaxCoordM, c["max_coord_m"].D, "max_coord_m");
                T.Equal(Protocol.QuatTolerance, c["quat_tolerance"].D, "quat_tolerance");
                T.Equal(Protocol.MaxTimeS, c["max_time_s"].D, "max_time_s");
                T.Equal(Protocol.MaxIdBytes, (int)c["max_id_bytes"].L, "max_id_bytes");
                T.Equal(Quantize.PosUnitM, c["pos_unit_m"].D, "pos_unit_m");
                T.Equal(Quantize.RotScale, c["rot_scale"].D, "rot_scale");
                var st = s["structure"];
                T.Equal(Protocol.MaxDepth, (int)st["max_depth"].L, "max_depth");
                T.Equal(Protocol.MaxArrayLen, (int)st["max_array_len"].L, "max_array_len");
                T.Equal(Protocol.MaxMapLen, (int)st["max_map_len"].L, "max_map_len");
                T.Equal(Protocol.MaxStrBytes, (int)st["max_str_bytes"].L, "max_str_bytes");
                T.Equal(Protocol.MaxBinBytes, (int)st["max_bin_bytes"].L, "max_bin_bytes");
                var lim = s["limits"];
                T.Equal(Limits.Names.Length, lim.Count, "limits");
                for (int k = 0; k < Limits.Names.Length; k++)
                {
                    T.Equal(Limits.Names[k], lim.Fields[k].Key, "limit " + k);
                    T.Equal(Limits.Floor[k], lim.Fields[k].Value["min"].L, Limits.Names[k] + " min");
                    T.Equal(Limits.Max[k], lim.Fields[k].Value["max"].L, Limits.Names[k] + " max");
                }
                var c2 = s["constants_v2"];
                T.Equal(Records.RootUnitM, c2["root_unit_m"].D, "root_unit_m");
                T.Equal(Records.SkeletonUnitM, c2["skeleton_unit_m"].D, "skeleton_unit_m");
                T.Equal(Records.SkeletonBytes, (int)c2["skeleton_bytes"].L, "skeleton_bytes");
                T.Equal(Records.Smallest3Scale, c2["smallest3_scale"].D, "smallest3_scale");
                T.Equal(Records.RotStepRad, c2["rot_step_rad"].D, "rot_step_rad");
                T.Equal(Records.KeyframeBytes, (int)c2["keyframe_bytes"].L, "keyframe_bytes");
                T.Equal(string.Join(",", Records.RotWidths), string.Join(",", Array.ConvertAll(c2["rot_widths"].Doubles(), d => ((int)d).ToString())), "rot_widths");
                T.Equal(string.Join(",", Records.RootWidths), string.Join(",", Array.ConvertAll(c2["root_widths"].Doubles(), d => ((int)d).ToString())), "root_widths");
                T.Equal(string.Join(",", Protocol.PoseRatesHz), string.Join(",", c2["pose_rates_hz"].Doubles()), "pose_rates_hz");
                T.Equal(Protocol.MaxForecastMs, c2["max_forecast_ms"].D, "max_forecast_ms");
                var s2 = s["structure_v2"];
                T.Equal(Protocol.MaxServerMessageBytesV2, (int)s2["max_server_message_bytes"].L, "max_server_message_bytes");
                T.Equal(Protocol.MaxBinBytesV2, (int)s2["max_bin_bytes"].L, "v2 max_bin_bytes");
                T.Equal(string.Join(",", Protocol.JointNames), string.Join(",", s["types"]["joint"]["enum"].Items.ConvertAll(j => j.S)), "joints");
                foreach (var m in s["messages"].Fields)
                {
                    var versions = m.Value["versions"].Items;
                    foreach (var v in versions)
                    {
                        var set = v.L == 1 ? Protocol.TypesV1 : Protocol.TypesV2;
                        T.True(set.Contains(m.Key), m.Key + " in v" + v.L);
                    }
                }
            });
        }
    }
}
