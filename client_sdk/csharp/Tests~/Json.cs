// A small JSON reader for the shared vector files. Numbers keep their text, so a test
// tells a float field (1.0, 1e-05) from an int one (1), as the vectors' format asks.

using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace Posecast.Client.Tests
{
    public enum JsonKind { Null, Bool, Number, String, Array, Object }

    public sealed class Json
    {
        public JsonKind Kind;
        public bool Bool;
        public string Text;                       // a number's text, or a string
        public List<Json> Items;
        public List<KeyValuePair<string, Json>> Fields;

        public Json this[string key]
        {
            get
            {
                if (Fields != null) foreach (var f in Fields) if (f.Key == key) return f.Value;
                return null;
            }
        }
        public Json this[int i] { get { return Items[i]; } }
        public bool Has(string key) { return this[key] != null; }
        public int Count { get { return Items != null ? Items.Count : Fields.Count; } }
        public bool IsNull { get { return Kind == JsonKind.Null; } }
        public bool IsFloatText { get { return Text.IndexOfAny(new[] { '.', 'e', 'E' }) >= 0; } }
        public double D { get { return double.Parse(Text, NumberStyles.Float, CultureInfo.InvariantCulture); } }
        public long L { get { return long.Parse(Text, CultureInfo.InvariantCulture); } }
        public string S { get { return Text; } }

        public double[] Doubles()
        {
            var o = new double[Items.Count];
            for (int i = 0; i < o.Length; i++) o[i] = Items[i].D;
            return o;
        }

        public static Json Parse(string s)
        {
            int pos = 0;
            var v = Value(s, ref pos);
            Ws(s, ref pos);
            if (pos != s.Length) throw new FormatException("trailing JSON at " + pos);
            return v;
        }

        private static void Ws(string s, ref int p) { while (p < s.Length && char.IsWhiteSpace(s[p])) p++; }

        private static Json Value(string s, ref int p)
        {
            Ws(s, ref p);
            char c = s[p];
            if (c == '{')
            {
                p++;
                var o = new Json { Kind = JsonKind.Object, Fields = new List<KeyValuePair<string, Json>>() };
                Ws(s, ref p);
                if (s[p] == '}') { p++; return o; }
                while (true)
                {
                    Ws(s, ref p);
                    string k = Str(s, ref p);
                    Ws(s, ref p);
                    if (s[p++] != ':') throw new FormatException("expected : at " + p);
                    o.Fields.Add(new KeyValuePair<string, Json>(k, Value(s, ref p)));
                    Ws(s, ref p);
                    if (s[p] == ',') { p++; continue; }
                    if (s[p++] != '}') throw new FormatException("expected } at " + p);
                    return o;
                }
            }
            if (c == '[')
            {
                p++;
                var a = new Json { Kind = JsonKind.Array, Items = new List<Json>() };
                Ws(s, ref p);
                if (s[p] == ']') { p++; return a; }
                while (true)
                {
                    a.Items.Add(Value(s, ref p));
                    Ws(s, ref p);
                    if (s[p] == ',') { p++; continue; }
                    if (s[p++] != ']') throw new FormatException("expected ] at " + p);
                    return a;
                }
            }
            if (c == '"') return new Json { Kind = JsonKind.String, Text = Str(s, ref p) };
            if (string.CompareOrdinal(s, p, "true", 0, 4) == 0) { p += 4; return new Json { Kind = JsonKind.Bool, Bool = true }; }
            if (string.CompareOrdinal(s, p, "false", 0, 5) == 0) { p += 5; return new Json { Kind = JsonKind.Bool }; }
            if (string.CompareOrdinal(s, p, "null", 0, 4) == 0) { p += 4; return new Json { Kind = JsonKind.Null }; }
            int start = p;
            while (p < s.Length && "+-0123456789.eE".IndexOf(s[p]) >= 0) p++;
            if (p == start) throw new FormatException("bad JSON at " + p);
            return new Json { Kind = JsonKind.Number, Text = s.Substring(start, p - start) };
        }

        private static string Str(string s, ref int p)
        {
            if (s[p++] != '"') throw new FormatException("expected a string at " + p);
            var sb = new StringBuilder();
            while (true)
            {
                char c = s[p++];
                if (c == '"') return sb.ToString();
                if (c != '\\') { sb.Append(c); continue; }
                char e = s[p++];
                switch (e)
                {
                    case 'n': sb.Append('\n'); break;
                    case 't': sb.Append('\t'); break;
                    case 'r': sb.Append('\r'); break;
                    case 'b': sb.Append('\b'); break;
                    case 'f': sb.Append('\f'); break;
                    case 'u': sb.Append((char)Convert.ToInt32(s.Substring(p, 4), 16)); p += 4; break;
                    default: sb.Append(e); break;
                }
            }
        }
    }
}
