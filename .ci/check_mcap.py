"""Reads stereotac recordings with the reference Python MCAP reader (mcap, with
mcap-protobuf-support to decode Foxglove's protobuf schemas from the schemas the file
carries), checks what the README promises, and with --same compares the depth maps of
a live run and its `stereotac process` replay.

Usage: check_mcap.py FILE.mcap [...] [--same LIVE.mcap PROCESSED.mcap]
"""
import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

JSON_TOPICS = {"/stereotac/leds/phase", "/stereotac/clock", "/stereotac/tactile/contact",
               "/stereotac/stereo/summary"}


def check(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, f"{path}: no summary section"
        protobuf = DecoderFactory()
        topics = {}
        for schema, channel, message in reader.iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            decoded = None
            if channel.message_encoding == "protobuf":
                decoded = protobuf.decoder_for("protobuf", schema)(message.data)
            if channel.topic.endswith("/image") or channel.topic.endswith("/depth"):
                assert schema.name == "foxglove.RawImage", (channel.topic, schema.name)
                row = {"rgb8": 3, "32FC1": 4}[decoded.encoding] * decoded.width
                assert decoded.step >= row and len(decoded.data) >= decoded.step * decoded.height
            elif channel.topic.endswith("/points"):
                assert schema.name == "foxglove.PointCloud", schema.name
                assert [f.name for f in decoded.fields] == ["x", "y", "z"]
            elif channel.topic in JSON_TOPICS or channel.topic.endswith("/frame"):
                assert channel.message_encoding == "json"
                json.loads(message.data)
        f.seek(0)
        names = {m.name for m in make_reader(f).iter_metadata()}
        f.seek(0)
        attachments = {a.name for a in make_reader(f).iter_attachments()}
    assert "/stereotac/cam0/image" in topics and "/stereotac/cam0/frame" in topics, topics
    assert {"stereotac", "sensor"} <= names, names
    print(f"{path}: {sum(topics.values())} messages on {len(topics)} topics, "
          f"metadata {sorted(names)}, attachments {sorted(attachments)}")
    return topics


def depth_maps(path):
    out = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(
                topics=["/stereotac/tactile/depth", "/stereotac/stereo/depth",
                        "/stereotac/stereo/points"]):
            out.setdefault(channel.topic, []).append((message.log_time, message.data))
    return out


def main(args):
    same = None
    if "--same" in args:
        i = args.index("--same")
        same = args[i + 1:i + 3]
        args = args[:i] + args[i + 3:]
    for path in args:
        check(path)
    if same:
        # Live, a busy stage skips to the newest job; offline nothing is skipped: every
        # live depth map must have its identical twin at the same log time.
        a, b = (depth_maps(p) for p in same)
        assert a, f"{same[0]}: no depth maps"
        for topic, msgs in a.items():
            twins = dict(b.get(topic, []))
            for t, data in msgs:
                assert twins.get(t) == data, f"{topic} at {t}: {same[1]} differs from {same[0]}"
        print(f"{same[1]}: every depth map and point cloud identical to {same[0]} "
              f"({', '.join(f'{len(v)} on {k}' for k, v in sorted(a.items()))})")


if __name__ == "__main__":
    main(sys.argv[1:])
